"""``fpg-gym simulate``: simulate a Kinect recording (with ground truth) from a mocap clip."""

from __future__ import annotations

import argparse
import sys

from fpg_gym.commands import types

NAME = "simulate"
HELP = "simulate a Kinect recording with ground truth from a mocap clip (see --list)"

_DEFAULT_PREFIX = "default:"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "input",
        nargs="?",
        metavar="INPUT",
        help="mocap file (BVH, .bvh.gz, DeepMimic .txt, positions .npz) or default:NAME for an "
        "embedded DeepMimic clip (default:walk)",
    )
    parser.add_argument("--scenario", default="front-few", help="scenario name (see --list)")
    parser.add_argument("--seed", type=types.seed, default=0, help="random seed (default 0)")
    parser.add_argument("--out", metavar="FILE", help="recording file to write (.npz)")
    parser.add_argument(
        "--units", default="auto", choices=["auto", "m", "cm", "mm"], help="BVH length unit"
    )
    parser.add_argument("--list", action="store_true", help="list the scenarios and exit")
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def _read_input(text: str, units: str) -> object:
    from fpg_gym.io import DEFAULT_CLIP_NAMES, load_default_clips, read_clip

    if text.startswith(_DEFAULT_PREFIX):
        name = text[len(_DEFAULT_PREFIX) :]
        if name not in DEFAULT_CLIP_NAMES:
            raise ValueError(
                f"unknown embedded clip {name!r}; expected one of {', '.join(DEFAULT_CLIP_NAMES)}"
            )
        return load_default_clips([name])[0]
    return read_clip(text, units=units)


def run(args: argparse.Namespace) -> int:
    """Simulate, write the recording and print its statistics."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.core import metrics
    from fpg_gym.core.outputs import check_output
    from fpg_gym.io import write_recording
    from fpg_gym.simulate import SCENARIOS, get_scenario, simulate

    if args.list:
        width = max(len(name) for name in SCENARIOS)
        for name, scenario in SCENARIOS.items():
            print(f"{name:<{width}}  {scenario.description}")
        if args.json:
            emit_json({"scenarios": {n: s.description for n, s in SCENARIOS.items()}})
        return 0
    if not args.input or not args.out:
        print(
            "fpg-gym simulate: error: INPUT and --out are required (or pass --list)",
            file=sys.stderr,
        )
        return 2
    scenario = get_scenario(args.scenario)  # ValueError names the known scenarios
    inputs = [] if args.input.startswith(_DEFAULT_PREFIX) else [args.input]
    check_output(args.out, inputs, npz=True)  # before any work
    clip = _read_input(args.input, args.units)
    recording = simulate(clip, scenario, seed=args.seed)  # type: ignore[arg-type]
    path = write_recording(args.out, recording)
    assert recording.ground_truth is not None
    errors = metrics.frame_error(recording.ground_truth, recording.positions)
    shares = recording.state_shares()
    stats = recording.metadata["stats"]
    print(f"scenario         {scenario.name} (seed {args.seed})")
    print(f"frames           {recording.num_frames} at {recording.fps:.3g} Hz")
    err_02 = 100 * metrics.err_ratio(errors)
    print(f"raw error        {errors.mean():.3f} m (Eq. 13), Err0.2 {err_02:.1f} %")
    print(
        f"states           inferred {100 * shares['inferred']:.1f} %, "
        f"not tracked {100 * shares['not_tracked']:.1f} %"
    )
    ms = stats["ms_per_frame"]
    print(f"time             {ms:.3f} ms per frame (this run, start-up included)")
    print(f"written          {path}")
    if args.json:
        emit_json(
            {
                "out": str(path),
                "scenario": scenario.name,
                "seed": args.seed,
                "frames": recording.num_frames,
                "raw_error_m": float(errors.mean()),
                "err_0_2": metrics.err_ratio(errors),
                "inferred_share": shares["inferred"],
                "not_tracked_share": shares["not_tracked"],
                "ms_per_frame": stats["ms_per_frame"],
            }
        )
    return 0
