"""A 3D view of a stream: the Kinect input coloured by tracking state, reconstructions and the
ground truth, over time, as a rerun recording (``.rrd``; https://rerun.io).

The file opens in the rerun viewer (``rerun VIEW.rrd``, or ``fpg-gym view ... --spawn``) and
needs nothing else to be written: no display, no window (headless). Entities, all in the
input's camera space (metres, Y up, right-handed)::

    input/joints, input/bones                Kinect input; joints green tracked, orange
                                             inferred, red not tracked
    reconstruction/<method>/joints, /bones   one per method (blue, purple, ...)
    ground_truth/joints, /bones              grey, when the recording has it
    error/<method>                           FPG Eq. 13 error per frame (m), with ground truth

Timelines: ``frame`` (the frame index) and ``time`` (the recording's seconds).

rerun-sdk is an optional extra (``pip install 'fpg-gym[view]'``): a ~170 MB wheel with pyarrow,
about 1 s to import, so it is imported only here, when a view is written.
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import metrics, skeleton
from fpg_gym.core.errors import FpgGymError, import_optional
from fpg_gym.core.outputs import atomic_path

__all__ = [
    "STATE_COLORS",
    "ViewUnavailable",
    "require_rerun",
    "rerun_available",
    "write_view",
]

#: Joint colours by tracking state (not tracked, inferred, tracked), RGB.
STATE_COLORS: np.ndarray = np.array([[220, 40, 40], [240, 160, 0], [40, 180, 60]], dtype=np.uint8)
#: Colours of the reconstructions, in the order given; then the ground truth's.
METHOD_COLORS: tuple[tuple[int, int, int], ...] = (
    (50, 110, 230),
    (150, 70, 200),
    (0, 170, 190),
    (200, 90, 140),
)
TRUTH_COLOR = (170, 170, 170)
JOINT_RADIUS_M = 0.02
BONE_RADIUS_M = 0.008


class ViewUnavailable(FpgGymError, ImportError):
    """rerun-sdk (the ``view`` extra) is not installed."""


def require_rerun() -> Any:
    """The rerun module, or :class:`ViewUnavailable` saying how to install it."""
    return import_optional(  # optional extra (fpg-gym[view]): ~1 s to import, only for the view
        "rerun",
        ViewUnavailable(
            "the 3D view needs rerun-sdk: pip install 'fpg-gym[view]' (or pip install rerun-sdk)"
        ),
    )


def rerun_available() -> bool:
    """Whether rerun-sdk can be imported (without importing it)."""
    return importlib.util.find_spec("rerun") is not None


def _bones(poses: np.ndarray) -> np.ndarray:
    """``(T, 19, 2, 3)`` segments parent -> child."""
    return np.stack([poses[:, skeleton.BONES[:, 0]], poses[:, skeleton.BONES[:, 1]]], axis=2)


def write_view(
    path: str | os.PathLike[str],
    positions: np.ndarray,
    states: np.ndarray,
    timestamps: np.ndarray | None = None,
    *,
    reconstructions: Mapping[str, np.ndarray] | None = None,
    ground_truth: np.ndarray | None = None,
    name: str = "fpg-gym",
) -> Path:
    """Write the 3D view of a stream as a rerun ``.rrd`` file (entities in the module
    docstring).

    Parameters
    ----------
    path : str or Path
        The ``.rrd`` file (written beside, then renamed).
    positions : array_like, shape (T, 20, 3)
        The Kinect input.
    states : array_like, shape (T, 20)
        Its tracking states (0, 1, 2).
    timestamps : array_like, shape (T,), optional
        Seconds (30 Hz when omitted).
    reconstructions : mapping of str to array_like (T', 20, 3), optional
        Poses by method name; T' <= T (an interrupted run shows the frames it has).
    ground_truth : array_like, shape (T, 20, 3), optional
    name : str
        The recording's application id (shown by the viewer).

    Raises
    ------
    ViewUnavailable
        Without rerun-sdk.
    ValueError
        On shapes that do not fit.
    """
    rr = require_rerun()
    positions = np.asarray(positions, dtype=np.float32)
    count = len(positions)
    if positions.shape != (count, skeleton.NUM_JOINTS, 3) or count == 0:
        raise ValueError(f"positions: expected shape (T, 20, 3), got {positions.shape}")
    states = np.asarray(states, dtype=np.int64)
    if states.shape != (count, skeleton.NUM_JOINTS) or not np.all(np.isin(states, (0, 1, 2))):
        raise ValueError(f"states: expected (T, 20) values 0, 1, 2; got shape {states.shape}")
    stamps = np.arange(count) / 30.0 if timestamps is None else np.asarray(timestamps, np.float64)
    layers: dict[str, tuple[np.ndarray, tuple[int, int, int]]] = {}
    for i, (method, poses) in enumerate((reconstructions or {}).items()):
        poses = np.asarray(poses, dtype=np.float32)
        if poses.ndim != 3 or poses.shape[1:] != (20, 3) or len(poses) > count:
            raise ValueError(f"reconstruction {method!r}: expected (T<={count}, 20, 3) poses")
        layers[f"reconstruction/{method}"] = (poses, METHOD_COLORS[i % len(METHOD_COLORS)])
    if ground_truth is not None:
        truth = np.asarray(ground_truth, dtype=np.float32)
        if truth.shape != positions.shape:
            raise ValueError(f"ground_truth: expected shape {positions.shape}, got {truth.shape}")
        layers["ground_truth"] = (truth, TRUTH_COLOR)

    stream = rr.RecordingStream(name)
    errors = {
        method.removeprefix("reconstruction/"): metrics.frame_error(truth[: len(p)], p)
        for method, (p, _) in layers.items()
        if ground_truth is not None and method != "ground_truth"
    }
    with atomic_path(path) as partial:
        stream.save(str(partial))
        stream.log("/", rr.ViewCoordinates.RIGHT_HAND_Y_UP, static=True)
        bones = {entity: _bones(p) for entity, (p, _) in layers.items()}
        input_bones = _bones(positions)
        for t in range(count):
            stream.set_time("frame", sequence=t)
            stream.set_time("time", duration=float(stamps[t] - stamps[0]))
            stream.log(
                "input/joints",
                rr.Points3D(positions[t], colors=STATE_COLORS[states[t]], radii=JOINT_RADIUS_M),
            )
            stream.log(
                "input/bones",
                rr.LineStrips3D(input_bones[t], colors=[(200, 200, 200)], radii=BONE_RADIUS_M),
            )
            for entity, (poses, color) in layers.items():
                if t >= len(poses):
                    continue
                stream.log(
                    f"{entity}/joints", rr.Points3D(poses[t], colors=[color], radii=JOINT_RADIUS_M)
                )
                stream.log(
                    f"{entity}/bones",
                    rr.LineStrips3D(bones[entity][t], colors=[color], radii=BONE_RADIUS_M),
                )
            for method, error in errors.items():
                if t < len(error):
                    stream.log(f"error/{method}", rr.Scalars(float(error[t])))
        stream.flush()
        stream.disconnect()  # closes the file sink: everything is on disk before the rename
    return Path(path)
