"""``fpg-gym bench``: stage timings, kernels, selection vs graph size, graph build, env, read."""

from __future__ import annotations

import argparse

NAME = "bench"
HELP = (
    "time the pipeline: per-stage frame time, the search kernels side by side (CPU time), "
    "selection vs graph size, graph build vs input size, env steps/s, mocap read speed"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "mocap",
        nargs="*",
        metavar="MOCAP",
        help="mocap files/folders to use instead of the embedded clips "
        "(e.g. ../shared/data/bandai_namco/dataset-1)",
    )
    parser.add_argument("--quick", action="store_true", help="a reduced, fast run")
    parser.add_argument(
        "--sections",
        default=None,
        metavar="A,B",
        help="subset of stages,kernels,selection,build,env,read (default all)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true", help="last stdout line is the JSON report")


def run(args: argparse.Namespace) -> int:
    """Run the bench and print its tables."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.experiments.bench import BenchSettings, run_bench
    from fpg_gym.experiments.bench_report import format_bench

    settings = BenchSettings.make(quick=args.quick, mocap=args.mocap)
    if args.sections:
        chosen = tuple(s.strip() for s in args.sections.split(",") if s.strip())
        unknown = sorted(set(chosen) - set(settings.sections))
        if unknown:
            raise ValueError(
                f"--sections: unknown {', '.join(unknown)}; expected some of "
                + ", ".join(settings.sections)
            )
        settings.sections = chosen
    report = run_bench(settings, progress=not args.quiet)
    print(format_bench(report))
    if args.json:
        emit_json(report)
    return 130 if report["interrupted"] else 0
