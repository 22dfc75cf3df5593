"""``fpg-gym import-uiprmd``: pair UI-PRMD Kinect v2 streams with their Vicon ground truth."""

from __future__ import annotations

import argparse

from fpg_gym.commands import types

NAME = "import-uiprmd"
HELP = (
    "import UI-PRMD (real Kinect v2 + Vicon): paired recordings with ground truth and Vicon "
    "joint-centre clips"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "root",
        metavar="ROOT",
        help="UI-PRMD folder (holding Kinect/ and Vicon/, or 'Segmented Movements/')",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--subjects",
        metavar="LIST",
        help="comma-separated subjects to import, e.g. s01,s02 (default: every subject found)",
    )
    parser.add_argument(
        "--max-lag", type=int, default=15, help="largest Kinect/Vicon lag searched, frames (15)"
    )
    parser.add_argument("--workers", type=types.workers, default=None, help="processes (all cores)")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def run(args: argparse.Namespace) -> int:
    """Import, print a per-session alignment table and the summary."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.io.ui_prmd_import import import_uiprmd

    if args.max_lag < 0:
        raise ValueError(f"--max-lag: expected a non-negative number of frames, got {args.max_lag}")
    subjects = None
    if args.subjects:
        subjects = [s.strip() for s in args.subjects.split(",") if s.strip()]
    summary = import_uiprmd(
        args.root, args.out, subjects=subjects, max_lag=args.max_lag, workers=args.workers
    )
    print(
        f"{'session':<10} {'reps':>4} {'frames':>7} {'alignment (mm)':>15} {'lags':>12} "
        f"{'pelvis (mm)':>12}"
    )
    for report in summary["session_reports"]:
        lags = report["lags"]
        span = f"{min(lags)}..{max(lags)}" if lags else "-"
        mean = report["mean_alignment_m"]
        shown = f"{1000 * mean:.1f}" if mean is not None else "-"
        width = report["pelvis_width_m"]
        pelvis = f"{1000 * width:.0f}" if width is not None else "-"
        print(
            f"{report['session']:<10} {len(report['repetitions']):>4} "
            f"{sum(report['frames']):>7} {shown:>15} {span:>12} {pelvis:>12}"
        )
    for name, why in summary["skipped"].items():
        print(f"skipped {name}: {why}")
    for warning in summary["warnings"]:
        print(f"warning: {warning}")
    mean = summary["mean_alignment_m"]
    print(
        f"{summary['repetitions']} repetitions in {summary['sessions']} sessions written to "
        f"{summary['out']}; mean alignment error "
        f"{'-' if mean is None else f'{1000 * mean:.1f} mm'}"
    )
    if args.json:
        emit_json({k: v for k, v in summary.items() if k != "session_reports"})
    return 0
