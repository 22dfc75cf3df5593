"""Is this a person in metres at a real frame rate? The checks every reader shares.

A file can be well formed and still wrong: a BVH in millimetres read as a 1,466 m person, a
positions ``.npz`` written in centimetres, a recording scaled by 10^6, ``fps`` 1e-9. Every
reader (BVH, DeepMimic, positions ``.npz``, each Kinect and tracker format, pose graphs) ends
with :func:`check_plausible`, which refuses, naming the file and the field:

* a coordinate beyond :data:`MAX_COORDINATE_M` (the sensors see to about 8 m);
* a body whose size (:func:`body_size`: head to ankles along the bones, median over frames)
  is outside :data:`BODY_SIZE_M` (adults measure 1.25-1.71 m here: the embedded humanoid 1.47 m,
  UI-PRMD's Vicon and Kinect v2 subjects 1.25-1.71 m, Bandai Namco's actors 1.35 m);
* a frame rate outside :data:`FRAME_RATE_HZ`.

An unusual but real input (a robot, a giant avatar, a 2 kHz capture) is read as it is with
``--accept-unusual`` on the command line, or within :func:`accepting_unusual` (both set
``$FPG_GYM_ACCEPT_UNUSUAL``, which worker processes inherit).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError

__all__ = [
    "ACCEPT_UNUSUAL_ENV",
    "BODY_SIZE_M",
    "FRAME_RATE_HZ",
    "MAX_COORDINATE_M",
    "UnusualInputError",
    "accepting_unusual",
    "body_size",
    "check_frame_rate",
    "check_plausible",
    "check_recording",
    "unusual_accepted",
]

#: Environment variable that turns the checks off (``1``); ``--accept-unusual`` sets it.
ACCEPT_UNUSUAL_ENV = "FPG_GYM_ACCEPT_UNUSUAL"
#: Largest plausible coordinate (metres): the sensors see up to about 8 m; mocap volumes span
#: tens of metres at most.
MAX_COORDINATE_M = 1000.0
#: Plausible body size (metres, :func:`body_size`): a small child to well beyond the tallest
#: adult. Millimetres (x1000), centimetres (x100), inches (x39) and feet (x3.3) fall outside.
BODY_SIZE_M = (0.4, 3.0)
#: Plausible frame rates (Hz).
FRAME_RATE_HZ = (1.0, 1000.0)
#: What a refusal tells the user to do about a real input.
_ACCEPT_HINT = "--accept-unusual reads it as it is"

_INDEX = {name: index for index, name in enumerate(skeleton.JOINT_NAMES)}
#: Bones from the head down the spine, then each leg to the ankle.
_SPINE = [("Head", "ShoulderCenter"), ("ShoulderCenter", "Spine"), ("Spine", "HipCenter")]
_LEGS = [
    [("HipLeft", "KneeLeft"), ("KneeLeft", "AnkleLeft")],
    [("HipRight", "KneeRight"), ("KneeRight", "AnkleRight")],
]
_BONES = np.array([[_INDEX[a], _INDEX[b]] for a, b in [*_SPINE, *_LEGS[0], *_LEGS[1]]])


class UnusualInputError(DataFormatError):
    """A well-formed input whose values are not a person in metres at a real frame rate."""


def unusual_accepted() -> bool:
    """Whether the plausibility checks are off (``$FPG_GYM_ACCEPT_UNUSUAL`` set, not ``0``)."""
    return os.environ.get(ACCEPT_UNUSUAL_ENV, "").strip() not in ("", "0")


@contextmanager
def accepting_unusual(accept: bool = True) -> Iterator[None]:
    """Within the block, readers accept unusual inputs (``accept``; else as before)."""
    previous = os.environ.get(ACCEPT_UNUSUAL_ENV)
    if accept:
        os.environ[ACCEPT_UNUSUAL_ENV] = "1"
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(ACCEPT_UNUSUAL_ENV, None)
        else:
            os.environ[ACCEPT_UNUSUAL_ENV] = previous


def body_size(positions: npt.ArrayLike, states: npt.ArrayLike | None = None) -> float | None:
    """Head to ankles along the bones (metres): the spine's three bones plus the mean leg
    (hip-knee-ankle), each bone's median length over the frames where it is seen.

    Parameters
    ----------
    positions : array_like, shape (T, 20, 3)
    states : array_like, shape (T, 20), optional
        Tracking states: only frames where both ends of a bone are tracked (2) count.

    Returns
    -------
    float or None
        None when a spine bone or both legs are never seen.
    """
    poses = np.asarray(positions, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
    lengths = np.linalg.norm(poses[:, _BONES[:, 0]] - poses[:, _BONES[:, 1]], axis=-1)
    seen = lengths > 0
    if states is not None:
        tracked = np.asarray(states).reshape(-1, skeleton.NUM_JOINTS) == skeleton.TRACKED
        seen &= tracked[:, _BONES[:, 0]] & tracked[:, _BONES[:, 1]]
    with warnings.catch_warnings():  # a bone never seen: its median is NaN, said below
        warnings.simplefilter("ignore", RuntimeWarning)
        medians = np.nanmedian(np.where(seen, lengths, np.nan), axis=0)
    spine, left, right = medians[:3], medians[3:5].sum(), medians[5:7].sum()
    legs = [leg for leg in (left, right) if np.isfinite(leg)]
    if not np.all(np.isfinite(spine)) or not legs:
        return None
    return float(spine.sum() + np.mean(legs))


def _unit_hint(size: float) -> str:
    """A guess at the unit a body of ``size`` "metres" was written in."""
    low, high = BODY_SIZE_M
    for unit, factor in (("millimetres", 1000.0), ("centimetres", 100.0), ("inches", 39.37)):
        if low <= size / factor <= high:
            return f"; {unit}? ({size / factor:.2f} m as {unit})"
    return ""


def check_frame_rate(
    path: str | os.PathLike[str], fps: float, *, field: str | None = "fps"
) -> None:
    """Refuse a frame rate outside :data:`FRAME_RATE_HZ` (unless :func:`unusual_accepted`).

    Raises
    ------
    UnusualInputError
        Naming ``path`` and ``field``.
    """
    low, high = FRAME_RATE_HZ
    if unusual_accepted() or low <= fps <= high:
        return
    raise UnusualInputError(
        path,
        f"a frame rate of {fps:g} Hz; expected {low:g}-{high:g} Hz ({_ACCEPT_HINT})",
        field=field,
    )


def check_plausible(
    path: str | os.PathLike[str],
    positions: npt.ArrayLike,
    *,
    fps: float | None = None,
    states: npt.ArrayLike | None = None,
    field: str | None = "positions",
) -> None:
    """Refuse what is not a person in metres at a real frame rate (see the module docstring),
    unless :func:`unusual_accepted`.

    Parameters
    ----------
    path : str or Path
        The file read (named in the message).
    positions : array_like, shape (T, 20, 3)
        Kinect-20 positions as read, in metres.
    fps : float, optional
        The frame rate (checked by :func:`check_frame_rate`).
    states : array_like, shape (T, 20), optional
        Tracking states (:func:`body_size` then measures tracked bones only).
    field : str, optional
        The field or array the positions came from.

    Raises
    ------
    UnusualInputError
        Naming ``path``, the field and what was expected.
    """
    if unusual_accepted():
        return
    poses = np.asarray(positions).reshape(-1, skeleton.NUM_JOINTS, 3)
    with np.errstate(invalid="ignore"):
        beyond = np.abs(poses) > MAX_COORDINATE_M
    if beyond.any():
        frame, joint = (int(i) for i in np.argwhere(beyond)[0][:2])
        value = float(np.abs(poses[frame, joint]).max())
        raise UnusualInputError(
            path,
            f"a coordinate of {value:g} m at frame {frame}, joint "
            f"{skeleton.JOINT_NAMES[joint]}; expected metres within ±{MAX_COORDINATE_M:g} m"
            f"{_unit_hint(body_size(poses, states) or 0.0)} ({_ACCEPT_HINT})",
            field=field,
        )
    size = body_size(poses, states)
    low, high = BODY_SIZE_M
    if size is not None and not low <= size <= high:
        raise UnusualInputError(
            path,
            f"the body measures {size:.4g} m from head to ankles (median over frames); "
            f"expected {low:g}-{high:g} m for a person in metres{_unit_hint(size)} "
            f"({_ACCEPT_HINT})",
            field=field,
        )
    if fps is not None:
        check_frame_rate(path, fps)


def check_recording(path: str | os.PathLike[str], recording: Any) -> None:
    """:func:`check_plausible` on a :class:`~fpg_gym.io.recording.Recording` as read: its
    positions (tracked bones measured), frame rate (from its timestamps) and ground truth.

    Raises
    ------
    UnusualInputError
        Naming ``path`` and the field.
    """
    check_plausible(path, recording.positions, states=recording.states)
    if recording.num_frames > 1:
        check_frame_rate(path, recording.fps, field="timestamps")
    if recording.ground_truth is not None:
        check_plausible(path, recording.ground_truth, field="ground_truth")
