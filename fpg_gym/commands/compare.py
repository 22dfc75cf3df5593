"""``fpg-gym compare``: run reconstruction methods on many episodes and write a report."""

from __future__ import annotations

import argparse
import os
from typing import Any

from fpg_gym.commands import types
from fpg_gym.commands.reconstruct import add_calibration_arguments

NAME = "compare"
HELP = (
    "compare methods (raw, holt, kalman, shum, fpg x optimisers, +ragdoll) on simulated "
    "episodes or recordings: results.csv, summary.json, report.md, plots"
)

_EPILOG = """\
methods: BASE[:OPTION][+ragdoll] with BASE raw | holt | kalman | shum | fpg; OPTION is a filter
preset (holt:smoothed, holt:very-smoothed, kalman:fast) or, for shum (brute-force selection) and
fpg (graph selection), an optimiser (local-search, random-search, cma-es, none; default
local-search). --optimizers A,B with --selectors graph,brute-force adds fpg:A, shum:A, ...

hold-out: the graph must not contain the evaluated takes. --graph default builds the embedded
graph without the evaluated embedded clips; for your own data build the graph from other takes
(scripts/holdout_split.py writes the two lists; pass them as @graph_takes.txt / @eval_takes.txt).

examples:
  fpg-gym compare --clips default --methods raw,holt,kalman --optimizers none,local-search \\
      --out runs/embedded
  fpg-gym compare --graph bandai.npz --clips @eval_takes.txt --max-frames 150 \\
      --optimizers none,random-search,local-search,cma-es --selectors graph,brute-force \\
      --methods raw,holt,kalman --out runs/bandai
"""


def _list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def _seeds(text: str) -> list[int]:
    try:
        values = [int(item) for item in _list(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from None
    if not values or any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected non-negative integers, got {text!r}")
    if len(set(values)) < len(values):
        raise argparse.ArgumentTypeError(
            f"a seed given twice in {text!r}; each seed is one set of episodes"
        )
    return values


def add_backend_arguments(parser: Any, local: str) -> None:
    """``--backend local|ray`` and ``--address`` (the commands whose work can run on Ray)."""
    parser.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help=f"{local}, or a Ray cluster (pip install 'fpg-gym[distributed]')",
    )
    parser.add_argument(
        "--address",
        default=None,
        metavar="HOST:PORT",
        help="Ray cluster to use with --backend ray (default: RAY_ADDRESS, else a local Ray)",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = _EPILOG
    parser.add_argument(
        "--graph",
        default="default",
        metavar="FILE",
        help="pose graph .npz, or a name: 'default' (the inputs' sensor's default database: "
        "'uiprmd' for Kinect v2 recordings, else 'embedded' without the evaluated embedded "
        "clips), 'embedded', 'uiprmd'",
    )
    _add_episode_arguments(parser.add_argument_group("episodes"))
    _add_method_arguments(parser.add_argument_group("methods"))
    _add_run_arguments(parser)


def _add_episode_arguments(source: Any) -> None:
    """The episodes: simulated clips or recordings, seeds and length."""
    source.add_argument(
        "--clips",
        nargs="+",
        default=[],
        metavar="CLIP",
        help="mocap files/folders, 'default' (embedded held-out clips walk, punch, kick, "
        "dance_b) or embedded clip names; simulated in every --scenarios",
    )
    source.add_argument(
        "--scenarios",
        type=_list,
        default=None,
        metavar="A,B",
        help="simulator scenarios (default front-many,left45-many,right45-many)",
    )
    source.add_argument(
        "--inputs",
        nargs="+",
        default=[],
        metavar="REC",
        help="recordings (.npz with ground truth from `fpg-gym simulate`, or Kinect files)",
    )
    source.add_argument(
        "--input-format",
        choices=("msrc12", "kinect_v2", "ntu", "csv", "npz"),
        default=None,
        help="format of the --inputs files (default: guessed per file)",
    )
    source.add_argument(
        "--seeds", type=_seeds, default=[0], metavar="S,T", help="seeds (default 0)"
    )
    source.add_argument(
        "--max-frames",
        type=types.integer(3),
        default=None,
        metavar="N",
        help="first N frames per episode",
    )


def _add_method_arguments(methods: Any) -> None:
    """The methods compared and their search settings."""
    methods.add_argument(
        "--methods",
        type=_list,
        default=[],
        metavar="M,N",
        help="method names, e.g. raw,holt,holt:smoothed,kalman,shum,fpg,fpg:cma-es+ragdoll",
    )
    methods.add_argument(
        "--optimizers",
        type=_list,
        default=[],
        metavar="A,B",
        help="optimisers to run with each of --selectors (e.g. none,random-search,local-search)",
    )
    methods.add_argument(
        "--selectors",
        type=_list,
        default=["graph"],
        metavar="S,T",
        help="graph (fpg) and/or brute-force (shum) for --optimizers (default graph)",
    )
    methods.add_argument(
        "--ragdoll",
        choices=["off", "on", "both"],
        default="off",
        help="add the ragdoll to every method (on), run each with and without (both); "
        "default off (a +ragdoll suffix still counts)",
    )
    methods.add_argument(
        "--baseline", default="fpg:local-search", help="method for the paired tests"
    )
    methods.add_argument(
        "--budget",
        type=types.integer(0),
        default=2000,
        help="energy evaluations per frame (default 2000)",
    )
    methods.add_argument(
        "--k", type=types.integer(1), default=30, help="candidates per frame (default 30)"
    )
    add_calibration_arguments(methods)


def _add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Where and how the comparison runs and what it writes."""
    parser.add_argument(
        "--workers",
        type=types.workers,
        default=None,
        help="worker processes (default: CPU count; 1 runs in this process); with "
        "--backend ray and no --address, the CPUs of the local Ray instance",
    )
    parser.add_argument(
        "--batch",
        type=types.integer(1),
        default=8,
        metavar="N",
        help="episodes of one reconstruction method run side by side in a process, their "
        "searches batched (default 8; 1: one by one); same rows, timings aside",
    )
    add_backend_arguments(parser, "local worker processes")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--fresh", action="store_true", help="discard results already in --out (else resume)"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def run(args: argparse.Namespace) -> int:
    """Run the comparison, print the table and where the files are."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.experiments import CompareConfig, format_tests, run_compare
    from fpg_gym.methods import expand_methods

    methods = expand_methods(args.methods, args.optimizers, args.selectors, args.ragdoll)
    config = CompareConfig(
        out=args.out,
        methods=[m.name for m in methods],
        graph=args.graph,
        clips=list(args.clips),
        inputs=list(args.inputs),
        scenarios=list(args.scenarios or []),
        seeds=list(args.seeds),
        budget=args.budget,
        k=args.k,
        max_frames=args.max_frames,
        workers=args.workers if args.workers is not None else (os.cpu_count() or 1),
        batch=args.batch,
        backend=args.backend,
        address=args.address,
        baseline=args.baseline,
        sensor_map=args.sensor_map,
        output_map=args.output_map,
        sensor_blend=args.sensor_blend,
        calibrate_output=args.calibrate_output,
        calibration_map=args.calibration_map,
        input_format=args.input_format,
        sensor=args.sensor,
        preset=args.preset,
    )
    outcome = run_compare(
        config, progress=not args.quiet, fresh=args.fresh, plots=not args.no_plots
    )
    summary = outcome.summary
    print(outcome.table)
    print()
    print(f"paired test against {summary['baseline']}:")
    print(format_tests(summary))
    print()
    state = " (interrupted)" if outcome.interrupted else ""
    print(
        f"{len(summary['episodes'])} episodes x {len(summary['method_order'])} methods; "
        f"{outcome.tasks_run} runs finished now, {outcome.tasks_skipped} kept from before; "
        f"{outcome.seconds:.1f} s{state}"
    )
    written = ["report.md", "results.csv", "summary.json", *summary.get("plots", {}).values()]
    print(f"written          {outcome.out}/{', '.join(written)}")
    if args.json:
        emit_json(
            {
                "out": str(outcome.out),
                "seconds": round(outcome.seconds, 3),
                "interrupted": outcome.interrupted,
                "baseline": summary["baseline"],
                "episodes": len(summary["episodes"]),
                "methods": {
                    name: {
                        "mean_error_m": m["mean_error_m"],
                        "err02_pct": m["err02_pct"],
                        "ms_per_frame_median": (m["ms_per_frame"] or {}).get("median"),
                        "wilcoxon_p": m["vs_baseline"]["wilcoxon_p"],
                    }
                    for name, m in summary["methods"].items()
                },
            }
        )
    return 130 if outcome.interrupted else 0
