"""``fpg-gym fit-map``: fit joint-definition maps from recordings with ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "fit-map"
HELP = (
    "fit the joint-definition map of a sensor (sensor -> ground-truth or database definitions) "
    "from recordings with ground truth, e.g. imported UI-PRMD repetitions"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "recordings",
        nargs="+",
        metavar="REC",
        help="recording .npz files with ground truth, or folders of them (never the subjects "
        "you will score)",
    )
    parser.add_argument("--out", required=True, metavar="MAP.json", help="sensor map to write")
    parser.add_argument("--sensor", default="kinect-v2", help="name of the sensor's definitions")
    parser.add_argument(
        "--truth", default="vicon", help="name of the ground truth's definitions (vicon)"
    )
    parser.add_argument(
        "--graph",
        metavar="G",
        help="a pose graph in other definitions than the ground truth's ('default' or .npz): "
        "the sensor map then goes into the database's definitions, and --output-map gets the "
        "map from the database's back to the ground truth's",
    )
    parser.add_argument("--output-map", metavar="MAP.json", help="output map to write (--graph)")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def run(args: argparse.Namespace) -> int:
    """Fit, write the map(s), print their offsets' sizes and residuals."""
    import numpy as np

    from fpg_gym.commands.output import emit_json
    from fpg_gym.core.outputs import check_output
    from fpg_gym.definitions import fit_sensor_maps
    from fpg_gym.graph import load_graph
    from fpg_gym.io import expand_inputs
    from fpg_gym.io.recording import load_recording

    if args.graph and not args.output_map:
        raise ValueError("--output-map: needed with --graph (the map back to the truth's joints)")
    # Before any work: neither output is an input (the recordings, the graph), a folder or
    # unwritable, and the two are not one file.
    inputs = [*args.recordings, *([args.graph] if args.graph and args.graph != "default" else [])]
    check_output(args.out, inputs)
    if args.output_map:
        check_output(args.output_map, [*inputs, args.out], argument="--output-map")
    files = expand_inputs(args.recordings, lambda p: p.suffix == ".npz", ".npz recording")
    sensor, truth = [], []
    for path in files:
        recording = load_recording(path)
        if recording.ground_truth is None:
            raise ValueError(f"{path}: no ground_truth; fit-map needs paired recordings")
        sensor.append(recording.positions)
        truth.append(recording.ground_truth)
    database = None
    name = "database"
    if args.graph:
        graph = load_graph(args.graph)
        database = graph.poses
        name = "embedded" if args.graph == "default" else Path(args.graph).stem
    sensor_map, output_map = fit_sensor_maps(
        np.concatenate(sensor),
        np.concatenate(truth),
        sensor=args.sensor,
        truth=args.truth,
        database=database,
        database_name=name,
    )
    sensor_map.info["recordings"] = len(files)
    sensor_map.save(args.out)
    print(f"{sensor_map!r}: {len(files)} recordings, {sensor_map.info['pairs']} frames")
    print(
        f"mean joint distance to the truth {1000 * sensor_map.info['residual_before_m']:.1f} mm "
        f"before, {1000 * sensor_map.info['residual_m']:.1f} mm after; written {args.out}"
    )
    if output_map is not None:
        output_map.save(args.output_map)
        print(f"{output_map!r}: written {args.output_map}")
    if args.json:
        emit_json(
            {
                "out": args.out,
                "output_map": args.output_map,
                "recordings": len(files),
                "sensor_map": sensor_map.to_dict(),
            }
        )
    return 0
