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
  ``--no-correction``), beside ``closed-form`` (the
  anchor, 1), ``local-search`` (2,000), the raw sensor and two oracles that see the truth (its
  latent point by joints and by bones); 95 % confidence intervals by a bootstrap over episodes.
* ``sim``: the simulated held-out Bandai protocol (:func:`sim_protocol`), the same models and
  rows.
* ``rl``: an RL sampler as a search accelerator (:func:`rl_protocol`): PPO trained on the
  energy's gain without the closed form (:data:`RL_ACCELERATOR`), then ``learned+search:`` (200
  evaluations) against the local search at 2,000 and 200, the untrained policy and the zero
  action, paired per episode, on the embedded held-out clips (``--rl-model PATH``: evaluate
  that model instead of training one).

Usage::

    python scripts/learned_samplers.py --out runs/learned [--protocols embedded,bandai]
    python scripts/learned_samplers.py --protocols uiprmd --workers 2 --out runs/learned
    python scripts/learned_samplers.py --protocols sim --out runs/learned
    python scripts/learned_samplers.py --protocols rl --out runs/learned
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
from fpg_gym.definitions import DefinitionMap
from fpg_gym.filters import make_filter
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import load_clips
from fpg_gym.io.recording import load_recording
from fpg_gym.methods import MethodRunner
from fpg_gym.reconstruct import Reconstructor
from policies.learned_optimizers import LearnedSampler
from policies.output_correction import CorrectionSource, describe_correction, learn_correction
from policies.pose_sampler import LINEAR_FEATURES, describe_fit, fit_linear
from policies.sampler import FEATURE_SETS, SamplerSpec
from policies.supervised import SupervisedSampler
from policies.supervised_fit import fit_supervised
from policies.training import (
    TrainConfig,
    collect_imitation_data,
    simulate_episodes,
    train_sampler,
    truth_latent,
)

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "bandai_namco"
SCENARIOS = "front-many,left45-many,right45-many"
#: A UI-PRMD recording's subject in its file name (``mMM_sSS_eEE``): train-sampler's groups.
SUBJECT_PATTERN = "_(s[0-9]+)_"


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
    training groups (:func:`policies.output_correction.learn_correction`); saved as
    ``{out}/sampler_{name}_linear``."""

    t0 = time.process_time()
    sampler, report = fit_linear(spec, [(d.observations, d.actions, d.episodes) for d in groups])
    cpu = time.process_time() - t0
    correction_report: dict[str, Any] = {}
    if sources and task.get("correct", True):
        t1 = time.process_time()
        bare = LearnedSampler(sampler, samples=1, correct_output=False)
        correction, correction_report = learn_correction(
            [
                CorrectionSource(graph, options, recordings, bare)
                for graph, options, recordings, _ in sources
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


def _row(truth: np.ndarray, poses: np.ndarray, recording: Any) -> dict[str, float]:
    """One episode's figures: FPG Eq. 13 (``error``), MPJPE absolute, root-relative and
    Procrustes-aligned, jitter, the largest settled bone range (mm) and the mean bone-length
    error against the truth (mm)."""
    spread = metrics.settled_bone_spread(poses, timestamps=recording.timestamps)
    return {
        "error": float(metrics.frame_error(truth, poses).mean()),
        "mpjpe": metrics.mpjpe(truth, poses),
        "mpjpe_root": metrics.mpjpe(truth, poses, "root"),
        "mpjpe_pa": metrics.mpjpe(truth, poses, "procrustes"),
        "jitter": float(np.nanmean(metrics.jitter(poses, timestamps=recording.timestamps))),
        "spread_mm": float(1000 * np.nanmax(spread)) if np.isfinite(spread).any() else np.nan,
        "bone_error_mm": float(1000 * metrics.bone_length_error(truth, poses).mean()),
    }


def _score(
    graph: Any, options: dict[str, Any], models: dict[str, str], episodes: list[tuple[str, Any]]
) -> list[dict[str, Any]]:
    """Every method on every ``(name, recording)``: the sensor's baselines (raw, the SDK's
    Holt filter, the sensor through the sensor map and that filtered by Holt), closed-form,
    local-search, each model's ``learned:`` and ``learned+search:`` (and a linear model's
    ``uncorrected``, an MLP's mean alone) and the bones oracle: :func:`_row`'s figures and CPU
    ms per frame."""

    def mean_only(path: str, **_: Any) -> Any:
        return LearnedSampler(path, samples=1)

    def uncorrected(path: str, **_: Any) -> Any:
        return LearnedSampler(path, correct_output=False)

    optimizers.register_prefix("mean-only", mean_only, overwrite=True)
    optimizers.register_prefix("uncorrected", uncorrected, overwrite=True)
    methods = ["raw", "holt", "fpg:closed-form", "fpg:local-search"]
    for path in models.values():
        methods += [f"fpg:learned:{path}", f"fpg:learned+search:{path}"]
        linear = LearnedSampler(path).sampler.spec.kind == "linear"
        # A linear model's mean alone is its learned: (the posterior picks the mean).
        methods.append(f"fpg:uncorrected:{path}" if linear else f"fpg:mean-only:{path}")
    sensor_map = options.get("sensor_map")
    rows = []
    with MethodRunner(graph, budget=2000, reconstructor_options=options) as runner:
        for name, recording in episodes:
            truth = recording.ground_truth
            assert truth is not None
            baselines: dict[str, Any] = {}
            if sensor_map is not None:  # the sensor in the truth's definitions, no database
                mapped = sensor_map.apply(recording.positions)
                holt = make_filter("holt")
                baselines["mapped"] = mapped
                baselines["mapped+holt"] = holt.filter_sequence(
                    mapped, recording.states, recording.timestamps
                )
            for method in [*methods, *baselines, "oracle-bones"]:
                c0 = time.process_time()
                if method == "oracle-bones":
                    poses = _oracle(graph, options, recording, "bones")
                elif method in baselines:
                    poses = baselines[method]
                else:
                    poses = runner.run(method, recording, seed=0).poses
                cpu = 1000 * (time.process_time() - c0) / recording.num_frames
                rows.append(
                    {
                        "episode": name,
                        "method": method,
                        **_row(truth, poses, recording),
                        "cpu_ms": cpu,
                    }
                )
    return rows


def _uiprmd_linear(
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
    if task["model"] == "linear":
        trained, graph, sensor_map = _uiprmd_linear(
            task, imported, subjects, held_out, train_subjects
        )
        data_cpu = 0.0  # counted in the training's CPU (train-sampler collects its data)
    else:
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
    rows = _score(graph, {**options, "sensor_map": sensor_map}, trained["models"], episodes)
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
    # with the graph of the other folds.
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


#: Figures of a row (:func:`_row`) the tables pool per episode.
FIGURES = ("error", "mpjpe", "mpjpe_root", "mpjpe_pa", "jitter", "spread_mm", "bone_error_mm")
#: Evaluations per frame of each row's method (200 for the learned ones).
EVALUATIONS = {
    "raw": "–",
    "holt": "–",
    "mapped": "–",
    "mapped+holt": "–",
    "closed-form": "1",
    "local-search": "2,000",
    "mean-only": "1",
    "oracle-bones": "– (sees the truth)",
}


def _by_method(results: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """``{row name: {episode: {figure: value}}}``: each figure of :data:`FIGURES` (NaN where a
    fold file lacks it) and ``cpu_ms``, averaged over the seeds of one method; a row per seed
    too (``"NAME (seed S)"``) when there are several."""
    models = {res["subject"]: res["models"] for res in results}
    several = len({seed for fold in models.values() for seed in fold}) > 1
    by: dict[str, dict[str, dict[str, list[float]]]] = {}
    for result in results:
        for row in result["rows"]:
            name, seed = _method_kind(row["method"], models)
            keys = [name] + ([f"{name} (seed {seed})"] if seed is not None and several else [])
            for key in keys:
                slot = by.setdefault(key, {}).setdefault(row["episode"], {})
                for figure in (*FIGURES, "cpu_ms"):
                    slot.setdefault(figure, []).append(float(row.get(figure, np.nan)))
    return {
        name: {
            episode: {figure: float(np.mean(values)) for figure, values in slot.items()}
            for episode, slot in episodes.items()
        }
        for name, episodes in by.items()
    }


def _change(values: np.ndarray, base: np.ndarray, rng: np.random.Generator) -> str:
    """The change of the mean of ``values`` against ``base`` (paired episodes) with its 95 %
    bootstrap interval."""
    low, high = metrics.bootstrap_mean_ci(values, base=base, rng=rng)
    return f"{100 * (values.mean() / base.mean() - 1):+.1f} % [{100 * low:+.1f}, {100 * high:+.1f}]"


def uiprmd_table(results: list[dict[str, Any]], episodes: list[str] | None = None) -> str:
    """The table of every method over the episodes (``episodes``: a subset of them): FPG
    Eq. 13 and MPJPE with their 95 % CIs and their changes against closed-form (paired CIs),
    root-relative and Procrustes-aligned MPJPE, jitter, the largest settled bone range over
    the episodes, the bone-length error against the truth, CPU ms per frame; learned rows pool
    the seeds (one row per seed below, when there are several)."""
    by = _by_method(results)
    order = sorted(by["closed-form"]) if episodes is None else sorted(episodes)
    rng = np.random.default_rng(2016)

    def figure(name: str, key: str) -> np.ndarray:
        return np.array([by[name][e][key] for e in order])

    lines = [
        "| method | evaluations/frame | Eq. 13 (m) [95 % CI] | vs closed-form [95 % CI] | "
        "MPJPE (m) [95 % CI] | vs closed-form [95 % CI] | root-relative MPJPE (m) | PA-MPJPE "
        "(m) | jitter (m/s²) | settled bone range, max (mm) | bone length error (mm) | CPU "
        "ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in by:
        cells = []
        for key in ("error", "mpjpe"):
            values, base = figure(name, key), figure("closed-form", key)
            lo, hi = metrics.bootstrap_mean_ci(values, rng=rng)
            cells += [f"{values.mean():.4f} [{lo:.4f}, {hi:.4f}]", _change(values, base, rng)]
        cells += [
            f"{figure(name, 'mpjpe_root').mean():.4f}",
            f"{figure(name, 'mpjpe_pa').mean():.4f}",
            f"{figure(name, 'jitter').mean():.2f}",
            f"{np.nanmax(figure(name, 'spread_mm')):.1f}",
            f"{figure(name, 'bone_error_mm').mean():.1f}",
            f"{np.median(figure(name, 'cpu_ms')):.2f}",
        ]
        kind = name.split(" ")[0]
        lines.append(f"| {name} | {EVALUATIONS.get(kind, '200')} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _subject_errors(result: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
    """One fold's episode figures by method (seeds pooled): ``{method: {figure: (episodes,)}}``,
    episodes in the same (sorted) order for every method."""
    by = _by_method([result])
    return {
        name: {key: np.array([episodes[e][key] for e in sorted(episodes)]) for key in FIGURES}
        for name, episodes in by.items()
    }


SUBJECT_METHODS = ("closed-form", "local-search", "learned", "learned+search", "oracle-bones")


def uiprmd_subject_table(results: list[dict[str, Any]]) -> str:
    """Per held-out subject: closed-form's and ``learned:``'s Eq. 13 and MPJPE, ``learned:``'s
    changes against closed-form with their paired 95 % CIs over the subject's episodes, the
    jitter of both and ``learned:``'s largest settled bone range."""
    rng = np.random.default_rng(2016)
    lines = [
        "| held out | episodes | closed-form Eq. 13 (m) | learned Eq. 13 (m) | change [95 % CI] "
        "| closed-form MPJPE (m) | learned MPJPE (m) | change [95 % CI] | jitter closed-form "
        "→ learned (m/s²) | learned settled bone range, max (mm) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for result in sorted(results, key=lambda r: r["subject"]):
        errors = _subject_errors(result)
        base, learned = errors["closed-form"], errors.get("learned")
        if learned is None:
            continue
        cells = []
        for key in ("error", "mpjpe"):
            cells += [
                f"{base[key].mean():.4f}",
                f"{learned[key].mean():.4f}",
                _change(learned[key], base[key], rng),
            ]
        lines.append(
            f"| {result['subject']} | {len(base['error'])} | {' | '.join(cells)} | "
            f"{base['jitter'].mean():.2f} → {learned['jitter'].mean():.2f} | "
            f"{np.nanmax(learned['spread_mm']):.1f} |"
        )
    return "\n".join(lines)


#: Disjoint sets of UI-PRMD repetitions (``eNN`` of a recording's name): the repetitions
#: scored stand in for seeds where training is deterministic.
REPETITION_SETS = (("e01", "e04", "e07", "e10"), ("e02", "e05", "e08"), ("e03", "e06", "e09"))


def repetition_table(results: list[dict[str, Any]]) -> str:
    """``learned:`` against closed-form (Eq. 13 and MPJPE, paired 95 % CIs) on each set of
    :data:`REPETITION_SETS` that has two episodes or more (empty when none has)."""
    by = _by_method(results)
    if "learned" not in by:
        return ""
    rng = np.random.default_rng(2016)
    lines = [
        "| repetitions | episodes | learned vs closed-form, Eq. 13 [95 % CI] | MPJPE [95 % CI] |",
        "| --- | --- | --- | --- |",
    ]
    for chosen in REPETITION_SETS:
        order = sorted(e for e in by["closed-form"] if e.rsplit("_", 1)[-1] in chosen)
        if len(order) < 2:
            continue
        cells = [
            _change(
                np.array([by["learned"][e][key] for e in order]),
                np.array([by["closed-form"][e][key] for e in order]),
                rng,
            )
            for key in ("error", "mpjpe")
        ]
        lines.append(f"| {', '.join(chosen)} | {len(order)} | {' | '.join(cells)} |")
    return "\n".join(lines) if len(lines) > 2 else ""


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


#: ``train-sampler`` settings of the RL search accelerator (``--protocols rl``): no closed
#: form (the Gaussian centred on the search's start), the energy's gain as the reward, the
#: latent coordinates of the sensor, prediction and start with the reliabilities as features,
#: and PPO settings for a one-frame problem (no discount).
RL_ACCELERATOR: dict[str, Any] = {
    "kind": "rl",
    "algo": "ppo",
    "graph": "default",
    "anchor": "none",
    "action_mode": "delta",
    "reward": "energy-gain",
    "features": ["x0", "z_kinect", "z_prediction", "reliability", "latent_std", "latent_mask"],
    "hyperparameters": {
        "learning_rate": 1e-3,
        "n_steps": 2048,
        "batch_size": 256,
        "n_epochs": 10,
        "gamma": 0.0,
        "gae_lambda": 0.0,
        "net_arch": [64, 64],
    },
    "timesteps": 300_000,
    "eval_every": 75_000,
}


def rl_protocol(args: argparse.Namespace) -> str:
    """An RL sampler's proposals against the local search (module docstring): train one
    (unless ``--rl-model``), then every agent on the embedded held-out clips x the ``*-many``
    scenarios x ``--rl-eval-seeds``, each episode with the per-frame problem (temporal stage
    off, as the env's), errors paired against ``local-search`` (2,000) and against the
    untrained policy and the zero action."""
    import optimizers.local_search as local
    from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
    from fpg_gym.graph import load_graph
    from fpg_gym.reconstruct import TemporalConfig
    from policies.learned_optimizers import LearnedSearch
    from policies.loading import load_sampler
    from policies.rl import UNTRAINED_CHECKPOINT, zero_action
    from policies.training import training_clips

    folder = args.out / "rl"
    folder.mkdir(parents=True, exist_ok=True)
    model = args.rl_model
    trained_note = f"model {model}"
    if model is None:
        model = str(folder / "sampler_rl")
        c0, w0 = time.process_time(), time.perf_counter()
        train_sampler(TrainConfig(out=model, seed=args.rl_seed, progress=False, **RL_ACCELERATOR))
        trained_note = (
            f"trained in {time.process_time() - c0:.0f} s CPU, {time.perf_counter() - w0:.0f} s "
            f"wall (seed {args.rl_seed})"
        )
    trained = load_sampler(model)
    untrained = load_sampler(f"{model}.checkpoints/{UNTRAINED_CHECKPOINT}")
    agents: dict[str, Any] = {
        "local-search": (2000, local.LocalSearch()),
        "local-search (200)": (200, local.LocalSearch(iterations=2)),
        "closed-form": (1, "closed-form"),
        "learned+search": (200, LearnedSearch(trained)),
        "learned": (200, LearnedSampler(trained)),
        "mean alone": (1, LearnedSampler(trained, samples=1)),
        "untrained, learned+search": (200, LearnedSearch(untrained)),
        "zero action, learned+search": (200, LearnedSearch(zero_action(trained))),
    }
    graph = load_graph("default", exclude=DEFAULT_HOLDOUT_CLIPS)
    clips = training_clips(list(DEFAULT_HOLDOUT_CLIPS))
    seeds = [int(s) for s in args.rl_eval_seeds.split(",")]
    recordings = simulate_episodes(clips, SCENARIOS.split(","), seeds)
    errors: dict[str, list[float]] = {name: [] for name in agents}
    energies: dict[str, list[float]] = {name: [] for name in agents}
    c0 = time.process_time()
    for i, recording in enumerate(recordings):
        with Reconstructor(graph, ragdoll=False, temporal=TemporalConfig.off()) as reconstructor:
            for name, (_, agent) in agents.items():
                result = reconstructor.reconstruct(recording, agent, rng=i)
                errors[name].append(
                    float(metrics.frame_error(recording.ground_truth, result.poses).mean())
                )
                energies[name].append(float(result.arrays()["energy"].mean()))
    rng = np.random.default_rng(2016)
    base = np.array(errors["local-search"])
    lines = [
        "| method | evaluations/frame | mean error (m) [95 % CI] | vs local-search [95 % CI] "
        "| lower than local-search on | mean energy |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, (evaluations, _) in agents.items():
        values = np.array(errors[name])
        low, high = metrics.bootstrap_mean_ci(values, rng=rng)
        lines.append(
            f"| {name} | {evaluations:,} | {values.mean():.4f} [{low:.4f}, {high:.4f}] | "
            f"{_change(values, base, rng)} | {(values < base).sum()} of {len(values)} | "
            f"{np.mean(energies[name]):.4f} |"
        )
    learned = np.array(errors["learned+search"])
    against = [
        f"against {name}: {_change(learned, np.array(errors[name]), rng)}, lower on "
        f"{(learned < np.array(errors[name])).sum()} of {len(learned)}"
        for name in (
            "untrained, learned+search",
            "zero action, learned+search",
            "local-search (200)",
        )
    ]
    report = (
        f"### RL sampler as a search accelerator ({len(recordings)} episodes: the embedded "
        f"held-out clips x {SCENARIOS} x seeds {args.rl_eval_seeds}, "
        f"{sum(r.num_frames for r in recordings)} frames; {trained_note}; evaluation "
        f"{time.process_time() - c0:.0f} s CPU)\n\n"
        + "\n".join(lines)
        + "\n\n`learned+search` "
        + "; ".join(against)
        + ".\n"
    )
    (folder / "table.md").write_text(report)
    (folder / "errors.json").write_text(json.dumps({"errors": errors, "energies": energies}))
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
    group = parser.add_argument_group("rl protocol")
    group.add_argument("--rl-model", default=None, help="evaluate this model (default: train one)")
    group.add_argument("--rl-seed", type=int, default=0, help="training seed (0)")
    group.add_argument(
        "--rl-eval-seeds", default="0,1,2", help="simulator seeds of the evaluated episodes"
    )
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
        print(f"\nBy repetitions scored:\n\n{repetition_table(results)}")
        if results:
            print(f"\n{plot_subjects(results, args.out / 'uiprmd' / 'per_subject.png')}")
        return 0
    if "sim" in wanted:
        reports.append(sim_protocol(args))
    if "rl" in wanted:
        reports.append(rl_protocol(args))
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
