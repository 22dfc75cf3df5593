"""``fpg-gym build-graph``: build a Filtered Pose Graph from mocap clips and save it as ``.npz``."""

from __future__ import annotations

import argparse
import time

from fpg_gym.commands import types

NAME = "build-graph"
HELP = "build a Filtered Pose Graph (FPG Alg. 1-4) from mocap clips and save it as .npz"


def _positive(text: str) -> float:
    value = float(text)
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive distance in metres, got {text}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="mocap files or folders (BVH, .bvh.gz, DeepMimic .txt, positions .npz) or 'default'",
    )
    parser.add_argument("--out", required=True, metavar="FILE", help="graph file to write (.npz)")
    parser.add_argument(
        "--thres1", type=_positive, default=None, help="filter threshold in metres (default 0.2)"
    )
    parser.add_argument(
        "--thres2",
        type=_positive,
        default=None,
        help="edge threshold in metres (default: mean + 2 std of the intra-clip distances)",
    )
    parser.add_argument("--mirror", action="store_true", help="add left/right mirror images")
    parser.add_argument(
        "--units", default="auto", choices=["auto", "m", "cm", "mm"], help="BVH units"
    )
    parser.add_argument("--workers", type=types.workers, default=None, help="reader processes")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def run(args: argparse.Namespace) -> int:
    """Read the clips, build the graph, save it and print its statistics."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.core.outputs import check_output
    from fpg_gym.graph import DEFAULT_THRES1, FilteredPoseGraph
    from fpg_gym.io import load_clips

    # Before any work: the output must not be an input, a folder or unwritable.
    check_output(args.out, [item for item in args.inputs if item != "default"])
    start = time.perf_counter()
    clips = load_clips(args.inputs, workers=args.workers, units=args.units, progress=not args.quiet)
    read_seconds = time.perf_counter() - start
    thres1 = DEFAULT_THRES1 if args.thres1 is None else args.thres1
    graph = FilteredPoseGraph.build(
        clips, thres1=thres1, thres2=args.thres2, mirror=args.mirror, progress=not args.quiet
    )
    path = graph.save(args.out)
    s = graph.stats
    origin = "mean + 2 std of intra-clip distances" if s["thres2_computed"] else "given"
    print(f"clips            {s['clips']}{' (+ mirror images)' if args.mirror else ''}")
    print(f"input poses      {s['poses']}")
    print(f"after intra-clip {s['intra_nodes']}")
    print(f"nodes            {s['nodes']}")
    print(f"edges            {s['edges']}")
    degree = f"mean {s['mean_degree']:.2f}, min {s['min_degree']}, max {s['max_degree']}"
    print(f"degree           {degree}")
    print(f"isolated nodes   {s['isolated']}")
    print(f"thres1           {s['thres1']:.4f} m")
    print(f"thres2           {s['thres2']:.4f} m ({origin})")
    print(f"read time        {read_seconds:.2f} s")
    print(
        f"build time       {s['seconds']:.2f} s (normalise {s['seconds_normalise']:.2f}, intra "
        f"{s['seconds_intra']:.2f}, inter {s['seconds_inter']:.2f}, edges {s['seconds_edges']:.2f})"
    )
    print(f"written          {path}")
    if args.json:
        emit_json(
            {
                "poses": s["poses"],
                "nodes": s["nodes"],
                "edges": s["edges"],
                "mean_degree": s["mean_degree"],
                "min_degree": s["min_degree"],
                "max_degree": s["max_degree"],
                "isolated": s["isolated"],
                "thres1": s["thres1"],
                "thres2": s["thres2"],
                "seconds": s["seconds"],
                "read_seconds": round(read_seconds, 3),
                "clips": s["clips"],
                "mirror": bool(args.mirror),
                "out": str(path),
            }
        )
    return 0
