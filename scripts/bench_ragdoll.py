"""Benchmark the PD ragdoll (fpg_gym.physics.ragdoll): time per frame, tracking error, bone lengths.

Tracks clean mocap clips — the embedded DeepMimic clips walk, punch, kick, dance_a, dance_b, and
with ``--bandai N`` the first N Bandai Namco dataset-1 clips of ../shared/data when present —
with ``--ragdolls`` instances side by side in one process (interleaved frame by frame), for
``--rounds`` rounds. Reports, per round, the median and 95th percentile of the wall-clock and CPU
time of one ``track`` call (one Kinect frame of one ragdoll), and per clip the FPG Eq. 13
bone-vector error, the worst per-frame error, the largest bone-length deviation from the model,
the largest joint-constraint gap and the divergence count.

Usage::

    python scripts/bench_ragdoll.py                     # default clips, 1 ragdoll, 3 rounds
    python scripts/bench_ragdoll.py --ragdolls 4 --bandai 5 --json /tmp/ragdoll.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from fpg_gym.core import metrics, poses
from fpg_gym.io import BANDAI_NAMCO_MAP, Clip, load_default_clips, read_bvh
from fpg_gym.physics.ragdoll import PhysicsWarning, Ragdoll

DEFAULT_CLIPS = ("walk", "punch", "kick", "dance_a", "dance_b")
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load(names: tuple[str, ...], bandai: int) -> list[Clip]:
    clips = load_default_clips(names) if names else []
    folder = SHARED / "bandai_namco" / "dataset-1"
    if bandai > 0:
        if not folder.is_dir():
            print(f"note: {folder} is absent; Bandai Namco clips skipped", file=sys.stderr)
        else:
            for path in sorted(folder.glob("*.bvh"))[:bandai]:
                clips.append(read_bvh(path, BANDAI_NAMCO_MAP))
    return clips


def run_clip(clip: Clip, count: int) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
    """Track one clip with ``count`` ragdolls side by side; return its figures and the wall
    and CPU seconds of every track call."""
    lengths = poses.bone_lengths(clip.positions).mean(axis=0)
    bodies = [Ragdoll(lengths) for _ in range(count)]
    wall, cpu, outputs = [], [], [[] for _ in bodies]
    try:
        for body in bodies:
            body.reset(clip.positions[0])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PhysicsWarning)  # counted in info below
            for target in clip.positions:
                for body, out in zip(bodies, outputs, strict=True):
                    w0, c0 = time.perf_counter(), time.process_time()
                    out.append(body.track(target))
                    wall.append(time.perf_counter() - w0)
                    cpu.append(time.process_time() - c0)
        result = np.array(outputs[0])
        errors = metrics.frame_error(clip.positions, result)
        figures = {
            "frames": float(clip.num_frames),
            "eq13_mean_m": float(errors.mean()),
            "eq13_worst_frame_m": float(errors.max()),
            "bone_length_error_max_m": float(
                np.max(np.abs(poses.bone_lengths(result) - bodies[0].model.bone_lengths))
            ),
            "joint_gap_max_m": max(body.info["max_joint_gap"] for body in bodies),
            "divergences": float(sum(body.info["divergences"] for body in bodies)),
        }
    finally:
        for body in bodies:
            body.close()
    return figures, np.array(wall), np.array(cpu)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ragdolls", type=int, default=1, help="instances side by side")
    parser.add_argument("--rounds", type=int, default=3, help="timing rounds (default 3)")
    parser.add_argument("--bandai", type=int, default=0, help="add the first N Bandai clips")
    parser.add_argument("--clips", nargs="*", default=list(DEFAULT_CLIPS), help="default clips")
    parser.add_argument("--json", type=Path, help="write the figures to this JSON file")
    args = parser.parse_args(argv)
    if args.ragdolls < 1 or args.rounds < 1:
        parser.error("--ragdolls and --rounds must be at least 1")

    clips = load(tuple(args.clips), args.bandai)
    rounds, per_clip = [], {}
    for round_index in range(args.rounds):
        walls, cpus = [], []
        for clip in tqdm(clips, desc=f"round {round_index + 1}/{args.rounds}", unit="clip"):
            figures, wall, cpu = run_clip(clip, args.ragdolls)
            per_clip[clip.name] = figures
            walls.append(wall)
            cpus.append(cpu)
        wall_ms, cpu_ms = 1e3 * np.concatenate(walls), 1e3 * np.concatenate(cpus)
        rounds.append(
            {
                "calls": int(wall_ms.size),
                "wall_median_ms": float(np.median(wall_ms)),
                "wall_p95_ms": float(np.percentile(wall_ms, 95)),
                "cpu_median_ms": float(np.median(cpu_ms)),
                "cpu_p95_ms": float(np.percentile(cpu_ms, 95)),
            }
        )

    print(f"\nper frame per ragdoll, {args.ragdolls} ragdoll(s) side by side:")
    for i, r in enumerate(rounds, 1):
        print(
            f"  round {i}: {r['calls']} calls  wall median {r['wall_median_ms']:.3f} ms, "
            f"p95 {r['wall_p95_ms']:.3f} ms   cpu median {r['cpu_median_ms']:.3f} ms, "
            f"p95 {r['cpu_p95_ms']:.3f} ms"
        )
    print(
        f"\n{'clip':40s} {'frames':>6s} {'Eq13 cm':>8s} {'worst cm':>8s} "
        f"{'bone mm':>8s} {'gap mm':>7s} {'div':>4s}"
    )
    for name, f in per_clip.items():
        print(
            f"{name:40s} {int(f['frames']):6d} {100 * f['eq13_mean_m']:8.3f} "
            f"{100 * f['eq13_worst_frame_m']:8.2f} {1000 * f['bone_length_error_max_m']:8.4f} "
            f"{1000 * f['joint_gap_max_m']:7.2f} {int(f['divergences']):4d}"
        )
    if args.json:
        args.json.write_text(
            json.dumps({"ragdolls": args.ragdolls, "rounds": rounds, "clips": per_clip}, indent=2)
        )
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
