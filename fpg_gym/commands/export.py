"""``fpg-gym export``: a reconstruction (or a recording) as BVH or CSV for other tools."""

from __future__ import annotations

import argparse
from typing import Any

NAME = "export"
HELP = (
    "write a reconstruction .npz (fpg-gym reconstruct --out) or a recording as BVH (rotations "
    "solved from the positions) or CSV, for animation and biomechanics tools"
)

#: Formats by file extension.
EXPORT_FORMATS: tuple[str, ...] = ("bvh", "csv")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument("input", metavar="IN.npz", help="reconstruction or recording .npz")
    parser.add_argument(
        "--out", required=True, metavar="FILE", help="output file: .bvh or .csv (by extension)"
    )
    parser.add_argument(
        "--key",
        default=None,
        metavar="NAME",
        help="which poses: 'poses' (a reconstruction's, the default when present), 'positions' "
        "(a recording's raw input) or 'ground_truth'",
    )


def _format(path: Any) -> str:
    suffix = str(path).lower().rsplit(".", 1)[-1]
    if suffix not in EXPORT_FORMATS:
        raise ValueError(f"--out {path}: expected a .bvh or .csv file name")
    return suffix


def _timestamps(path: str, stamps: Any, count: int) -> tuple[Any, float, str]:
    """``(timestamps, fps, note)`` of the exported frames: the file's timestamps, checked
    (one per frame, finite, increasing, a plausible rate), or 30 Hz when it has none (said in
    the note).

    Raises
    ------
    DataFormatError
        Timestamps that do not fit the poses, naming the file and the field.
    """
    import numpy as np

    from fpg_gym.core.errors import DataFormatError
    from fpg_gym.io.plausibility import check_frame_rate

    if stamps is None:
        return np.arange(count) / 30.0, 30.0, " (no timestamps in the file: 30 Hz assumed)"
    stamps = np.asarray(stamps)
    if stamps.shape != (count,) or not np.issubdtype(stamps.dtype, np.number):
        raise DataFormatError(
            path,
            f"expected {count} numbers (one per frame), got shape {stamps.shape} of {stamps.dtype}",
            field="timestamps",
        )
    stamps = stamps.astype(np.float64)
    steps = np.diff(stamps)
    if not np.all(np.isfinite(stamps)) or np.any(steps < 0):
        raise DataFormatError(
            path, "expected finite seconds that never decrease", field="timestamps"
        )
    if count > 1 and not np.any(steps > 0):
        raise DataFormatError(
            path, "every frame has the same time; expected seconds", field="timestamps"
        )
    fps = float(1.0 / np.median(steps[steps > 0])) if count > 1 else 30.0
    check_frame_rate(path, fps, field="timestamps")
    return stamps, fps, ""


def run(args: argparse.Namespace) -> int:
    """Write the file; print what was written."""
    import numpy as np

    from fpg_gym.core import skeleton
    from fpg_gym.core.errors import DataFormatError
    from fpg_gym.core.outputs import atomic_path, check_output
    from fpg_gym.io import Recording
    from fpg_gym.io.bvh_write import write_bvh
    from fpg_gym.io.kinect import write_csv
    from fpg_gym.io.npz import load_npz
    from fpg_gym.io.plausibility import check_plausible

    kind = _format(args.out)
    out = check_output(args.out, [args.input])
    arrays = load_npz(args.input)
    key = args.key or ("poses" if "poses" in arrays else "positions")
    if key not in arrays:
        raise DataFormatError(
            args.input, f"no array {key!r} (it holds {', '.join(sorted(arrays))}); pass --key"
        )
    poses = np.asarray(arrays[key], dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (skeleton.NUM_JOINTS, 3) or not len(poses):
        raise DataFormatError(
            args.input, f"expected (T, 20, 3) poses, got shape {poses.shape}", field=key
        )
    if not np.all(np.isfinite(poses)):
        raise DataFormatError(args.input, "NaN or inf in the poses", field=key)
    check_plausible(args.input, poses, field=key)
    count = len(poses)
    stamps, fps, rate_note = _timestamps(args.input, arrays.get("timestamps"), count)
    if kind == "bvh":
        write_bvh(out, poses, fps=fps)
    else:
        recording = Recording(
            positions=poses.astype(np.float32),
            states=np.full((count, skeleton.NUM_JOINTS), skeleton.TRACKED, dtype=np.int8),
            timestamps=stamps,
        )
        with atomic_path(out) as partial:
            write_csv(partial, recording)
    print(f"written          {out} ({count} frames of {key!r}, {fps:.3g} Hz{rate_note}, {kind})")
    return 0
