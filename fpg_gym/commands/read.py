"""``fpg-gym read``: read mocap files and print what they hold."""

from __future__ import annotations

import argparse
import time

from fpg_gym.commands import types

NAME = "read"
HELP = "read mocap clips (BVH, DeepMimic, positions .npz, or 'default') and print statistics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="files, folders or 'default'")
    parser.add_argument("--units", default="auto", choices=["auto", "m", "cm", "mm"])
    parser.add_argument("--workers", type=types.workers, default=None, help="reader processes")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def run(args: argparse.Namespace) -> int:
    """Read the clips and print counts, frames, durations, heights and bone-length spread."""
    import numpy as np

    from fpg_gym.commands.output import emit_json
    from fpg_gym.core.poses import bone_lengths, height
    from fpg_gym.io import load_clips

    start = time.perf_counter()
    clips = load_clips(args.inputs, workers=args.workers, units=args.units)
    seconds = time.perf_counter() - start
    frames = sum(c.num_frames for c in clips)
    heights = np.array([float(np.percentile(height(c.positions), 90)) for c in clips])
    spread = np.array([float(np.ptp(bone_lengths(c.positions), axis=0).max()) for c in clips])
    print(f"clips            {len(clips)}")
    print(f"frames           {frames} ({frames / 30.0 / 60.0:.1f} min at 30 Hz)")
    low, high = heights.min(), heights.max()
    print(f"height (p90)     median {np.median(heights):.3f} m, range {low:.3f}-{high:.3f} m")
    spread_mm = 1000 * spread
    print(f"bone spread      median {np.median(spread_mm):.2f} mm, max {spread_mm.max():.2f} mm")
    print(f"read time        {seconds:.2f} s ({frames / max(seconds, 1e-9):.0f} frames/s)")
    if args.json:
        emit_json(
            {
                "clips": len(clips),
                "frames": frames,
                "seconds": round(seconds, 3),
                "median_height_m": float(np.median(heights)),
                "max_bone_spread_m": float(spread.max()),
            }
        )
    return 0
