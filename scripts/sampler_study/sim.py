"""The simulated held-out Bandai protocol: the UI-PRMD protocol's models and rows on simulated
streams of the seed-2016 take split of Bandai Namco dataset-1."""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import time
from typing import Any

import numpy as np

from fpg_gym.core.holdout import split_takes
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import load_clips
from policies.training import collect_imitation_data, simulate_episodes
from sampler_study import SCENARIOS, study_command
from sampler_study.scoring import score
from sampler_study.tables import uiprmd_table
from sampler_study.training import sampler_spec, train_seeds


def _sim_data(
    graph_clips: list[Any], clips: list[Any], spec: Any, task: dict[str, Any], seed: int
) -> tuple[Any, tuple[Any, dict[str, Any], list[Any]]]:
    """Ground-truth imitation data of simulated streams of ``clips`` (``task["sim_scenarios"]``,
    first ``task["train_frames"]`` frames), collected with a graph of ``graph_clips``; and
    that ``(graph, reconstructor options, recordings)`` (what its output correction learns
    from)."""

    graph = FilteredPoseGraph.build(graph_clips, progress=False)
    recordings = simulate_episodes(
        clips, task["sim_scenarios"], [seed], max_frames=task["train_frames"]
    )
    target = spec.hyperparameters.get("target", "truth")
    data = collect_imitation_data(graph, recordings, spec, target=target, follow="anchor")
    return data, (graph, {}, recordings)


def _nested_data(
    graph_clips: list[Any],
    folds: list[list[int]],
    val_ids: set[int],
    spec: Any,
    task: dict[str, Any],
) -> tuple[list[Any], Any, list[tuple[Any, dict[str, Any], list[Any], int]]]:
    """Each fold's training and validation imitation data (:func:`_sim_data` with a graph of
    the other folds, simulator seed ``1000 + fold``): ``(training parts, the validation parts
    in one, the output correction's groups)``."""
    train_parts: list[Any] = []
    val_parts: list[Any] = []
    train_sources: list[tuple[Any, dict[str, Any], list[Any]]] = []
    val_sources: list[tuple[Any, dict[str, Any], list[Any]]] = []
    for f, fold in enumerate(folds):
        other = [graph_clips[i] for g, ids in enumerate(folds) if g != f for i in ids]
        for ids, parts, sources in (
            ([i for i in fold if i not in val_ids], train_parts, train_sources),
            ([i for i in fold if i in val_ids], val_parts, val_sources),
        ):
            if ids:
                part, source = _sim_data(other, [graph_clips[i] for i in ids], spec, task, 1000 + f)
                parts.append(part)
                sources.append(source)
    val = dataclasses.replace(
        val_parts[0],
        observations=np.concatenate([d.observations for d in val_parts]),
        actions=np.concatenate([d.actions for d in val_parts]),
        masks=np.concatenate([d.masks for d in val_parts]),
        episodes=np.concatenate([d.episodes for d in val_parts]),
        search_energies=np.concatenate([d.search_energies for d in val_parts]),
    )
    # The correction's groups: each fold's training and validation parts, each reconstructed
    # with the graph of the other folds.
    groups = [(*source, g) for g, source in enumerate(train_sources)]
    groups += [(*source, len(train_parts)) for source in val_sources]
    return train_parts, val, groups


def sim_protocol(args: argparse.Namespace) -> str:
    """The simulated held-out Bandai protocol with ground-truth samplers (module docstring)."""
    if args.model == "mlp":
        import torch  # the learn extra (optional)

        torch.set_num_threads(1)
    folder = args.out / "sim"
    folder.mkdir(parents=True, exist_ok=True)
    files = sorted((args.data / "dataset-1").glob("*.bvh"))
    graph_files, eval_files = split_takes(files)
    eval_files = eval_files[: args.sim_eval_takes]
    graph_clips = load_clips(graph_files, progress=False)
    eval_clips = load_clips(eval_files, progress=False)
    task = {
        "out": str(folder),
        "seeds": [int(s) for s in args.seeds.split(",")],
        "epochs": args.epochs,
        "hidden": [int(w) for w in args.hidden.split(",")],
        "features": args.features,
        "model": args.model,
        "correct": args.correction,
        "sim_scenarios": args.sim_train_scenarios.split(","),
        "train_frames": args.sim_train_frames,
        "command": study_command(args),
    }
    spec = sampler_spec(task)
    # Nested: the graph takes in ``--sim-folds`` folds; a fold's streams are collected with a
    # graph of the other folds, so no training target is a database pose (as on held-out
    # takes); more folds make that graph closer to the evaluation graph (all graph takes). A
    # seeded tenth of the takes (from every fold) is the validation split.
    order = np.random.default_rng(2016).permutation(len(graph_clips))
    bounds = [f * len(order) // args.sim_folds for f in range(args.sim_folds + 1)]
    folds = [sorted(order[a:b]) for a, b in itertools.pairwise(bounds)]
    val_ids = set(order[:: max(2, round(1 / args.sim_val_share))].tolist())
    start = time.perf_counter()
    t0 = time.process_time()
    train_parts, val, groups = _nested_data(graph_clips, folds, val_ids, spec, task)
    data_cpu = time.process_time() - t0
    info = {
        "protocol": "simulated held-out Bandai dataset-1 (seed-2016 take split)",
        "graph_takes": len(graph_clips),
        "validation_takes": sorted(graph_clips[i].name for i in val_ids),
        "scenarios": task["sim_scenarios"],
    }
    trained = train_seeds(spec, train_parts, val, task, "bandai", info, groups)
    graph = FilteredPoseGraph.build(graph_clips, progress=False)
    scenarios = SCENARIOS.split(",")
    recordings = simulate_episodes(eval_clips, scenarios, [0], max_frames=args.max_frames)
    names = [f"{c.name}/{s}" for c in eval_clips for s in scenarios]
    rows = score(graph, {}, trained["models"], list(zip(names, recordings, strict=True)))
    result = {"subject": "bandai", "data_cpu_s": data_cpu, **trained, "rows": rows}
    (folder / "results.json").write_text(json.dumps([result], indent=1))
    report = (
        f"### simulated held-out Bandai ({len(names)} episodes: {len(eval_clips)} held-out "
        f"dataset-1 takes x {SCENARIOS}, first {args.max_frames} frames; seeds {args.seeds})\n\n"
        f"{uiprmd_table([result])}\n\nWall time {time.perf_counter() - start:.0f} s; training "
        f"CPU per sampler {np.mean(list(trained['train_cpu_s'].values())):.0f} s, data CPU "
        f"{data_cpu:.0f} s ({trained['frames']} training frames, {len(val)} validation); "
        f"offset kept (mean_scale) {json.dumps(trained['mean_scale'])}.\n"
    )
    (folder / "table.md").write_text(report)
    print(report, flush=True)
    return report
