"""Train the learned samplers and compare them with the papers' search (issue 9 figures).

Two protocols, both with the held-out rule (samplers and graph never see an evaluated take):

* ``embedded``: the embedded DeepMimic clips. The default graph and the samplers use the 11
  clips other than walk, punch, kick, dance_b; those four are evaluated.
* ``bandai``: Bandai Namco dataset-1 split by whole takes (``scripts/holdout_split.py``, seed
  2016, 20 % held out). The graph and the samplers use the graph takes only; the first
  ``--eval-takes`` held-out takes (first ``--max-frames`` frames) are evaluated.

For each: ``fpg-gym train-sampler`` for the supervised and the PPO sampler (timed), then
``fpg-gym compare`` on the ``*-many`` scenarios with ``local-search`` (2,000 evaluations),
``learned:`` and ``learned+search:`` (200 each); then, on the same episodes (same seeds),
``random-search`` with 200 evaluations (the fair floor of a 200-evaluation sampler) and two
diagnostic rows run through the Python API: the sampler's anchor alone and its mean alone
(1 evaluation each). Prints one table per protocol (``table.md`` in each folder).

* ``uiprmd``: real Kinect v2 streams against Vicon, leave subjects out over s01-s08
  (:mod:`scripts.real_kinect`'s machinery: the UI-PRMD database and the Kinect v2 -> Vicon map
  of each fold are fitted on the other seven subjects only). The sampler learns the ground
  truth of the training subjects' real streams (every repetition; ``--train-reps N``: N per
  exercise); its imitation data of a training subject is collected with a database that lacks
  that subject too (nested), so the truth is never among the candidates, as on the held-out
  subject. ``--exclude-training LIST``: subjects no fold trains on (database, map, sampler),
  still scored when held out. ``--model linear`` (default): the linear pose-space sampler
  (:mod:`policies.pose_sampler`, target ``bones``), its settings chosen by leave-one-subject-out
  cross-validation over the seven training subjects, deterministic (one model per fold
  whatever ``--seeds``). ``--model mlp``: the supervised MLP (target ``truth``), one per
  training seed, one training subject per fold being the validation split (early stopping,
  spread calibration). Each model is scored on the held-out subject with ``learned:`` and
  ``learned+search:`` (200 evaluations) and its mean alone (1; a linear sampler's three with
  the output correction it learns from its own outputs of the training subjects,
  :mod:`policies.output_correction`, and ``uncorrected``: ``learned:`` without it;
  ``--no-correction``, ``--cross-fit``), beside ``closed-form`` (the
  anchor, 1), ``local-search`` (2,000), the raw sensor and two oracles that see the truth (its
  latent point by joints and by bones); 95 % confidence intervals by a bootstrap over episodes.
* ``sim``: the simulated held-out Bandai protocol (:func:`sim_protocol`), the same models and
  rows.

Usage::

    python scripts/learned_samplers.py --out runs/learned [--protocols embedded,bandai]
    python scripts/learned_samplers.py --protocols uiprmd --workers 2 --out runs/learned
    python scripts/learned_samplers.py --protocols sim --out runs/learned
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import json
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import real_kinect  # scripts/real_kinect.py: the UI-PRMD leave-subjects-out machinery

import optimizers
from fpg_gym.core import metrics
from fpg_gym.core.holdout import split_takes
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import load_clips
from fpg_gym.io.recording import load_recording
from fpg_gym.methods import MethodRunner
from fpg_gym.reconstruct import Reconstructor
from policies.learned_optimizers import LearnedSampler
from policies.output_correction import CorrectionSource, describe_correction, learn_correction
from policies.pose_sampler import (
    LINEAR_FEATURES,
    describe_fit,
    fit_linear,
    out_of_group_samplers,
)
from policies.sampler import FEATURE_SETS, SamplerSpec
from policies.supervised import SupervisedSampler, fit_supervised
from policies.training import collect_imitation_data, simulate_episodes, truth_latent

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "bandai_namco"
SCENARIOS = "front-many,left45-many,right45-many"


def sh(args: list[str], log: Path) -> float:
    """Run a command (echoed, output appended to ``log``); returns its wall time."""
    line = " ".join(shlex.quote(a) for a in args)
    print(f"$ {line}", flush=True)
    start = time.perf_counter()
    with log.open("a") as handle:
        handle.write(f"$ {line}\n")
        handle.flush()
        subprocess.run(args, check=True, stdout=handle, stderr=subprocess.STDOUT, cwd=REPO)
    seconds = time.perf_counter() - start
    print(f"  ({seconds:.1f} s)", flush=True)
    return seconds


def _safe(text: str) -> str:
    """File-name form of a name, as ``fpg-gym compare`` writes its frame files."""
    return re.sub(r"[^A-Za-z0-9._+-]+", "_", text).strip("_") or "x"


def aggregate(folder: Path) -> dict[str, dict[str, float]]:
    """Frame-pooled figures per method of a compare folder."""
    rows = list(csv.DictReader((folder / "results.csv").open()))
    out: dict[str, dict[str, list[np.ndarray]]] = {}
    for row in rows:
        path = folder / "frames" / _safe(row["episode"]) / f"{_safe(row['method'])}.npz"
        with np.load(path, allow_pickle=False) as frames:
            acc = out.setdefault(row["method"], {"errors": [], "ms": [], "energy": [], "ev": []})
            acc["errors"].append(frames["errors"])
            acc["ms"].append(frames["ms"])
            acc["energy"].append(frames["energy"])
            acc["ev"].append(frames["evaluations"])
    table = {}
    for method, acc in out.items():
        errors = np.concatenate(acc["errors"])
        table[method] = {
            "episodes": len(acc["errors"]),
            "frames": len(errors),
            "mean_energy": float(np.mean(np.concatenate(acc["energy"]))),
            "mean_error": float(np.mean(errors)),
            "err02": float(100 * np.mean(errors >= 0.2)),
            "ms": float(np.mean(np.concatenate(acc["ms"]))),
            "evaluations": float(np.mean(np.concatenate(acc["ev"]))),
        }
    return table


def markdown(table: dict[str, dict[str, float]], names: dict[str, str], baseline: str) -> str:
    base = table[baseline]["mean_error"]
    lines = [
        "| method | evaluations/frame | mean energy | mean error (m) | vs local search | "
        "Err0.2 (%) | ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for method, row in table.items():
        change = 100 * (row["mean_error"] / base - 1)
        lines.append(
            f"| {names.get(method, method)} | {row['evaluations']:.0f} | "
            f"{row['mean_energy']:.4f} | {row['mean_error']:.4f} | {change:+.1f} % | "
            f"{row['err02']:.1f} | {row['ms']:.2f} |"
        )
    return "\n".join(lines)


def diagnostics(
    folder: Path, graph: str, clips: list[str], models: dict[str, str], max_frames: int | None
) -> None:
    """random-search (200), the anchor alone and each sampler's mean alone, on the same
    episodes as the main comparison (in this process: the extra optimisers are registered
    here)."""
    import optimizers
    from fpg_gym.experiments import CompareConfig, run_compare
    from policies.learned_optimizers import LearnedSampler
    from policies.loading import load_sampler
    from policies.sampler import AnchorSampler

    def mean_only(path: str, **_: Any) -> Any:
        return LearnedSampler(path, samples=1)

    def anchor_only(path: str, **_: Any) -> Any:
        return LearnedSampler(AnchorSampler(load_sampler(path).spec), samples=1)

    optimizers.register_prefix("mean-only", mean_only, overwrite=True)
    optimizers.register_prefix("anchor-only", anchor_only, overwrite=True)
    first = next(iter(models.values()))
    methods = [f"fpg:anchor-only:{first}"] + [f"fpg:mean-only:{m}" for m in models.values()]
    common = {
        "graph": graph,
        "clips": clips,
        "scenarios": SCENARIOS.split(","),
        "max_frames": max_frames,
        "workers": 1,
    }
    for name, budget, chosen in (
        ("diagnostics", 2000, methods),
        ("random200", 200, ["fpg:random-search"]),
    ):
        config = CompareConfig(
            out=str(folder / name), methods=chosen, budget=budget, baseline=chosen[0], **common
        )
        print(f"compare (API) {name}: {', '.join(chosen)} budget {budget}", flush=True)
        run_compare(config, progress=False, plots=False, log=lambda _: None)


def protocol(
    name: str,
    out: Path,
    graph: str,
    train_clips: list[str],
    eval_clips: list[str],
    args: argparse.Namespace,
    extra_train: list[str],
) -> str:
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "log.txt"
    timings: dict[str, float] = {}
    models = {"supervised": str(folder / "sampler_sup"), "ppo": str(folder / "sampler_ppo")}
    base = ["fpg-gym", "train-sampler", "--graph", graph, "--quiet", *extra_train]
    if train_clips:
        base += ["--clips", *train_clips]
    timings["train supervised"] = sh(
        [*base, "--kind", "supervised", "--out", models["supervised"], "--timesteps",
         str(args.sup_timesteps)],
        log,
    )  # fmt: skip
    timings["train ppo"] = sh(
        [*base, "--kind", "rl", "--algo", "ppo", "--out", models["ppo"], "--timesteps",
         str(args.rl_timesteps)],
        log,
    )  # fmt: skip
    optimizer_list = ["local-search"] + [
        f"{kind}:{path}" for path in models.values() for kind in ("learned", "learned+search")
    ]
    frames = ["--max-frames", str(args.max_frames)] if args.max_frames else []
    compare = folder / "compare"
    timings["compare"] = sh(
        ["fpg-gym", "compare", "--graph", graph, "--clips", *eval_clips, *frames,
         "--scenarios", SCENARIOS, "--optimizers", ",".join(optimizer_list),
         "--workers", "1", "--fresh", "--no-plots", "--quiet", "--out", str(compare)],
        log,
    )  # fmt: skip
    diagnostics(folder, graph, eval_clips, models, args.max_frames)
    table: dict[str, dict[str, float]] = {}
    table.update(aggregate(compare))
    table.update(aggregate(folder / "random200"))
    table.update(aggregate(folder / "diagnostics"))
    names = {"fpg:local-search": "local-search (2,000)", "fpg:random-search": "random-search (200)"}
    for kind, path in models.items():
        names[f"fpg:learned:{path}"] = f"learned:{kind} (200)"
        names[f"fpg:learned+search:{path}"] = f"learned+search:{kind} (200)"
        names[f"fpg:mean-only:{path}"] = f"{kind} mean alone (1)"
    names[f"fpg:anchor-only:{models['supervised']}"] = "anchor alone (1)"
    text = markdown(table, names, "fpg:local-search")
    timing = ", ".join(f"{k} {v:.0f} s" for k, v in timings.items())
    report = f"### {name}\n\n{text}\n\nWall times: {timing}.\n"
    (folder / "table.md").write_text(report)
    print(report, flush=True)
    return report


# --------------------------------------------------------------------------- UI-PRMD


def _uiprmd_data(
    imported: Path,
    subjects: dict[str, list[Path]],
    held_out: str,
    subject: str,
    spec: Any,
    options: dict[str, Any],
    reps: int,
    thres1: float,
    excluded: frozenset[str] = frozenset(),
) -> tuple[Any, tuple[Any, dict[str, Any], list[Any]]]:
    """Ground-truth imitation data of one training ``subject``, collected with a database and
    sensor map that lack it, the held-out subject and the ``excluded`` ones; and that
    ``(graph, reconstructor options, recordings)`` (what its output correction learns from)."""

    left_out = {held_out, subject, *excluded}
    graph = real_kinect.uiprmd_graph(imported, left_out, thres1)
    others = [load_recording(p) for s, ps in subjects.items() if s not in left_out for p in ps]
    sensor_map, _, _ = real_kinect.fold_maps("uiprmd", graph, others, True, False)
    recordings = [load_recording(p) for p in real_kinect.repetitions(subjects[subject], reps)]
    fold_options = {**options, "sensor_map": sensor_map}
    data = collect_imitation_data(
        graph,
        recordings,
        spec,
        target=spec.hyperparameters.get("target", "truth"),
        follow="anchor",
        reconstructor_options=fold_options,
    )
    return data, (graph, fold_options, recordings)


def _oracle(
    graph: Any, options: dict[str, Any], recording: Any, metric: str = "joints"
) -> np.ndarray:
    """The stream reconstructed from the ground truth's own latent point every frame
    (:func:`policies.training.truth_latent`, its joints projected or, ``metric="bones"``, its
    bone directions at the frame's bone lengths): what a perfect sampler of this latent space
    would give (a ceiling of every sampler; it sees the truth, so it is no method)."""

    truth = recording.ground_truth
    out = np.empty_like(recording.positions)
    with Reconstructor(graph, ragdoll=False, **options) as reconstructor:
        for t in range(recording.num_frames):
            problem = reconstructor.prepare(
                recording.positions[t], recording.states[t], float(recording.timestamps[t])
            )
            assert reconstructor.placement is not None
            z = truth_latent(problem, reconstructor.placement, truth[t], metric)
            out[t] = reconstructor.finish(z)[0]
    return out


def _spec(task: dict[str, Any]) -> Any:
    """The sampler's description (ground-truth target, the env's layout): the linear
    pose-space sampler (``--model linear``) or the supervised MLP (``--model mlp``)."""

    if task["model"] == "linear":
        return SamplerSpec.for_layout(
            "linear",
            "ridge",
            action_mode="absolute",
            features=list(LINEAR_FEATURES),
            hyperparameters={"target": "bones"},
        )
    return SamplerSpec.for_layout(
        "supervised",
        "mlp",
        action_mode="absolute",
        features=list(FEATURE_SETS[task["features"]]),
        hyperparameters={"hidden": task["hidden"], "target": "truth", "epochs": task["epochs"]},
    )


def _train_seeds(
    spec: Any,
    train: list[Any],
    val: Any,
    task: dict[str, Any],
    name: str,
    info: dict[str, Any],
    sources: list[tuple[Any, dict[str, Any], list[Any], int]] | None = None,
) -> dict[str, Any]:
    """One sampler per seed of ``task["seeds"]`` on the ``train`` imitation data, early
    stopping, shrinking and spread calibration on ``val``; saved as ``{out}/sampler_{name}_seedS``.
    A linear sampler learns its output correction from ``sources`` (``(graph, options,
    recordings, group)``: the group's index in ``[*train, val]``; none: no correction, or with
    ``task["correct"]`` false).
    """

    if spec.kind == "linear":
        return _train_linear(spec, [*train, val], task, name, info, sources)
    obs = np.concatenate([d.observations for d in train])
    act = np.concatenate([d.actions for d in train])
    mask = np.concatenate([d.masks for d in train])
    transformed = spec.feature_map().transform(obs)
    features = transformed[0]
    result: dict[str, Any] = {"models": {}, "train_cpu_s": {}, "mean_scale": {}}
    for seed in task["seeds"]:
        t0 = time.process_time()
        sampler = SupervisedSampler.create(
            dataclasses.replace(spec, hyperparameters=dict(spec.hyperparameters)),
            features.mean(axis=0),
            np.maximum(features.std(axis=0), 1e-3),
            seed=seed,
        )
        history = fit_supervised(
            sampler,
            obs,
            act,
            mask,
            epochs=task["epochs"],
            seed=seed,
            validation=(val.observations, val.actions, val.masks),
            transformed=transformed,
        )
        result["train_cpu_s"][str(seed)] = time.process_time() - t0
        result["mean_scale"][str(seed)] = float(history[-1].get("mean_scale", 1.0))
        sampler.spec.training = {
            **info,
            "frames": len(obs),
            "validation_frames": len(val),
            "best_epoch": next(r["epoch"] for r in history if r.get("best")),
            "mean_scale": history[-1].get("mean_scale"),
            "std_scale": history[-1].get("std_scale"),
            "seed": seed,
            "command": task["command"],
        }
        path = Path(task["out"]) / f"sampler_{name}_seed{seed}"
        sampler.save(path)
        result["models"][str(seed)] = str(path)
    result["frames"] = len(obs)
    return result


def _train_linear(
    spec: Any,
    groups: list[Any],
    task: dict[str, Any],
    name: str,
    info: dict[str, Any],
    sources: list[tuple[Any, dict[str, Any], list[Any], int]] | None = None,
) -> dict[str, Any]:
    """The linear pose-space sampler, its settings chosen by leave-one-group-out
    cross-validation over ``groups`` (imitation data of the training subjects, or of the
    simulated protocol's folds); deterministic (one model whatever the seeds); with
    ``sources`` and ``task["correct"]``, its output correction learnt from its outputs of the
    training groups (:func:`policies.output_correction.learn_correction`; with
    ``task["cross_fit"]`` each group's outputs come from the sampler fitted without it); saved as
    ``{out}/sampler_{name}_linear``."""

    t0 = time.process_time()
    sampler, report = fit_linear(spec, [(d.observations, d.actions, d.episodes) for d in groups])
    cpu = time.process_time() - t0
    correction_report: dict[str, Any] = {}
    if sources and task.get("correct", True):
        t1 = time.process_time()
        bare = LearnedSampler(sampler, samples=1, correct_output=False)
        samplers = (  # cross-fitted: each group's outputs by the sampler fitted without it
            [
                LearnedSampler(alone, samples=1)
                for alone in out_of_group_samplers(
                    sampler, [(d.observations, d.actions, d.episodes) for d in groups]
                )
            ]
            if task.get("cross_fit")
            else [bare] * len(groups)
        )
        correction, correction_report = learn_correction(
            [
                CorrectionSource(graph, options, recordings, samplers[g])
                for graph, options, recordings, g in sources
            ]
        )
        sampler.with_correction(correction, correction_report)
        correction_report = {**correction_report, "cpu_s": time.process_time() - t1}
        cpu += correction_report["cpu_s"]  # the model's training: the sampler and its correction
        print(f"{name}: {describe_correction(correction_report)}", file=sys.stderr, flush=True)
    sampler.spec.training = {**info, **report, "command": task["command"]}
    path = Path(task["out"]) / f"sampler_{name}_linear"
    sampler.save(path)
    print(
        f"{name}: {describe_fit(report)}; by pose weight {json.dumps(report['cv_pose'])}",
        file=sys.stderr,
        flush=True,
    )
    return {
        "models": {"linear": str(path)},
        "train_cpu_s": {"linear": cpu},
        "mean_scale": {},
        "frames": sum(len(d) for d in groups),
        "linear": report,
        "correction": correction_report,
    }


def _score(
    graph: Any, options: dict[str, Any], models: dict[str, str], episodes: list[tuple[str, Any]]
) -> list[dict[str, Any]]:
    """Every method (raw, closed-form, local-search, each model's mean alone, ``learned:`` and
    ``learned+search:``, the oracle) on every ``(name, recording)``: error, jitter, CPU."""

    def mean_only(path: str, **_: Any) -> Any:
        return LearnedSampler(path, samples=1)

    def uncorrected(path: str, **_: Any) -> Any:
        return LearnedSampler(path, correct_output=False)

    optimizers.register_prefix("mean-only", mean_only, overwrite=True)
    optimizers.register_prefix("uncorrected", uncorrected, overwrite=True)
    methods = ["raw", "fpg:closed-form", "fpg:local-search"]
    for path in models.values():
        methods += [f"fpg:mean-only:{path}", f"fpg:learned:{path}", f"fpg:learned+search:{path}"]
        if LearnedSampler(path).sampler.spec.kind == "linear":  # with or without a correction
            methods.append(f"fpg:uncorrected:{path}")
    rows = []
    with MethodRunner(graph, budget=2000, reconstructor_options=options) as runner:
        for name, recording in episodes:
            truth = recording.ground_truth
            assert truth is not None
            for method in [*methods, "oracle", "oracle-bones"]:
                c0 = time.process_time()
                if method.startswith("oracle"):
                    metric = "bones" if method == "oracle-bones" else "joints"
                    poses = _oracle(graph, options, recording, metric)
                else:
                    poses = runner.run(method, recording, seed=0).poses
                cpu = 1000 * (time.process_time() - c0) / recording.num_frames
                rows.append(
                    {
                        "episode": name,
                        "method": method,
                        "error": float(metrics.frame_error(truth, poses).mean()),
                        "jitter": float(np.nanmean(metrics.jitter(poses, fps=recording.fps))),
                        "cpu_ms": cpu,
                    }
                )
    return rows


def _uiprmd_fold(task: dict[str, Any]) -> dict[str, Any]:
    """One held-out subject: data, ``len(seeds)`` samplers, and every method scored."""
    if task["model"] == "mlp":
        import torch  # the learn extra (optional)

        torch.set_num_threads(1)
    imported = Path(task["imported"])
    held_out, thres1 = task["subject"], task["thres1"]
    excluded = frozenset(task["exclude_training"])
    subjects = real_kinect.by_subject(imported / "recordings")
    train_subjects = [s for s in sorted(subjects) if s != held_out and s not in excluded]
    # The validation subject: the first training subject after the held-out one (cyclic).
    val_subject = train_subjects[next((i for i, s in enumerate(train_subjects) if s > held_out), 0)]
    options: dict[str, Any] = {"sensor_blend": task["blend"]}
    spec = _spec(task)
    t0 = time.process_time()
    collected = {
        s: _uiprmd_data(
            imported, subjects, held_out, s, spec, options, task["train_reps"], thres1, excluded
        )
        for s in train_subjects
    }
    data = {s: part[0] for s, part in collected.items()}
    data_cpu = time.process_time() - t0
    info = {
        "protocol": "uiprmd leave-subjects-out",
        "held_out": held_out,
        "validation_subject": val_subject,
        "train_subjects": [s for s in train_subjects if s != val_subject],
        "excluded_from_training": sorted(excluded),
    }
    trained = _train_seeds(
        spec,
        [data[s] for s in train_subjects if s != val_subject],
        data[val_subject],
        task,
        held_out,
        info,
        # The correction's groups in the sampler's order (training subjects, then validation).
        [
            (*collected[s][1], g)
            for g, s in enumerate([s for s in train_subjects if s != val_subject] + [val_subject])
        ],
    )
    collected.clear()  # the nested graphs
    graph = real_kinect.uiprmd_graph(imported, {held_out, *excluded}, thres1)
    train_recs = [load_recording(p) for s in train_subjects for p in subjects[s]]
    sensor_map, _, _ = real_kinect.fold_maps("uiprmd", graph, train_recs, True, False)
    episodes = [
        (path.stem, load_recording(path))
        for path in real_kinect.repetitions(subjects[held_out], task["reps"])
    ]
    rows = _score(graph, {**options, "sensor_map": sensor_map}, trained["models"], episodes)
    result = {
        "subject": held_out,
        "validation_subject": val_subject,
        "data_cpu_s": data_cpu,
        **trained,
        "rows": rows,
    }
    # Each fold's rows as soon as they exist (a stopped run keeps its finished folds).
    (Path(task["out"]) / f"fold_{held_out}.json").write_text(json.dumps(result, indent=1))
    return result


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
        "cross_fit": args.cross_fit,
        "sim_scenarios": args.sim_train_scenarios.split(","),
        "train_frames": args.sim_train_frames,
        "command": "python scripts/learned_samplers.py "
        + " ".join(shlex.quote(a) for a in (args.argv or [])),
    }
    spec = _spec(task)
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
    data_cpu = time.process_time() - t0
    val = dataclasses.replace(
        val_parts[0],
        observations=np.concatenate([d.observations for d in val_parts]),
        actions=np.concatenate([d.actions for d in val_parts]),
        masks=np.concatenate([d.masks for d in val_parts]),
        episodes=np.concatenate([d.episodes for d in val_parts]),
        search_energies=np.concatenate([d.search_energies for d in val_parts]),
    )
    info = {
        "protocol": "simulated held-out Bandai dataset-1 (seed-2016 take split)",
        "graph_takes": len(graph_clips),
        "validation_takes": sorted(graph_clips[i].name for i in val_ids),
        "scenarios": task["sim_scenarios"],
    }
    # The correction's groups: each fold's training and validation parts, each reconstructed
    # with the graph of the other folds (with --cross-fit, by the sampler fitted without the
    # part's group).
    sources = [(*source, g) for g, source in enumerate(train_sources)]
    sources += [(*source, len(train_parts)) for source in val_sources]
    trained = _train_seeds(spec, train_parts, val, task, "bandai", info, sources)
    graph = FilteredPoseGraph.build(graph_clips, progress=False)
    scenarios = SCENARIOS.split(",")
    recordings = simulate_episodes(eval_clips, scenarios, [0], max_frames=args.max_frames)
    names = [f"{c.name}/{s}" for c in eval_clips for s in scenarios]
    rows = _score(graph, {}, trained["models"], list(zip(names, recordings, strict=True)))
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


def _method_kind(method: str, models: dict[str, dict[str, str]]) -> tuple[str, str | None]:
    """``(row name, seed)`` of a method of the UI-PRMD protocol."""
    for fold in models.values():
        for seed, path in fold.items():
            if method.endswith(path):
                return method[: -len(path)].removeprefix("fpg:").rstrip(":"), seed
    return method.removeprefix("fpg:"), None


def uiprmd_table(results: list[dict[str, Any]]) -> str:
    """The UI-PRMD table: per method, mean error with its 95 % CI (episodes), the change
    against closed-form with its CI (paired), jitter, CPU ms per frame; learned rows pool the
    seeds (one row per seed below, when there are several)."""
    rows = [r for result in results for r in result["rows"]]
    models = {res["subject"]: res["models"] for res in results}
    # One row per seed only when there are several (the linear sampler has one model).
    several = len({seed for fold in models.values() for seed in fold}) > 1
    rng = np.random.default_rng(2016)
    by: dict[str, dict[str, dict[str, Any]]] = {}
    for row in rows:
        name, seed = _method_kind(row["method"], models)
        for key in [name] + ([f"{name} (seed {seed})"] if seed is not None and several else []):
            episodes = by.setdefault(key, {})
            slot = episodes.setdefault(row["episode"], {"error": [], "jitter": [], "cpu": []})
            slot["error"].append(row["error"])
            slot["jitter"].append(row["jitter"])
            slot["cpu"].append(row["cpu_ms"])
    base = by["closed-form"]
    order = sorted(base)
    lines = [
        "| method | evaluations/frame | mean error (m) [95 % CI] | vs closed-form [95 % CI] "
        "| vs local-search | jitter (m/s²) | CPU ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    evaluations = {
        "raw": "–",
        "closed-form": "1",
        "local-search": "2,000",
        "mean-only": "1",
        "oracle": "– (sees the truth)",
        "oracle-bones": "– (sees the truth)",
    }
    local = np.array([np.mean(by["local-search"][e]["error"]) for e in order])
    anchor = np.array([np.mean(base[e]["error"]) for e in order])
    for name, episodes in by.items():
        err = np.array([np.mean(episodes[e]["error"]) for e in order])
        lo, hi = metrics.bootstrap_mean_ci(err, rng=rng)
        rlo, rhi = metrics.bootstrap_mean_ci(err, base=anchor, rng=rng)
        jit = np.mean([np.mean(episodes[e]["jitter"]) for e in order])
        cpu = np.median([np.median(episodes[e]["cpu"]) for e in order])
        kind = name.split(" ")[0]
        lines.append(
            f"| {name} | {evaluations.get(kind, '200')} | {err.mean():.4f} [{lo:.4f}, {hi:.4f}] "
            f"| {100 * (err.mean() / anchor.mean() - 1):+.1f} % [{100 * rlo:+.1f}, "
            f"{100 * rhi:+.1f}] | {100 * (err.mean() / local.mean() - 1):+.1f} % | {jit:.2f} | "
            f"{cpu:.2f} |"
        )
    return "\n".join(lines)


def _subject_errors(result: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
    """One fold's episode means by method (seeds pooled): ``{method: {"error", "jitter"}}``,
    episodes in the same (sorted) order for every method."""
    models = {result["subject"]: result["models"]}
    by: dict[str, dict[str, list[float]]] = {}
    for row in result["rows"]:
        name, _ = _method_kind(row["method"], models)
        slot = by.setdefault(name, {}).setdefault(row["episode"], [])
        slot.append((row["error"], row["jitter"]))
    out = {}
    for name, episodes in by.items():
        values = np.array([np.mean(episodes[e], axis=0) for e in sorted(episodes)])
        out[name] = {"error": values[:, 0], "jitter": values[:, 1]}
    return out


SUBJECT_METHODS = ("closed-form", "local-search", "learned", "learned+search", "oracle-bones")


def uiprmd_subject_table(results: list[dict[str, Any]]) -> str:
    """Per held-out subject: each method's mean error (seeds pooled) and ``learned:``'s
    change against closed-form with its paired 95 % CI over the subject's episodes; jitter."""
    rng = np.random.default_rng(2016)
    lines = [
        "| held out | episodes | "
        + " | ".join(f"{m} (m)" for m in SUBJECT_METHODS)
        + " | learned vs closed-form [95 % CI] | jitter closed-form → learned (m/s²) |",
        "| --- | --- | " + " | ".join("---" for _ in SUBJECT_METHODS) + " | --- | --- |",
    ]
    for result in sorted(results, key=lambda r: r["subject"]):
        errors = _subject_errors(result)
        base, learned = errors["closed-form"], errors.get("learned")
        cells = [
            f"{errors[m]['error'].mean():.4f}" if m in errors else "–" for m in SUBJECT_METHODS
        ]
        change = jitter = "–"
        if learned is not None:
            low, high = metrics.bootstrap_mean_ci(learned["error"], base=base["error"], rng=rng)
            change = (
                f"{100 * (learned['error'].mean() / base['error'].mean() - 1):+.1f} % "
                f"[{100 * low:+.1f}, {100 * high:+.1f}]"
            )
            jitter = f"{base['jitter'].mean():.2f} → {learned['jitter'].mean():.2f}"
        lines.append(
            f"| {result['subject']} | {len(base['error'])} | {' | '.join(cells)} | {change} "
            f"| {jitter} |"
        )
    return "\n".join(lines)


def plot_subjects(results: list[dict[str, Any]], path: Path) -> Path:
    """A PNG of each held-out subject's mean error by method (:data:`SUBJECT_METHODS`), with
    95 % bootstrap intervals over the subject's episodes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rng = np.random.default_rng(2016)
    ordered = sorted(results, key=lambda r: r["subject"])
    folds = [_subject_errors(result) for result in ordered]
    figure = Figure(figsize=(max(6.0, 1.1 * len(ordered) + 2), 4.0))
    axes = figure.add_subplot()
    width = 0.8 / len(SUBJECT_METHODS)
    for k, method in enumerate(SUBJECT_METHODS):
        # Per subject: the mean and its interval's lower and upper reach (cm); NaN: no row.
        bars = np.full((len(folds), 3), np.nan)
        for i, errors in enumerate(folds):
            if method in errors:
                values = errors[method]["error"]
                low, high = metrics.bootstrap_mean_ci(values, rng=rng)
                bars[i] = 100 * np.array([values.mean(), values.mean() - low, high - values.mean()])
        x = np.arange(len(folds)) + (k - (len(SUBJECT_METHODS) - 1) / 2) * width
        axes.bar(x, bars[:, 0], width, label=method)
        axes.errorbar(x, bars[:, 0], yerr=np.nan_to_num(bars[:, 1:].T), fmt="none", ecolor="k",
                      elinewidth=0.8, capsize=2)  # fmt: skip
    axes.set_xticks(np.arange(len(ordered)), [r["subject"] for r in ordered])
    axes.set_xlabel("held-out subject")
    axes.set_ylabel("mean error, FPG Eq. 13 (cm)")
    axes.set_title("UI-PRMD, leave subjects out (95 % CI over episodes)")
    axes.legend(fontsize=8, ncols=len(SUBJECT_METHODS), loc="upper center",
                bbox_to_anchor=(0.5, -0.14))  # fmt: skip
    figure.tight_layout()
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=110)
    return path


def uiprmd_protocol(args: argparse.Namespace) -> str:
    """The UI-PRMD leave-subjects-out protocol (see the module docstring)."""
    folder = args.out / "uiprmd"
    folder.mkdir(parents=True, exist_ok=True)
    imported = real_kinect.imported_uiprmd(args.work, args.data.parent)
    excluded = [s for s in args.exclude_training.split(",") if s]
    known = real_kinect.by_subject(imported / "recordings")
    unknown = sorted(set(excluded) - set(known))
    if unknown:
        raise SystemExit(
            f"--exclude-training: no subject {', '.join(unknown)} in {imported} "
            f"(it has {', '.join(sorted(known))})"
        )
    command = "python scripts/learned_samplers.py " + " ".join(
        shlex.quote(a) for a in (args.argv or [])
    )
    tasks = [
        {
            "imported": str(imported),
            "out": str(folder),
            "subject": subject,
            "seeds": [int(s) for s in args.seeds.split(",")],
            "thres1": args.uiprmd_thres1,
            "blend": args.sensor_blend,
            "train_reps": args.train_reps,
            "exclude_training": excluded,
            "reps": args.reps,
            "epochs": args.epochs,
            "hidden": [int(w) for w in args.hidden.split(",")],
            "features": args.features,
            "model": args.model,
            "correct": args.correction,
            "cross_fit": args.cross_fit,
            "command": command,
        }
        for subject in args.subjects.split(",")
    ]
    start = time.perf_counter()
    results = []
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for result in pool.map(_uiprmd_fold, tasks):
            print(
                f"held out {result['subject']} (validation {result['validation_subject']}): "
                f"{result['frames']} training frames, data {result['data_cpu_s']:.0f} s CPU, "
                f"training {json.dumps(result['train_cpu_s'])} s CPU, offset kept "
                f"(mean_scale) {json.dumps(result['mean_scale'])}",
                file=sys.stderr,
                flush=True,
            )
            results.append(result)
    (folder / "results.json").write_text(json.dumps(results, indent=1))
    wall = time.perf_counter() - start
    episodes = len({r["episode"] for res in results for r in res["rows"]})
    report = (
        f"### uiprmd (leave-subjects-out, held out {args.subjects}, {episodes} episodes, "
        f"seeds {args.seeds}, sensor blend {args.sensor_blend}, temporal defaults"
        f"{', trained without ' + args.exclude_training if args.exclude_training else ''})\n\n"
        f"{uiprmd_table(results)}\n\nPer held-out subject:\n\n{uiprmd_subject_table(results)}"
        f"\n\nWall time {wall:.0f} s ({args.workers} workers); "
        f"training CPU per sampler: "
        f"{np.mean([v for res in results for v in res['train_cpu_s'].values()]):.0f} s, data "
        f"CPU per fold {np.mean([res['data_cpu_s'] for res in results]):.0f} s.\n"
    )
    (folder / "table.md").write_text(report)
    plot_subjects(results, folder / "per_subject.png")
    print(report, flush=True)
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "learned")
    parser.add_argument("--protocols", default="embedded,bandai")
    parser.add_argument("--data", type=Path, default=DATA, help="bandai_namco folder")
    parser.add_argument("--eval-takes", type=int, default=4)
    parser.add_argument("--max-frames", type=int, default=150)
    parser.add_argument("--sup-timesteps", type=int, default=20_000)
    parser.add_argument("--rl-timesteps", type=int, default=100_000)
    group = parser.add_argument_group("uiprmd protocol")
    group.add_argument("--work", type=Path, default=Path("runs/real_kinect"), help="import folder")
    group.add_argument("--subjects", default="s01,s02,s03,s04,s05,s06,s07,s08")
    group.add_argument("--seeds", default="0,1,2", help="training seeds")
    group.add_argument("--reps", type=int, default=1, help="scored repetitions per exercise")
    group.add_argument(
        "--train-reps", type=int, default=0, help="training reps per exercise (0: all, default)"
    )
    group.add_argument(
        "--exclude-training",
        default="",
        metavar="LIST",
        help="subjects no fold trains on (database, sensor map, sampler), still scored when "
        "held out, e.g. s05 (its hip markers are flagged by import-uiprmd); default: none",
    )
    group.add_argument("--epochs", type=int, default=40)
    group.add_argument("--hidden", default="256,256", help="MLP layer widths")
    group.add_argument("--features", default="all", choices=("all", "latent"))
    group.add_argument(
        "--model",
        default="linear",
        choices=("linear", "mlp"),
        help="linear pose-space sampler (default) or the supervised MLP",
    )
    group.add_argument(
        "--correction",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the linear sampler learns an output correction from its own outputs of the "
        "training groups (default: yes; scored also without it, as 'uncorrected')",
    )
    group.add_argument(
        "--cross-fit",
        action="store_true",
        help="the correction learns from each training group's outputs by the sampler fitted "
        "without that group (policies.pose_sampler.out_of_group_samplers) instead of the "
        "sampler's own outputs of its training data",
    )
    group.add_argument("--uiprmd-thres1", type=float, default=0.1)
    group.add_argument("--sensor-blend", type=float, default=0.5)
    group.add_argument("--workers", type=int, default=1)
    group.add_argument(
        "--report-only", action="store_true", help="table of the finished folds in --out, no run"
    )
    group = parser.add_argument_group("sim protocol (also --seeds, --epochs, --hidden, --features)")
    group.add_argument("--sim-eval-takes", type=int, default=8, help="held-out takes scored")
    group.add_argument("--sim-train-frames", type=int, default=100, help="frames per stream")
    group.add_argument("--sim-train-scenarios", default=SCENARIOS)
    group.add_argument("--sim-val-share", type=float, default=0.1)
    group.add_argument(
        "--sim-folds", type=int, default=2, help="folds of the nested data collection (2)"
    )
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    args.out.mkdir(parents=True, exist_ok=True)
    reports = []
    wanted = [p.strip() for p in args.protocols.split(",") if p.strip()]
    if args.report_only:  # the table of the folds a (possibly stopped) run has finished
        folds = sorted((args.out / "uiprmd").glob("fold_*.json"))
        results = [json.loads(path.read_text()) for path in folds]
        print(f"{len(results)} fold(s): {', '.join(r['subject'] for r in results)}\n")
        print(uiprmd_table(results))
        print(f"\nPer held-out subject:\n\n{uiprmd_subject_table(results)}")
        if results:
            print(f"\n{plot_subjects(results, args.out / 'uiprmd' / 'per_subject.png')}")
        return 0
    if "sim" in wanted:
        reports.append(sim_protocol(args))
    if "uiprmd" in wanted:
        reports.append(uiprmd_protocol(args))
    if "embedded" in wanted:
        reports.append(protocol("embedded", args.out, "default", [], ["default"], args, []))
    if "bandai" in wanted:
        folder = args.out / "bandai"
        split = folder / "split"
        log = folder / "log.txt"
        folder.mkdir(parents=True, exist_ok=True)
        sh(
            [sys.executable, "scripts/holdout_split.py", "--data", str(args.data),
             "--out-dir", str(split), "--eval-count", str(args.eval_takes)],
            log,
        )  # fmt: skip
        graph = folder / "graph.npz"
        if not graph.is_file():
            sh(["fpg-gym", "build-graph", f"@{split}/graph_takes.txt", "--out", str(graph),
                "--quiet"], log)  # fmt: skip
        eval_takes = (split / "eval_takes.txt").read_text().split()
        reports.append(
            protocol(
                "bandai",
                args.out,
                str(graph),
                [f"@{split}/graph_takes.txt"],
                eval_takes,
                args,
                ["--max-frames", str(args.max_frames)],
            )
        )
    (args.out / "tables.md").write_text("\n".join(reports))
    return 0


if __name__ == "__main__":
    sys.exit(main())
