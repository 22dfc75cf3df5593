"""The UI-PRMD leave-subjects-out protocol: real Kinect v2 streams against Vicon, each held-out
subject scored with a database, sensor map and samplers fitted on the other subjects only
(:mod:`real_kinect`'s machinery; ``scripts/learned_samplers.py`` describes the rows)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import real_kinect  # scripts/real_kinect.py: the UI-PRMD leave-subjects-out machinery

from fpg_gym.definitions import DefinitionMap
from fpg_gym.io.recording import load_recording
from policies.training import TrainConfig, collect_imitation_data, train_sampler
from sampler_study import study_command
from sampler_study.scoring import score
from sampler_study.tables import (
    plot_subjects,
    repetition_table,
    uiprmd_subject_table,
    uiprmd_table,
)
from sampler_study.training import sampler_spec, train_seeds

#: A UI-PRMD recording's subject in its file name (``mMM_sSS_eEE``): train-sampler's groups.
SUBJECT_PATTERN = "_(s[0-9]+)_"


def _training_data(
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


def train_linear(
    task: dict[str, Any],
    imported: Path,
    subjects: dict[str, list[Path]],
    held_out: str,
    train_subjects: list[str],
) -> tuple[dict[str, Any], Any, Any]:
    """One fold's linear sampler, trained as ``fpg-gym train-sampler --kind linear --target
    bones --follow anchor --recordings ... --group-pattern '_(s[0-9]+)_' --val-share 0``
    trains it (:func:`policies.training.train_sampler`, the same code): on the training
    subjects' recordings, with the fold's graph and sensor map written to files (the
    evaluation's; each training subject's data and output correction collected with a graph and
    map of the other training subjects, cross-fitted). Returns the trained models' record,
    the graph and the sensor map (as the file holds it)."""
    folder = Path(task["out"]) / f"fold_{held_out}"
    folder.mkdir(parents=True, exist_ok=True)
    excluded = set(task["exclude_training"])
    graph = real_kinect.uiprmd_graph(imported, {held_out, *excluded}, task["thres1"])
    graph_path = graph.save(folder / "graph.npz")
    train_recs = [load_recording(p) for s in train_subjects for p in subjects[s]]
    sensor_map, _, _ = real_kinect.fold_maps("uiprmd", graph, train_recs, True, False)
    assert sensor_map is not None
    map_path = folder / "sensor_map.json"
    sensor_map.save(map_path)
    reps = task["train_reps"]
    # In file-name order, as a folder or a shell pattern gives them to train-sampler.
    paths = sorted(p for s in train_subjects for p in real_kinect.repetitions(subjects[s], reps))
    config = TrainConfig(
        kind="linear",
        out=str(folder / "sampler_linear"),
        graph=str(graph_path),
        recordings=[str(p) for p in paths],
        group_pattern=SUBJECT_PATTERN,
        sensor_map=str(map_path),
        sensor_blend=task["blend"],
        val_share=0.0,
        target="bones",
        follow="anchor",
        correction=task["correct"],
        progress=False,
    )
    t0 = time.process_time()
    result = train_sampler(
        config, log=lambda line: print(f"{held_out}: {line}", file=sys.stderr, flush=True)
    )
    cpu = time.process_time() - t0
    result.sampler.spec.training["command"] = task["command"]
    result.sampler.save(result.model)
    history = result.history[0]
    trained = {
        "models": {"linear": result.model},
        "train_cpu_s": {"linear": cpu},
        "mean_scale": {},
        "frames": history["linear"]["frames"],
        "linear": history["linear"],
        "correction": history.get("correction", {}),
        "seconds": result.seconds,
    }
    return trained, graph, DefinitionMap.load(map_path)


def run_fold(task: dict[str, Any]) -> dict[str, Any]:
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
    if task["model"] == "linear":
        trained, graph, sensor_map = train_linear(
            task, imported, subjects, held_out, train_subjects
        )
        data_cpu = 0.0  # counted in the training's CPU (train-sampler collects its data)
    else:
        spec = sampler_spec(task)
        t0 = time.process_time()
        collected = {
            s: _training_data(
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
        trained = train_seeds(
            spec, [data[s] for s in train_subjects if s != val_subject], data[val_subject], task,
            held_out, info,
        )  # fmt: skip
        collected.clear()  # the nested graphs
        graph = real_kinect.uiprmd_graph(imported, {held_out, *excluded}, thres1)
        train_recs = [load_recording(p) for s in train_subjects for p in subjects[s]]
        sensor_map, _, _ = real_kinect.fold_maps("uiprmd", graph, train_recs, True, False)
    episodes = [
        (path.stem, load_recording(path))
        for path in real_kinect.repetitions(subjects[held_out], task["reps"])
    ]
    rows = score(graph, {**options, "sensor_map": sensor_map}, trained["models"], episodes)
    result = {
        "subject": held_out,
        "validation_subject": None if task["model"] == "linear" else val_subject,
        "data_cpu_s": data_cpu,
        **trained,
        "rows": rows,
    }
    # Each fold's rows as soon as they exist (a stopped run keeps its finished folds).
    (Path(task["out"]) / f"fold_{held_out}.json").write_text(json.dumps(result, indent=1))
    return result


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
    command = study_command(args)
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
            "command": command,
        }
        for subject in args.subjects.split(",")
    ]
    start = time.perf_counter()
    results = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for result in pool.map(run_fold, tasks):
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
        f"\n\nBy repetitions scored:\n\n{repetition_table(results)}"
        f"\n\nWall time {wall:.0f} s ({args.workers} workers); "
        f"training CPU per sampler: "
        f"{np.mean([v for res in results for v in res['train_cpu_s'].values()]):.0f} s, data "
        f"CPU per fold {np.mean([res['data_cpu_s'] for res in results]):.0f} s.\n"
    )
    (folder / "table.md").write_text(report)
    plot_subjects(results, folder / "per_subject.png")
    print(report, flush=True)
    return report


def report_finished(out: Path) -> None:
    """Print the tables of the folds a (possibly stopped) run has finished in ``out``."""
    folds = sorted((out / "uiprmd").glob("fold_*.json"))
    if not folds:
        where = out / "uiprmd"
        print(f"error: --report-only: no finished fold (fold_*.json) in {where}", file=sys.stderr)
        raise SystemExit(2)
    results = [json.loads(path.read_text()) for path in folds]
    print(f"{len(results)} fold(s): {', '.join(r['subject'] for r in results)}\n")
    print(uiprmd_table(results))
    print(f"\nPer held-out subject:\n\n{uiprmd_subject_table(results)}")
    print(f"\nBy repetitions scored:\n\n{repetition_table(results)}")
    print(f"\n{plot_subjects(results, out / 'uiprmd' / 'per_subject.png')}")
