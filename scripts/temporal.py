"""Before/after table of the temporal-coherence switches (issue 15).

Runs graph selection + local search (the papers' baseline pipeline) on held-out episodes with
each switch of :class:`fpg_gym.reconstruct.TemporalConfig` and the bone settling rule
(:class:`fpg_gym.reconstruct.BoneSettlingConfig`) turned on one after the other, and prints FPG
Eq. 13 mean error, Err0.2, jitter, lag against the ground truth and the largest bone-length range
after the first second, next to the raw input, the Kinect SDK's Holt filter and the ground truth.

Episodes are simulated exactly as ``fpg-gym compare`` simulates them (same seeds, same
optimiser seeds), from the takes listed in ``--takes`` (default: the held-out Bandai Namco takes
of ``scripts/holdout_split.py``), or read from recordings with ground truth (``--inputs``, e.g.
imported real recordings). Tuning was done on other takes (``--takes
runs/split/eval_takes_all.txt --skip 8 --count 6``, the validation takes); the README's table is
this script's output on the evaluation takes::

    python scripts/holdout_split.py --datasets dataset-1,dataset-2 --eval-count 8 \
        --out-dir runs/split
    fpg-gym build-graph @runs/split/graph_takes.txt --out runs/bandai_graph.npz
    python scripts/temporal.py --graph runs/bandai_graph.npz --takes runs/split/eval_takes.txt
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # run from a checkout without installing
    sys.path.insert(0, str(REPO))

from fpg_gym.core import metrics  # noqa: E402
from fpg_gym.experiments import markdown_table, plan_episodes  # noqa: E402
from fpg_gym.methods import ragdoll_factory  # noqa: E402
from fpg_gym.reconstruct import (  # noqa: E402
    BoneSettlingConfig,
    Reconstructor,
    TemporalConfig,
)

COLUMNS = (
    "setting",
    "mean error (m)",
    "Err0.2 (%)",
    "jitter (m/s²)",
    "lag (frames)",
    "bone spread after 1 s, max (mm)",
    "ms/frame",
)


@dataclass(frozen=True)
class Setting:
    """One row: a name and the reconstructor's temporal and bone settings."""

    name: str
    temporal: TemporalConfig
    bones: BoneSettlingConfig
    ragdoll: bool = False


def settings(ragdoll: bool) -> list[Setting]:
    """The switches, turned on one after the other, then alternatives to the default."""
    off = TemporalConfig.off()
    no_bones = BoneSettlingConfig(enabled=False)
    on = BoneSettlingConfig()
    default = TemporalConfig()
    continuity = replace(off, velocity_damping=0.0, motion_scale=8.0)
    rows = [
        Setting("papers (every switch off)", off, no_bones),
        Setting("+ bone settling", off, on),
        Setting("+ continuity prior (Em anchored, weight 2)", continuity, on),
        Setting("+ output Kalman stage", replace(continuity, output="kalman"), on),
        Setting("+ root smoothing = **default**", default, on),
        Setting("default + heading smoothing", replace(default, smooth_heading=True), on),
        Setting("default + aligned latent basis", replace(default, align_basis=True), on),
        Setting("default, output One-Euro instead", replace(default, output="one-euro"), on),
        Setting("default without output stage", replace(default, output=""), on),
        Setting(
            "default without continuity prior",
            replace(default, velocity_damping=1.0, motion_scale=1.0),
            on,
        ),
    ]
    if ragdoll:
        rows += [
            Setting("papers + ragdoll", off, no_bones, True),
            Setting("default + ragdoll", default, on, True),
        ]
    return rows


def load_episodes(args: argparse.Namespace) -> list[tuple[str, Any, int]]:
    """(name, recording, optimiser seed) of every episode."""
    from fpg_gym.io import load_clips
    from fpg_gym.io.recording import load_recording
    from fpg_gym.simulate import EpisodeSimulator

    episodes: list[tuple[str, Any, int]] = []
    if args.takes:
        lines = [ln.strip() for ln in Path(args.takes).read_text().splitlines() if ln.strip()]
        takes = lines[args.skip : args.skip + args.count]
        clips = load_clips(takes, progress=False)
        by_name = {c.name: c for c in clips}
        plan = plan_episodes(list(by_name), args.scenarios.split(","), [args.seed])
        with EpisodeSimulator() as simulator:
            for spec in plan:
                recording = simulator.simulate(by_name[spec.clip], spec.planned, args.max_frames)
                episodes.append((spec.id, recording, spec.sim_seed))
    for path in args.inputs:
        recording = load_recording(path).head(args.max_frames)
        episodes.append((Path(path).stem, recording, 0))
    return episodes


def measure(outputs: list[np.ndarray], episodes: list[tuple[str, Any, int]]) -> dict[str, float]:
    """Pooled error and Err0.2; jitter, lag and ms averaged over episodes; spread max."""
    errors, jitters, lags, spreads = [], [], [], []
    for poses, (_, recording, _) in zip(outputs, episodes, strict=True):
        stamps = np.asarray(recording.timestamps, dtype=np.float64)
        jitters.append(np.nanmean(metrics.jitter(poses, timestamps=stamps)))
        spread = metrics.settled_bone_spread(poses, timestamps=stamps)
        if np.isfinite(spread).any():
            spreads.append(float(np.nanmax(spread)))
        truth = recording.ground_truth
        if truth is not None:
            errors.append(metrics.frame_error(truth, poses))
            lags.append(metrics.lag(poses, truth))
    pooled = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "error": float(pooled.mean()) if pooled.size else float("nan"),
        "err02": 100.0 * metrics.err_ratio(pooled) if pooled.size else float("nan"),
        "jitter": float(np.nanmean(jitters)),
        "lag": float(np.nanmean(lags)) if lags else float("nan"),
        "spread": 1000.0 * max(spreads) if spreads else float("nan"),
    }


def row(name: str, m: dict[str, float], ms: float | None) -> list[str]:
    """Cells of one table row."""

    def fmt(value: float, digits: int) -> str:
        return "–" if not np.isfinite(value) else f"{value:.{digits}f}"

    return [
        name,
        fmt(m["error"], 4),
        fmt(m["err02"], 2),
        fmt(m["jitter"], 1),
        fmt(m["lag"], 2),
        fmt(m["spread"], 1),
        "–" if ms is None else f"{ms:.2f}",
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--graph", default="runs/bandai_graph.npz", help="pose graph .npz")
    parser.add_argument("--takes", default="runs/split/eval_takes.txt", help="list of takes")
    parser.add_argument("--skip", type=int, default=0, help="takes skipped at the list's start")
    parser.add_argument("--count", type=int, default=8, help="takes used")
    parser.add_argument("--scenarios", default="front-many,left45-many,right45-many")
    parser.add_argument("--seed", type=int, default=0, help="compare's --seeds value")
    parser.add_argument("--max-frames", type=int, default=150)
    parser.add_argument("--inputs", nargs="*", default=[], help="recordings (.npz)")
    parser.add_argument("--ragdoll", action="store_true", help="add rows with the ragdoll")
    parser.add_argument("--only", default="", help="comma-separated row numbers (1-based)")
    args = parser.parse_args(argv)
    from fpg_gym.filters import make_filter
    from fpg_gym.graph import load_graph

    if args.takes and not Path(args.takes).is_file():
        args.takes = ""
    episodes = load_episodes(args)
    if not episodes:
        parser.error("no episodes: give --takes and/or --inputs")
    graph = load_graph(args.graph)
    frames = sum(len(r.positions) for _, r, _ in episodes)
    print(f"{len(episodes)} episodes, {frames} frames; graph {graph!r}")
    rows = []
    truth = [r.ground_truth for _, r, _ in episodes if r.ground_truth is not None]
    if truth:
        jit = [
            np.nanmean(metrics.jitter(r.ground_truth, timestamps=r.timestamps))
            for _, r, _ in episodes
            if r.ground_truth is not None
        ]
        rows.append(["ground truth", "–", "–", f"{np.mean(jit):.1f}", "–", "–", "–"])
    rows.append(row("raw input", measure([r.positions for _, r, _ in episodes], episodes), None))
    holt = [
        make_filter("holt").filter_sequence(r.positions, r.states, r.timestamps)
        for _, r, _ in episodes
    ]
    rows.append(row("holt (Kinect SDK filter)", measure(holt, episodes), None))
    chosen = settings(args.ragdoll)
    if args.only:
        keep = {int(i) for i in args.only.split(",")}
        chosen = [s for i, s in enumerate(chosen, 1) if i in keep]
    for setting in chosen:
        started = time.perf_counter()
        with Reconstructor(
            graph,
            temporal=setting.temporal,
            bones=setting.bones,
            ragdoll=ragdoll_factory(setting.ragdoll),
        ) as rec:
            outputs = [
                rec.reconstruct(r, "local-search", rng=seed).poses for _, r, seed in episodes
            ]
        ms = 1000.0 * (time.perf_counter() - started) / frames
        rows.append(row(setting.name, measure(outputs, episodes), ms))
        print(" | ".join(rows[-1]), flush=True)
    print()
    print(markdown_table(COLUMNS, rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
