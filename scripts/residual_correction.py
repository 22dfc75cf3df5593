"""Issue 19 exploration: how much of the closed-form pipeline's error a learned model can remove.

A linear (ridge) model maps what a frame's output and input say, in the output's normalised
frame (its root at the origin, facing +Z), to the truth's root-relative joints minus the
output's: the output pose (60), the sensor pose (60, joints not tracked zeroed), the reliability
(20) and the tracking states (one-hot, 60). The corrected output is the output plus the
prediction. The features, targets and smoothing are the product's
(:mod:`fpg_gym.reconstruct.output_correction`), which a linear sampler's ``learned:`` now
applies after its output (:mod:`policies.output_correction`); this script applies it to the
closed form's output too, or to a sampler model's without its own correction.

Protocols (``--protocol``):

* ``sim``: Bandai Namco dataset-1, the seed-2016 take split (``fpg_gym.core.holdout.split_takes``).
  The graph takes are split in two halves (seeded); the training streams are one half's takes
  simulated in ``front-many`` and ``left45-many`` (first 150 frames) and reconstructed with a
  graph of the other half, so no truth is a candidate; the last tenth of those streams picks the
  ridge penalty and the smoothing, then the model is fitted on all of them. Scored on the first
  8 held-out takes x ``front-many``, ``left45-many``, ``right45-many`` (150 frames) with a graph
  of all graph takes, as ``scripts/learned_samplers.py``'s simulated protocol.
* ``uiprmd``: UI-PRMD leave one subject out, as ``scripts/real_kinect.py``: for each held-out
  subject, a graph of the other seven subjects' Vicon joint centres (thres1 0.1) and a Kinect v2
  sensor map fitted on them; training data: every repetition of each of them (``--train-reps N``:
  N per exercise), reconstructed with a graph that also lacks that subject; the penalty and the
  smoothing are chosen by leave-one-subject-out cross-validation over the seven, and the model is
  fitted on all seven; scored on one repetition per exercise of the held-out subject.

With ``--sampler-models DIR`` (``scripts/learned_samplers.py``'s UI-PRMD folder) each fold
corrects the output of its own linear sampler (``learned:DIR/sampler_{subject}_linear``, trained
on the same seven subjects, so its outputs on them are in-sample) instead of the closed form's,
and the corrected output is also compared with the closed form's.

The corrections are smoothed causally per episode (``c_t = alpha p_t + (1 - alpha) c_{t-1}``,
``alpha`` in :data:`SMOOTHING`, 1 for none), since a per-frame correction adds jitter.

Usage::

    python scripts/residual_correction.py --protocol sim
    python scripts/residual_correction.py --protocol uiprmd --work runs/real_kinect  # ~25 min
    python scripts/residual_correction.py --protocol uiprmd --sensor-blend 0.5  # samplers' pipeline
    python scripts/residual_correction.py --protocol uiprmd --sensor-blend 0.5 \
        --sampler-models runs/learned/uiprmd  # the linear sampler's output, corrected
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # this checkout's fpg_gym
sys.path.insert(0, str(REPO / "scripts"))  # real_kinect's UI-PRMD folds

from fpg_gym.core import metrics  # noqa: E402
from fpg_gym.core.holdout import split_takes  # noqa: E402
from fpg_gym.graph import FilteredPoseGraph  # noqa: E402
from fpg_gym.io import load_clips  # noqa: E402
from fpg_gym.reconstruct import Reconstructor  # noqa: E402
from fpg_gym.reconstruct.output_correction import (  # noqa: E402
    apply_correction,
    correction_frames,
    smooth_corrections,
)
from policies.ridge import fit_ridge, predict_ridge, ridge_sums  # noqa: E402

DEFAULT_DATA = REPO.parent / "shared" / "data"
PENALTIES = (1.0, 10.0, 100.0, 1000.0, 10000.0)
#: Causal smoothing of the corrections (1: none).
SMOOTHING = (1.0, 0.5, 0.25)


def frame_data(
    reconstructor: Reconstructor, recordings: list[Any], method: str = "closed-form"
) -> dict[str, Any]:
    """The pipeline's outputs of ``recordings`` with ``method`` (an optimiser name: the closed
    form, or ``learned:MODEL``) with each frame's features and target
    (:func:`~fpg_gym.reconstruct.output_correction.correction_frames`)."""
    features, targets, outputs, truths, fps, frames = [], [], [], [], [], []
    for recording in recordings:
        result = reconstructor.reconstruct(recording, method, rng=0)
        output = np.asarray(result.poses, dtype=np.float64)
        rows, target, local, placement = correction_frames(
            output, recording, result.arrays()["reliability"]
        )
        truth = np.asarray(recording.ground_truth, dtype=np.float64)[: len(output)]
        features.append(rows)
        targets.append(target)
        outputs.append(output)
        frames.append((local, placement))
        truths.append(truth)
        fps.append(float(getattr(recording, "fps", 30.0) or 30.0))
    return {
        "x": np.concatenate(features),
        "y": np.concatenate(targets),
        "outputs": outputs,
        "frames": frames,
        "truths": truths,
        "fps": fps,
    }


def corrected(data: dict[str, Any], prediction: np.ndarray, alpha: float) -> list[np.ndarray]:
    """The outputs plus the predicted corrections, back in camera space; each episode's
    corrections smoothed causally first (``c_t = alpha p_t + (1 - alpha) c_{t-1}``)."""
    counts = [len(local) for local, _ in data["frames"]]
    steps = smooth_corrections(prediction, np.repeat(np.arange(len(counts)), counts), alpha)
    parts = np.split(steps, np.cumsum(counts)[:-1])
    return [
        apply_correction(local, placement, step)
        for (local, placement), step in zip(data["frames"], parts, strict=True)
    ]


def scores(poses: list[np.ndarray], data: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Per-episode mean error (FPG Eq. 13) and jitter."""
    errors = np.array(
        [metrics.frame_error(t, p).mean() for p, t in zip(poses, data["truths"], strict=True)]
    )
    jitter = np.array(
        [np.nanmean(metrics.jitter(p, fps=f)) for p, f in zip(poses, data["fps"], strict=True)]
    )
    return errors, jitter


def merged(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """Several data sets as one."""
    return {
        "x": np.concatenate([p["x"] for p in parts]),
        "y": np.concatenate([p["y"] for p in parts]),
        "outputs": [o for p in parts for o in p["outputs"]],
        "frames": [f for p in parts for f in p["frames"]],
        "truths": [t for p in parts for t in p["truths"]],
        "fps": [f for p in parts for f in p["fps"]],
    }


def ridge(train: dict[str, Any], penalty: float) -> Any:
    """The ridge model of ``train`` (standardised features, an unpenalised intercept;
    :func:`policies.ridge.fit_ridge`) as a function of features."""
    model = fit_ridge([ridge_sums(train["x"], train["y"])], penalty)
    return lambda x: predict_ridge(model, x)


def choose(
    folds: list[tuple[dict[str, Any], dict[str, Any]]],
) -> tuple[float, float, dict[str, float]]:
    """The penalty and smoothing with the lowest mean validation error over ``folds``
    (``(train, validation)`` pairs); ``(penalty, alpha, errors by setting)``."""
    found: dict[str, float] = {}
    best: tuple[float, float, float] | None = None
    for penalty in PENALTIES:
        models = [(ridge(train, penalty), validation) for train, validation in folds]
        for alpha in SMOOTHING:
            error = float(
                np.mean(
                    [scores(corrected(v, model(v["x"]), alpha), v)[0].mean() for model, v in models]
                )
            )
            found[f"{penalty:g}/{alpha:g}"] = round(error, 5)
            if best is None or error < best[0]:
                best = (error, penalty, alpha)
    assert best is not None
    return best[1], best[2], found


def report(
    name: str,
    base: np.ndarray,
    fixed: np.ndarray,
    jb: np.ndarray,
    jf: np.ndarray,
    label: str = "closed-form",
) -> str:
    """One line: mean errors, the relative change with a paired 95 % bootstrap interval
    (``label``: what ``base`` scores)."""
    change = fixed - base
    low, high = metrics.bootstrap_mean_ci(fixed, base=base, rng=2016)
    return (
        f"{name}: {len(base)} episodes, {label} {base.mean():.4f} m -> corrected "
        f"{fixed.mean():.4f} m ({100 * (fixed.mean() / base.mean() - 1):+.1f} %, 95 % CI "
        f"[{100 * low:+.1f}, {100 * high:+.1f}]), lower on {int(np.sum(change < 0))}; jitter "
        f"{jb.mean():.2f} -> {jf.mean():.2f} m/s^2"
    )


def sim_protocol(data_root: Path, options: dict[str, Any]) -> str:
    """The simulated held-out Bandai protocol (module docstring)."""
    from policies.training import simulate_episodes

    files = sorted((data_root / "bandai_namco" / "dataset-1").glob("*.bvh"))
    graph_files, eval_files = split_takes(files)
    graph_clips = load_clips(graph_files, progress=False)
    order = np.random.default_rng(2016).permutation(len(graph_clips))
    half = [graph_clips[i] for i in sorted(order[: len(order) // 2])]
    other = [graph_clips[i] for i in sorted(order[len(order) // 2 :])]
    training = simulate_episodes(other, ["front-many", "left45-many"], [0], max_frames=150)
    cut = len(training) - max(1, len(training) // 10)
    reconstructor = Reconstructor(FilteredPoseGraph.build(half, progress=False), **options)
    train, validation = (
        frame_data(reconstructor, training[:cut]),
        frame_data(reconstructor, training[cut:]),
    )
    penalty, alpha, found = choose([(train, validation)])
    predict = ridge(merged([train, validation]), penalty)
    evaluation = simulate_episodes(
        load_clips(eval_files[:8], progress=False),
        ["front-many", "left45-many", "right45-many"],
        [0],
        max_frames=150,
    )
    graph = FilteredPoseGraph.build(graph_clips, progress=False)
    test = frame_data(Reconstructor(graph, **options), evaluation)
    base, jb = scores(test["outputs"], test)
    fixed, jf = scores(corrected(test, predict(test["x"]), alpha), test)
    print(
        f"penalty/smoothing {penalty:g}/{alpha:g} (validation errors {found}); "
        f"{len(train['x'])} training and {len(validation['x'])} validation frames"
    )
    return report("simulated held-out Bandai", base, fixed, jb, jf)


def uiprmd_protocol(
    work: Path,
    data_root: Path,
    train_reps: int,
    options: dict[str, Any],
    sampler_models: Path | None = None,
) -> str:
    """UI-PRMD leave one subject out (module docstring); with ``sampler_models`` (the folder of
    ``scripts/learned_samplers.py``'s UI-PRMD run) each fold corrects the output of its linear
    sampler, ``learned:`` with ``sampler_{subject}_linear``, instead of the closed form's."""
    import real_kinect

    from fpg_gym.io.recording import load_recording

    imported = real_kinect.imported_uiprmd(work, data_root)
    subjects = real_kinect.by_subject(imported / "recordings")
    names = sorted(subjects)
    graphs: dict[tuple[str, ...], FilteredPoseGraph] = {}

    def graph_without(excluded: set[str]) -> FilteredPoseGraph:
        key = tuple(sorted(excluded))
        if key not in graphs:
            graphs[key] = real_kinect.uiprmd_graph(imported, set(key), 0.1)
        return graphs[key]

    if sampler_models is not None:  # every fold's model, before hours of work
        missing = [s for s in names if not (sampler_models / f"sampler_{s}_linear.json").is_file()]
        if missing:
            raise SystemExit(
                f"--sampler-models: {sampler_models} has no sampler_<subject>_linear.json for "
                f"{', '.join(missing)} (scripts/learned_samplers.py --protocols uiprmd writes them)"
            )
    totals: list[tuple[np.ndarray, ...]] = []
    anchors: list[tuple[np.ndarray, np.ndarray]] = []
    for held_out in names:
        method, label = "closed-form", "closed-form"
        if sampler_models is not None:
            method, label = f"learned:{sampler_models / f'sampler_{held_out}_linear'}", "learned"
        others = [s for s in names if s != held_out]
        recordings = [load_recording(p) for s in others for p in subjects[s]]
        sensor_map, _, _ = real_kinect.fold_maps(
            "uiprmd", graph_without({held_out}), recordings, True, False
        )
        parts = {
            s: frame_data(
                Reconstructor(graph_without({held_out, s}), sensor_map=sensor_map, **options),
                [load_recording(p) for p in real_kinect.repetitions(subjects[s], train_reps)],
                method,
            )
            for s in others
        }
        inner = [
            (merged([parts[s] for s in others if s != v]), parts[v]) for v in others
        ]  # every training subject validates once
        penalty, alpha, _ = choose(inner)
        predict = ridge(merged([parts[s] for s in others]), penalty)
        reconstructor = Reconstructor(graph_without({held_out}), sensor_map=sensor_map, **options)
        episodes = [load_recording(p) for p in real_kinect.repetitions(subjects[held_out], 1)]
        test = frame_data(reconstructor, episodes, method)
        base, jb = scores(test["outputs"], test)
        fixed, jf = scores(corrected(test, predict(test["x"]), alpha), test)
        totals.append((base, fixed, jb, jf))
        name = f"{held_out} (penalty/smoothing {penalty:g}/{alpha:g})"
        print(report(name, base, fixed, jb, jf, label), flush=True)
        if sampler_models is not None:  # the corrected sampler against the closed form
            anchor = frame_data(reconstructor, episodes)
            anchors.append(scores(anchor["outputs"], anchor))
    pooled = [np.concatenate(column) for column in zip(*totals, strict=True)]
    line = report("UI-PRMD, 8 held-out subjects", *pooled, label=label)
    if anchors:
        base, jb = (np.concatenate(column) for column in zip(*anchors, strict=True))
        line += "\n" + report("the same against the anchor", base, pooled[1], jb, pooled[3])
    return line


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--protocol", choices=("sim", "uiprmd"), required=True)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--work", type=Path, default=Path("runs/real_kinect"))
    parser.add_argument(
        "--train-reps",
        type=int,
        default=0,
        help="UI-PRMD: repetitions per exercise of each training subject (0: all, the default)",
    )
    parser.add_argument(
        "--sensor-blend",
        type=float,
        default=0.0,
        help="the pipeline's sensor blend (0, the default: scripts/real_kinect.py's default)",
    )
    parser.add_argument(
        "--sampler-models",
        type=Path,
        help="UI-PRMD: correct each fold's linear sampler (learned_samplers.py's uiprmd folder)",
    )
    args = parser.parse_args()
    if args.sampler_models is not None and args.protocol != "uiprmd":
        parser.error("--sampler-models: only with --protocol uiprmd")
    if not 0.0 <= args.sensor_blend <= 1.0:
        parser.error(f"--sensor-blend: expected a value in [0, 1], got {args.sensor_blend:g}")
    options = {"sensor_blend": args.sensor_blend}
    threadpool_limits(1, "blas")
    start = time.perf_counter()
    if args.protocol == "sim":
        line = sim_protocol(args.data, options)
    else:
        line = uiprmd_protocol(args.work, args.data, args.train_reps, options, args.sampler_models)
    print(f"{line}; wall {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
