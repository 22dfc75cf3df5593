"""``fpg-gym view``: a 3D view of a recording and its reconstructions (a rerun ``.rrd``)."""

from __future__ import annotations

import argparse
from typing import Any

from fpg_gym.commands import types

NAME = "view"
HELP = (
    "write a 3D view (rerun .rrd): the Kinect input coloured by tracking state, reconstructions "
    "by --method or from --result files, and the ground truth, over time (needs fpg-gym[view])"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument("input", metavar="REC", help="recording (.npz, Kinect files, ...)")
    parser.add_argument(
        "--format", default=None, help="format of REC (default: guessed; see reconstruct)"
    )
    parser.add_argument(
        "--method",
        action="append",
        default=[],
        metavar="NAME",
        help="run a method on REC and show it (repeatable or comma-separated: raw, holt, "
        "fpg:local-search+ragdoll, ...)",
    )
    parser.add_argument(
        "--result",
        action="append",
        default=[],
        metavar="OUT.npz",
        help="show a reconstruction written by fpg-gym reconstruct --out (repeatable)",
    )
    parser.add_argument(
        "--graph", default="default", metavar="FILE", help="pose graph for --method (default)"
    )
    parser.add_argument("--seed", type=types.seed, default=0, help="optimiser seed (default 0)")
    parser.add_argument("--out", required=True, metavar="VIEW.rrd", help="rerun file to write")
    parser.add_argument(
        "--spawn", action="store_true", help="also open the rerun viewer on the written file"
    )


def run(args: argparse.Namespace) -> int:
    """Run the methods, read the results, write the ``.rrd``."""
    import subprocess
    import sys
    from pathlib import Path

    import numpy as np

    from fpg_gym.core.errors import DataFormatError
    from fpg_gym.core.outputs import check_output
    from fpg_gym.experiments.view import require_rerun, write_view
    from fpg_gym.graph import load_graph
    from fpg_gym.io import read_recording
    from fpg_gym.io.npz import load_npz
    from fpg_gym.methods import MethodRunner, parse_methods

    require_rerun()  # fail first, before any work, when the extra is missing
    out = check_output(args.out, [args.input, *args.result])
    if out.suffix != ".rrd":
        raise ValueError(f"--out {args.out}: expected a .rrd file name (a rerun recording)")
    methods = parse_methods(args.method)
    recording = read_recording(args.input, format=args.format)
    shown: dict[str, Any] = {}
    for result in args.result:
        arrays = load_npz(result)
        if "poses" not in arrays:
            raise DataFormatError(result, "no 'poses' array (expected fpg-gym reconstruct --out)")
        shown[Path(result).stem] = np.asarray(arrays["poses"])
    if methods:
        needs_graph = any(not m.is_filter for m in methods)
        graph = load_graph(args.graph) if needs_graph else None
        with MethodRunner(graph) as runner:
            for method in methods:
                shown[method.name] = runner.run(method, recording, seed=args.seed).poses
    path = write_view(
        out,
        recording.positions,
        recording.states,
        recording.timestamps,
        reconstructions=shown,
        ground_truth=recording.ground_truth,
    )
    layers = ", ".join(
        ["input", *shown, *(["ground truth"] if recording.ground_truth is not None else [])]
    )
    print(f"written          {path} ({recording.num_frames} frames: {layers})")
    if args.spawn:
        subprocess.Popen([sys.executable, "-m", "rerun", str(path)])
    else:
        print(f"open it with     rerun {path}")
    return 0
