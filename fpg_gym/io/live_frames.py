"""The live wire format: one JSON object per line, UTF-8 (:mod:`fpg_gym.methods.live` reads it).

``{"timestamp": 12.033, "joints": [[x, y, z], ... 20 ...], "states": [2, 2, 1, ...]}``

(the fields in :mod:`fpg_gym.methods.live`'s docstring); ``{"end": true}`` ends a stream.
:func:`parse_frame` reads a line into a :class:`LiveFrame` or raises a :class:`FrameError` whose
``reason`` is a short category for the counts; :func:`frame_line` writes one (what a sender
writes); :func:`is_end` recognises the end marker.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import FpgGymError
from fpg_gym.io.plausibility import MAX_COORDINATE_M  # a larger coordinate is a corrupt frame

__all__ = ["MAX_TIMESTAMP_S", "FrameError", "LiveFrame", "frame_line", "is_end", "parse_frame"]

#: Largest plausible timestamp (seconds, about 31,700 years): beyond it, a frame is corrupt (and
#: a float64 no longer resolves a frame interval well).
MAX_TIMESTAMP_S = 1e12


class FrameError(FpgGymError, ValueError):
    """A malformed live frame; ``reason`` is a short category for the counts."""

    def __init__(self, reason: str, detail: str = "") -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}" if detail else reason)


@dataclass(frozen=True)
class LiveFrame:
    """One received frame.

    Attributes
    ----------
    index : int
        Sequence number among well-formed frames (0, 1, ...).
    timestamp : float or None
        Seconds, as sent (None: not sent).
    positions : ndarray, shape (20, 3), float32
    states : ndarray, shape (20,), int8
    received : float
        ``time.perf_counter()`` when the line arrived.
    """

    index: int
    timestamp: float | None
    positions: np.ndarray
    states: np.ndarray
    received: float


def _joint_values(value: Any, name: str, width: int) -> np.ndarray:
    """A list of 20 (or an object naming all 20 joints) as an array ``(20, width)``."""
    if isinstance(value, dict):
        missing = [j for j in skeleton.JOINT_NAMES if j not in value]
        if missing:
            raise FrameError(f"{name} lacks joints", f"e.g. {missing[:3]}")
        value = [value[j] for j in skeleton.JOINT_NAMES]
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise FrameError(f"{name} not numbers") from None
    shape = (skeleton.NUM_JOINTS, width) if width > 1 else (skeleton.NUM_JOINTS,)
    if array.shape != shape:
        raise FrameError(f"{name} wrong shape", f"expected {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise FrameError(f"{name} not finite")
    return array


def parse_frame(line: str | bytes, index: int = 0, received: float | None = None) -> LiveFrame:
    """Parse one JSON line of the wire format (module docstring).

    Raises
    ------
    FrameError
        On anything that does not fit the format (``reason`` names the category).
    """
    try:
        data = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        raise FrameError("not JSON") from None
    if not isinstance(data, dict):
        raise FrameError("not a JSON object")
    if "joints" not in data:
        raise FrameError("no joints")
    positions = _joint_values(data["joints"], "joints", 3)
    if np.abs(positions).max() > MAX_COORDINATE_M:
        raise FrameError("joints implausible", f"a coordinate beyond ±{MAX_COORDINATE_M:g} m")
    states: np.ndarray
    if data.get("states") is None:
        states = np.full(skeleton.NUM_JOINTS, skeleton.TRACKED, dtype=np.int8)
    else:
        values = _joint_values(data["states"], "states", 1)
        if not np.all(np.isin(values, skeleton.TRACKING_STATES)):
            raise FrameError("states not 0, 1 or 2")
        states = values.astype(np.int8)
    stamp = data.get("timestamp")
    if stamp is not None:
        if isinstance(stamp, bool) or not isinstance(stamp, int | float):
            raise FrameError("timestamp not a number")
        try:
            stamp = float(stamp)
        except OverflowError:
            raise FrameError("timestamp not finite") from None
        if not math.isfinite(stamp):
            raise FrameError("timestamp not finite")
        if abs(stamp) > MAX_TIMESTAMP_S:
            raise FrameError("timestamp implausible", f"beyond ±{MAX_TIMESTAMP_S:g} s")
    return LiveFrame(
        index=index,
        timestamp=stamp,
        positions=positions.astype(np.float32),
        states=states,
        received=time.perf_counter() if received is None else received,
    )


def frame_line(
    positions: np.ndarray, states: np.ndarray | None = None, timestamp: float | None = None
) -> str:
    """One frame in the wire format (what a sender writes; values kept exactly)."""
    data: dict[str, Any] = {}
    if timestamp is not None:
        data["timestamp"] = float(timestamp)
    data["joints"] = np.asarray(positions, dtype=np.float64).tolist()
    if states is not None:
        data["states"] = np.asarray(states, dtype=int).tolist()
    return json.dumps(data, separators=(",", ":"))


def is_end(line: str | bytes) -> bool:
    """Whether a line is the end-of-stream marker ``{"end": true}``."""
    text = line.decode("utf-8", errors="replace") if isinstance(line, bytes) else line
    text = text.strip()
    if not text.startswith("{") or "end" not in text:
        return False
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError):
        return False
    return isinstance(data, dict) and data.get("end") is True
