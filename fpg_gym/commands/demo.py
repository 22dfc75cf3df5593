"""``fpg-gym demo``: real Kinect v2 streams against Vicon first, then simulated streams of the
embedded clips; compare, plot."""

from __future__ import annotations

import argparse
from typing import Any

from fpg_gym.commands import types

NAME = "demo"
HELP = (
    "the whole job on the packaged data (no files needed): real Kinect v2 repetitions against "
    "Vicon, with and without occlusions, then simulated Kinect episodes of the embedded clips; "
    "filters vs reconstruction, tables, plots and a GIF (18 s, 26 CPU s, on a shared 2-core "
    "machine at load about 1; 22 s the first time, which runs the kernels' numpy versions while "
    "numba compiles them in the background)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "--out", default="fpg-gym-demo", metavar="DIR", help="output folder (default fpg-gym-demo)"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="reduced run: 2 real repetitions (lost legs), 2 clips, 1 scenario, 24 frames",
    )
    parser.add_argument(
        "--methods",
        default=None,
        metavar="M,N",
        help="methods to run instead of the demo's set (see `fpg-gym compare --help`)",
    )
    parser.add_argument(
        "--workers", type=types.workers, default=None, help="processes (default: min(2, CPU count))"
    )
    parser.add_argument("--seed", type=types.seed, default=0, help="simulator/optimiser seed (0)")
    parser.add_argument("--no-gif", action="store_true", help="skip the animated GIF")
    parser.add_argument(
        "--no-view", action="store_true", help="skip demo.rrd (the 3D view; needs fpg-gym[view])"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def run(args: argparse.Namespace) -> int:
    """Run the demo and print the comparison."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.experiments.demo import print_outcome, run_demo

    if args.seed < 0:
        raise ValueError(f"--seed: expected a non-negative integer, got {args.seed}")
    methods = [m for m in args.methods.split(",") if m.strip()] if args.methods else None
    outcome = run_demo(
        args.out,
        quick=args.quick,
        methods=methods,
        workers=args.workers,
        seed=args.seed,
        progress=not args.quiet,
        gif=not args.no_gif,
        view=not args.no_view,
    )
    print_outcome(outcome)
    if args.json:
        summary = outcome.compare.summary
        emit_json(
            {
                "out": str(outcome.compare.out),
                "seconds": round(outcome.seconds, 3),
                "real": {
                    name: _methods(part.summary)
                    for name, part in (
                        ("clean", outcome.real_clean),
                        ("occluded", outcome.real_occluded),
                    )
                    if part is not None
                },
                "episodes": len(summary["episodes"]),
                "baseline": summary["baseline"],
                "files": [p.name for p in outcome.files],
                "methods": {
                    name: {
                        "mean_error_m": m["mean_error_m"],
                        "err02_pct": (m["err02_pct"] or {}).get("mean"),
                        "ms_per_frame_median": (m["ms_per_frame"] or {}).get("median"),
                    }
                    for name, m in summary["methods"].items()
                },
            }
        )
    return 130 if outcome.compare.interrupted else 0


def _methods(summary: dict[str, Any]) -> dict[str, Any]:
    """Each real method's Eq. 13 error, MPJPE and occluded joints' MPJPE."""
    return {
        name: {key: m.get(key) for key in ("mean_error_m", "mpjpe_m", "occluded_mpjpe_m")}
        for name, m in summary["methods"].items()
    }
