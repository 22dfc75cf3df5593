"""The line machinery the Kinect text readers share (:mod:`fpg_gym.io.kinect`): reading a
file's lines, keeping the lines that hold the expected numbers, counting the others by reason
(:class:`LineLog`, one :class:`SkippedLinesWarning` per file) and building the recording
(:func:`finish_recording`: no-body frames, joints not tracked, last known positions).
"""

from __future__ import annotations

import math
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.io._compression import read_input_bytes
from fpg_gym.io.plausibility import MAX_COORDINATE_M, check_recording
from fpg_gym.io.recording import NOT_TRACKED, Recording

__all__ = [
    "DEFAULT_FPS",
    "MAX_BAD_SHARE",
    "LineLog",
    "SkippedLinesWarning",
    "coordinate_columns",
    "finish_recording",
    "implausible",
    "numeric_lines",
    "parse_numbers",
    "read_text",
    "timestamp_unit",
]

#: Frame rate assumed where a file gives none.
DEFAULT_FPS = 30.0
#: A file where more than this share of the data lines is unusable is refused.
MAX_BAD_SHARE = 0.5


class SkippedLinesWarning(UserWarning):
    """A reader skipped lines of a Kinect file (counts and reasons in the message)."""


def read_text(path: Path) -> list[str]:
    """The file's lines (gzip-compressed files are accepted)."""
    text = read_input_bytes(path).decode("utf-8", errors="replace")
    return text.removeprefix("\ufeff").splitlines()  # a byte-order mark is not a header


class LineLog:
    """Counts skipped lines by reason and remembers the first few line numbers."""

    def __init__(self) -> None:
        self.reasons: Counter[str] = Counter()
        self.first: list[int] = []
        self.first_reason: str = ""

    def skip(self, line: int, reason: str) -> None:
        if not self.reasons:
            self.first_reason = reason
        self.reasons[reason] += 1
        if len(self.first) < 10:
            self.first.append(line)

    @property
    def count(self) -> int:
        return int(sum(self.reasons.values()))

    def check(self, path: Path, kept: int, fmt: str) -> None:
        """Raise when nothing (or too little) was usable."""
        total = kept + self.count
        if total == 0:
            raise DataFormatError(path, f"no data lines (empty {fmt} file)")
        if kept == 0 or self.count > MAX_BAD_SHARE * total:
            raise DataFormatError(
                path,
                f"{self.count} of {total} data lines do not fit the {fmt} layout; first bad "
                f"line: {self.first_reason} (pass format= to pick another reader)",
                line=self.first[0],
            )

    def report(self, path: Path, total: int) -> dict[str, Any]:
        """Metadata entry; warns once when lines were skipped."""
        entry: dict[str, Any] = {
            "count": self.count,
            "reasons": dict(self.reasons),
            "first_lines": self.first,
        }
        if self.count:
            reasons = "; ".join(f"{n} x {r}" for r, n in self.reasons.most_common())
            warnings.warn(
                f"{path}: skipped {self.count} of {total} data lines ({reasons}); first at "
                f"line {self.first[0]}",
                SkippedLinesWarning,
                stacklevel=3,
            )
        return entry


def parse_numbers(fields: Sequence[str]) -> np.ndarray | None:
    """The fields as float64 numbers, or None when one is not a number."""
    try:
        values = np.array([float(f) for f in fields], dtype=np.float64)
    except ValueError:
        return None
    return values


def numeric_lines(
    lines: Iterable[tuple[int, Sequence[str]]],
    expected: int,
    log: LineLog,
    *,
    finite: bool = True,
    coordinates: np.ndarray | None = None,
) -> Iterator[tuple[int, np.ndarray]]:
    """``(line number, values)`` of the lines holding ``expected`` numbers (all finite when
    ``finite``, and the ``coordinates`` columns within :data:`MAX_COORDINATE_M`); every other
    line is logged as skipped, with the reason."""
    for number, fields in lines:
        if len(fields) != expected:
            log.skip(number, f"expected {expected} fields, got {len(fields)}")
            continue
        values = parse_numbers(fields)
        if values is None:
            log.skip(number, "a field is not a number")
            continue
        if finite and not np.all(np.isfinite(values)):
            log.skip(number, "NaN or inf value")
            continue
        if coordinates is not None and implausible(values[coordinates]):
            log.skip(number, f"a coordinate beyond ±{MAX_COORDINATE_M:g} m")
            continue
        yield number, values


def implausible(coordinates: np.ndarray) -> bool:
    """Whether a finite coordinate lies beyond :data:`MAX_COORDINATE_M` (NaN is not judged
    here)."""
    with np.errstate(invalid="ignore"):
        return bool(np.any(np.abs(coordinates) > MAX_COORDINATE_M))


def coordinate_columns(offset: int, joints: int, stride: int, first: int) -> np.ndarray:
    """Column indices of the x, y, z values of ``joints`` joints laid out every ``stride``
    columns from ``offset``, x at ``first`` within each group."""
    starts = offset + stride * np.arange(joints) + first
    return (starts[:, None] + np.arange(3)[None, :]).ravel()


def timestamp_unit(ticks: np.ndarray, candidates: Iterable[float]) -> float:
    """The unit (seconds per tick) that makes the median frame step closest to 1/30 s."""
    steps = np.diff(ticks)
    steps = steps[steps > 0]
    if len(steps) == 0:
        return next(iter(candidates))
    step = float(np.median(steps))
    return min(candidates, key=lambda unit: abs(math.log(step * unit * DEFAULT_FPS)))


def finish_recording(
    path: Path,
    positions: np.ndarray,
    states: np.ndarray,
    timestamps: np.ndarray,
    body: np.ndarray,
    metadata: dict[str, Any],
) -> Recording:
    """Mark no-body frames and zero joints not tracked, fill their positions, build it."""
    positions = positions.astype(np.float64)
    states = states.astype(np.int8)
    zero = np.all(positions == 0.0, axis=-1)  # (T, 20): the sensor reported no position
    missing = zero | ~body[:, None]
    states[missing] = NOT_TRACKED
    if not body.any():
        raise DataFormatError(path, "no frame holds a body (every frame is empty)")
    filled = 0
    if missing.any():
        count = len(positions)
        frame = np.arange(count)[:, None]
        last = np.maximum.accumulate(np.where(missing, -1, frame), axis=0)  # (T, 20)
        known = ~missing
        first = np.where(known.any(axis=0), np.argmax(known, axis=0), 0)  # (20,)
        source = np.where(last >= 0, last, first[None, :])
        fill = positions[source, np.arange(skeleton.NUM_JOINTS)[None, :]]
        positions = np.where(missing[..., None], fill, positions)
        filled = int(missing.sum())
    metadata.update(
        {
            "source": str(path),
            "joint_set": "kinect20",
            "no_body_frames": int((~body).sum()),
            "filled_joint_frames": filled,
            "untracked_positions": "last_known" if filled else "sensor",
        }
    )
    recording = Recording(
        positions=positions.astype(np.float32),
        states=states,
        timestamps=timestamps,
        metadata=metadata,
    )
    check_recording(path, recording)
    return recording
