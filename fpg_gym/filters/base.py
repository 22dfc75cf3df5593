"""The common interface of the per-joint reference filters, and the identity filter ``raw``.

A filter is a small stateful object that consumes one Kinect frame at a time:

- ``reset()`` forgets everything (the next frame starts a new stream);
- ``update(positions (J, 3), states (J,), timestamp) -> (J, 3)`` filters one frame;
- ``filter_sequence(positions (T, J, 3), states (T, J), timestamps (T,)) -> (T, J, 3)`` filters a
  whole clip from a fresh state (by default) and returns exactly what repeated ``update`` returns.

The recursion is sequential in time, so both run one Python step per frame; inside a step every
operation is vectorised over the joints and the three axes.

Tracking states use the Kinect SDK values (``NUI_SKELETON_POSITION_TRACKING_STATE`` in SDK v1,
``TrackingState`` in SDK 2.0, and the ``state`` column of the Kinect v2 files in the shared data):
0 not tracked, 1 inferred, 2 tracked. A joint whose position is not finite is treated as not
tracked whatever its state says.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import asdict, fields, replace
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from fpg_gym.core.skeleton import INFERRED, NOT_TRACKED, TRACKED, TRACKING_STATES

#: Frame period used when no timestamps are given (Kinect v1 and v2 run at 30 Hz).
DEFAULT_DT: Final[float] = 1.0 / 30.0

FloatArray = npt.NDArray[np.float64]
Float32Array = npt.NDArray[np.float32]


def _as_positions(positions: npt.ArrayLike, name: str, ndim: int) -> FloatArray:
    """Validate a frame ``(J, 3)`` (ndim 2) or a sequence ``(T, J, 3)`` (ndim 3) as float64."""
    array = np.asarray(positions, dtype=np.float64)
    if array.ndim != ndim or array.shape[-1] != 3:
        expected = "(J, 3)" if ndim == 2 else "(T, J, 3)"
        raise ValueError(f"{name}: expected an array of shape {expected}, got shape {array.shape}")
    return array


def _as_states(
    states: npt.ArrayLike | None, shape: tuple[int, ...], name: str
) -> npt.NDArray[np.int8]:
    """Validate tracking states against ``shape``; ``None`` means every joint is tracked."""
    if states is None:
        return np.full(shape, TRACKED, dtype=np.int8)
    array = np.asarray(states)
    if array.shape != shape:
        raise ValueError(f"{name}: expected shape {shape} (one state per joint), got {array.shape}")
    if array.size and not np.isin(array, TRACKING_STATES).all():
        bad = np.unique(array[~np.isin(array, TRACKING_STATES)])
        raise ValueError(
            f"{name}: tracking states must be 0 (not tracked), 1 (inferred) or 2 (tracked), "
            f"got {bad[:5].tolist()}"
        )
    return array.astype(np.int8)


def _as_timestamps(timestamps: npt.ArrayLike | None, length: int, name: str) -> FloatArray:
    """Validate timestamps in seconds, non-decreasing; ``None`` means 30 Hz from 0."""
    if timestamps is None:
        return np.arange(length, dtype=np.float64) * DEFAULT_DT
    array = np.asarray(timestamps, dtype=np.float64)
    if array.shape != (length,):
        raise ValueError(
            f"{name}: expected shape ({length},) (one time per frame), got {array.shape}"
        )
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: timestamps must be finite seconds")
    if length > 1 and not (np.diff(array) >= 0).all():
        first = int(np.argmax(np.diff(array) < 0)) + 1
        raise ValueError(f"{name}: timestamps must not decrease (frame {first} goes back in time)")
    return array


class JointFilter(ABC):
    """A per-joint causal filter of Kinect skeleton frames (see the module docstring).

    Subclasses implement ``_start`` (allocate state for ``J`` joints) and ``_step`` (one frame,
    vectorised over joints and axes); this class does the validation, the time bookkeeping and
    the sequence loop, so ``filter_sequence`` and repeated ``update`` share one code path.
    """

    def __init__(self) -> None:
        self._num_joints: int | None = None
        self._last_time: float | None = None
        self._tracked: npt.NDArray[np.int8] | None = None  # update_tracked's states

    # -- public API --------------------------------------------------------------------------

    @property
    def params(self) -> dict[str, Any]:
        """The filter's parameters as a JSON-serialisable dict (for run metadata)."""
        return {}

    def reset(self) -> None:
        """Forget all state: the next frame starts a new stream."""
        self._num_joints = None
        self._last_time = None

    def update(
        self,
        positions: npt.ArrayLike,
        states: npt.ArrayLike | None = None,
        timestamp: float | None = None,
    ) -> Float32Array:
        """Filter one frame.

        Parameters
        ----------
        positions
            ``(J, 3)`` joint positions in metres (J is 20 for the Kinect v1 skeleton).
        states
            ``(J,)`` tracking states (0 not tracked, 1 inferred, 2 tracked); ``None``: all tracked.
        timestamp
            Time of the frame in seconds; ``None``: one 30 Hz frame after the previous one.

        Returns
        -------
        numpy.ndarray
            ``(J, 3)`` float32 filtered positions.
        """
        frame = _as_positions(positions, "positions", 2)
        state = _as_states(states, frame.shape[:1], "states")
        if timestamp is None:
            time = 0.0 if self._last_time is None else self._last_time + DEFAULT_DT
        else:
            time = float(timestamp)
            if not np.isfinite(time):
                raise ValueError(f"timestamp: expected finite seconds, got {timestamp!r}")
        dt = self._advance(frame.shape[0], time)
        return self._step(frame, state, dt).astype(np.float32)

    def update_tracked(self, frame: FloatArray, timestamp: float) -> Float32Array:
        """:meth:`update` of a frame its caller has checked: ``(J, 3)`` float64 positions of
        tracked joints (a reconstructor's own outputs, every frame: the checks of :meth:`update`
        cost more than the filter's step)."""
        states, dt = self.advance_tracked(frame.shape[0], timestamp)
        return self._step(frame, states, dt).astype(np.float32)

    def advance_tracked(self, count: int, timestamp: float) -> tuple[npt.NDArray[np.int8], float]:
        """:meth:`update_tracked`'s bookkeeping for a frame of ``count`` tracked joints at
        ``timestamp``: the states (all tracked) and the interval its step takes (the state
        allocated on a stream's first frame)."""
        if not math.isfinite(timestamp):
            raise ValueError(f"timestamp: expected finite seconds, got {timestamp!r}")
        if self._tracked is None or len(self._tracked) != count:
            self._tracked = np.full(count, TRACKED, dtype=np.int8)
        return self._tracked, self._advance(count, timestamp)

    def filter_sequence(
        self,
        positions: npt.ArrayLike,
        states: npt.ArrayLike | None = None,
        timestamps: npt.ArrayLike | None = None,
        *,
        reset: bool = True,
    ) -> Float32Array:
        """Filter a whole sequence; equal to calling :meth:`update` on each frame in turn.

        Parameters
        ----------
        positions
            ``(T, J, 3)`` joint positions in metres.
        states
            ``(T, J)`` tracking states; ``None``: all tracked.
        timestamps
            ``(T,)`` non-decreasing times in seconds; ``None``: 30 Hz from 0.
        reset
            Start from a fresh state (default); ``False`` continues the current stream.

        Returns
        -------
        numpy.ndarray
            ``(T, J, 3)`` float32 filtered positions.
        """
        clip = _as_positions(positions, "positions", 3)
        state = _as_states(states, clip.shape[:2], "states")
        times = _as_timestamps(timestamps, clip.shape[0], "timestamps")
        if reset:
            self.reset()
        out = np.empty(clip.shape, dtype=np.float32)
        for t in range(clip.shape[0]):
            dt = self._advance(clip.shape[1], float(times[t]))
            out[t] = self._step(clip[t], state[t], dt)
        return out

    # -- for subclasses ----------------------------------------------------------------------

    def _advance(self, num_joints: int, time: float) -> float:
        """Check the joint count, allocate state on the first frame, return dt (0 on the first).

        ``dt`` may be 0 (a repeated timestamp, as non-decreasing recordings allow).
        """
        if self._num_joints is None:
            self._num_joints = num_joints
            self._start(num_joints)
            dt = 0.0
        else:
            if num_joints != self._num_joints:
                raise ValueError(
                    f"positions: this stream has {self._num_joints} joints, got a frame with "
                    f"{num_joints} (call reset() to start a new stream)"
                )
            assert self._last_time is not None
            dt = time - self._last_time
            if not dt >= 0.0:
                raise ValueError(
                    f"timestamp: must not decrease, got {time} after {self._last_time}"
                )
        self._last_time = time
        return dt

    @abstractmethod
    def _start(self, num_joints: int) -> None:
        """Allocate the state for ``num_joints`` joints (called on the first frame after reset)."""

    @abstractmethod
    def _step(self, frame: FloatArray, states: npt.NDArray[np.int8], dt: float) -> FloatArray:
        """Filter one validated frame ``(J, 3)`` float64; ``dt`` is 0 on the first frame."""

    def __repr__(self) -> str:
        args = ", ".join(f"{key}={value!r}" for key, value in self.params.items())
        return f"{type(self).__name__}({args})"


class PresetFilter(JointFilter):
    """A filter whose parameters are a dataclass: a named preset refined by keyword overrides.

    Parameters
    ----------
    preset : str
        The preset's name (kept for :attr:`params`).
    base : dataclass instance
        The preset's parameters.
    overrides : mapping of str to float or None
        Fields of ``base`` replaced (as floats; None stays None).

    Raises
    ------
    TypeError
        An override that is not a field of ``base``.
    """

    def __init__(self, preset: str, base: Any, overrides: Mapping[str, Any]) -> None:
        super().__init__()
        names = sorted(f.name for f in fields(base))
        unknown = set(overrides) - set(names)
        if unknown:
            raise TypeError(
                f"{type(self).__name__}: unknown parameter(s) {sorted(unknown)}; expected preset "
                f"or one of {names}"
            )
        self.preset = preset
        given = {k: None if v is None else float(v) for k, v in overrides.items()}
        self.settings = replace(base, **given)

    @property
    def params(self) -> dict[str, Any]:
        """Preset name and the effective parameters."""
        return {"preset": self.preset, **asdict(self.settings)}


class RawFilter(JointFilter):
    """The identity: returns the input frame as is (the ``raw`` reference method)."""

    def _start(self, num_joints: int) -> None:
        pass

    def _step(self, frame: FloatArray, states: npt.NDArray[np.int8], dt: float) -> FloatArray:
        return frame.copy()


def valid_joints(frame: FloatArray, states: npt.NDArray[np.int8]) -> npt.NDArray[np.bool_]:
    """``(J,)`` True where a joint has a measurement: not ``NOT_TRACKED`` and a finite position."""
    return (states != NOT_TRACKED) & np.isfinite(frame).all(axis=1)


__all__ = [
    "DEFAULT_DT",
    "INFERRED",
    "NOT_TRACKED",
    "TRACKED",
    "JointFilter",
    "RawFilter",
    "valid_joints",
]
