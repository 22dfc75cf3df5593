"""The :class:`Recording`: a Kinect skeleton stream, and its ``.npz`` file format.

A recording is what a Kinect (or the simulator in :mod:`fpg_gym.simulate`) reports, mapped to
the Kinect-20 skeleton (:data:`fpg_gym.core.skeleton.JOINT_NAMES`), in the sensor's camera space:
metres, Y up, Z away from the sensor, X towards the sensor's left (Kinect SDK convention; a user
facing the sensor has the left shoulder at negative X).

File format (``.npz``, no pickle, exactly these keys):

============== ============ =========================================================
key            dtype/shape  content
============== ============ =========================================================
positions      f4 (T,20,3)  reported joint positions, metres, camera space; never NaN
states         i1 (T,20)    2 tracked, 1 inferred, 0 not tracked
timestamps     f8 (T,)      seconds, non-decreasing (0 at the first frame for readers)
ground_truth   f4 (T,20,3)  optional: the true positions in the same space (simulator)
occluded       b1 (T,20)    optional: joints the sensor could not see (simulator, benchmarks)
metadata       str (JSON)   source, format, joint_set, untracked_positions, ...
============== ============ =========================================================

A not-tracked joint still carries a finite position. ``metadata["untracked_positions"]`` says
which convention the file uses: ``"sensor"`` (whatever the sensor reported), ``"last_known"``
(the joint's last position from a frame in which the body was seen, the first seen position
for frames before that) or ``"simulated"`` (the simulator's drifting estimate).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import save_npz
from fpg_gym.core.skeleton import INFERRED, NOT_TRACKED, TRACKED
from fpg_gym.io.files import check_input_file
from fpg_gym.io.npz import check_npz
from fpg_gym.io.plausibility import check_recording

__all__ = [
    "INFERRED",
    "NOT_TRACKED",
    "RECORDING_KEYS",
    "TRACKED",
    "UNTRACKED_CONVENTIONS",
    "Recording",
    "load_recording",
    "write_recording",
]

#: Keys of a recording ``.npz`` file (``ground_truth`` optional).
RECORDING_KEYS: tuple[str, ...] = (
    "positions",
    "states",
    "timestamps",
    "ground_truth",
    "occluded",
    "metadata",
)
#: Values of ``metadata["untracked_positions"]``.
UNTRACKED_CONVENTIONS: tuple[str, ...] = ("sensor", "last_known", "simulated")
_REQUIRED = ("positions", "states", "timestamps", "metadata")
#: The shapes of a recording's arrays (``T`` frames), checked before they are inflated.
_SHAPES: dict[str, tuple[int | str, ...]] = {
    "positions": ("T", skeleton.NUM_JOINTS, 3),
    "states": ("T", skeleton.NUM_JOINTS),
    "timestamps": ("T",),
    "ground_truth": ("T", skeleton.NUM_JOINTS, 3),
    "metadata": (),
}


def _validate_positions(value: object, name: str, count: int | None) -> np.ndarray:
    array = np.asarray(value)
    if array.ndim != 3 or array.shape[1:] != (skeleton.NUM_JOINTS, 3):
        raise ValueError(f"{name}: expected shape (T, 20, 3), got {array.shape}")
    if count is not None and len(array) != count:
        raise ValueError(f"{name}: expected {count} frames, got {len(array)}")
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise ValueError(f"{name}: expected real numbers, got dtype {array.dtype}")
    with np.errstate(invalid="ignore"):
        beyond = np.abs(array) > np.finfo(np.float32).max
    if beyond.any():
        frame, joint = (int(i) for i in np.argwhere(beyond)[0][:2])
        raise ValueError(
            f"{name}: value {float(array[frame, joint].max()):g} at frame {frame}, joint "
            f"{skeleton.JOINT_NAMES[joint]} is beyond the float32 range (metres expected)"
        )
    array = array.astype(np.float32)
    if not np.all(np.isfinite(array)):
        frame, joint = (int(i) for i in np.argwhere(~np.isfinite(array))[0][:2])
        raise ValueError(
            f"{name}: NaN or inf at frame {frame}, joint {skeleton.JOINT_NAMES[joint]}; a "
            "not-tracked joint must carry a finite position (state 0 marks it)"
        )
    return array


@dataclass(frozen=True)
class Recording:
    """A Kinect skeleton stream on the Kinect-20 skeleton, in camera space.

    Attributes
    ----------
    positions : ndarray, shape (T, 20, 3), float32
        Reported joint positions in metres (finite everywhere).
    states : ndarray, shape (T, 20), int8
        2 tracked, 1 inferred, 0 not tracked.
    timestamps : ndarray, shape (T,), float64
        Seconds, non-decreasing.
    ground_truth : ndarray, shape (T, 20, 3), float32, or None
        True positions in the same space, when known (simulated streams).
    occluded : ndarray, shape (T, 20), bool, or None
        Which joints the sensor could not see, when known (the simulator and the occlusion
        benchmark mark them): scores split occluded and visible joints with it.
    metadata : dict
        JSON-serialisable: ``source``, ``format``, ``joint_set``, ``untracked_positions`` and,
        for readers, ``skipped_lines``/``no_body_frames``; for the simulator ``scenario``,
        ``seed``, ``camera``, ``parameters``.

    Raises
    ------
    ValueError
        On a wrong shape, a NaN/inf value, a state outside {0, 1, 2}, decreasing timestamps or
        metadata that JSON cannot encode.
    """

    positions: np.ndarray
    states: np.ndarray
    timestamps: np.ndarray
    ground_truth: np.ndarray | None = None
    metadata: dict[str, Any] = field(default_factory=dict, compare=False)
    occluded: np.ndarray | None = None

    def __post_init__(self) -> None:
        positions = _validate_positions(self.positions, "positions", None)
        count = len(positions)
        if count == 0:
            raise ValueError("positions: a recording needs at least one frame")
        states = np.asarray(self.states)
        if states.shape != (count, skeleton.NUM_JOINTS):
            raise ValueError(f"states: expected shape ({count}, 20), got {states.shape}")
        if not np.issubdtype(states.dtype, np.integer):
            if not (
                np.issubdtype(states.dtype, np.floating) and np.all(states == np.round(states))
            ):
                raise ValueError(f"states: expected integers 0, 1, 2, got dtype {states.dtype}")
        invalid = ~np.isin(states, skeleton.TRACKING_STATES)
        if invalid.any():
            frame, joint = (int(i) for i in np.argwhere(invalid)[0])
            raise ValueError(
                f"states: expected 0 (not tracked), 1 (inferred) or 2 (tracked), got "
                f"{states[frame, joint]} at frame {frame}, joint {skeleton.JOINT_NAMES[joint]}"
            )
        timestamps = np.asarray(self.timestamps, dtype=np.float64)
        if timestamps.shape != (count,):
            raise ValueError(f"timestamps: expected shape ({count},), got {timestamps.shape}")
        if not np.all(np.isfinite(timestamps)):
            raise ValueError("timestamps: NaN or inf value")
        if count > 1 and np.any(np.diff(timestamps) < 0):
            frame = int(np.argmax(np.diff(timestamps) < 0)) + 1
            raise ValueError(f"timestamps: must not decrease (frame {frame} goes back in time)")
        truth = self.ground_truth
        if truth is not None:
            truth = _validate_positions(truth, "ground_truth", count)
        occluded = self.occluded
        if occluded is not None:
            occluded = np.asarray(occluded)
            if occluded.shape != (count, skeleton.NUM_JOINTS):
                raise ValueError(f"occluded: expected shape ({count}, 20), got {occluded.shape}")
            if occluded.dtype != np.bool_ and not np.isin(occluded, (0, 1)).all():
                raise ValueError("occluded: expected booleans (0 or 1)")
            occluded = occluded.astype(bool)
        metadata = dict(self.metadata)
        try:
            json.dumps(metadata)
        except (TypeError, ValueError) as error:
            raise ValueError(f"metadata: must be JSON-serialisable ({error})") from None
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "states", states.astype(np.int8))
        object.__setattr__(self, "timestamps", timestamps)
        object.__setattr__(self, "ground_truth", truth)
        object.__setattr__(self, "occluded", occluded)
        object.__setattr__(self, "metadata", metadata)

    @property
    def num_frames(self) -> int:
        """Number of frames T."""
        return int(self.positions.shape[0])

    @property
    def fps(self) -> float:
        """Frame rate from the median frame interval (30.0 for a one-frame recording)."""
        if self.num_frames < 2:
            return 30.0
        steps = np.diff(self.timestamps)
        steps = steps[steps > 0]
        return float(1.0 / np.median(steps)) if len(steps) else 30.0

    @property
    def body_present(self) -> np.ndarray:
        """``(T,)`` bool: frames in which at least one joint is tracked or inferred."""
        return skeleton.body_present(self.states)

    def state_shares(self) -> dict[str, float]:
        """Shares of tracked, inferred and not-tracked joint-frames."""
        total = self.states.size
        return {
            "tracked": float(np.count_nonzero(self.states == TRACKED) / total),
            "inferred": float(np.count_nonzero(self.states == INFERRED) / total),
            "not_tracked": float(np.count_nonzero(self.states == NOT_TRACKED) / total),
        }

    def head(self, count: int | None) -> Recording:
        """The first ``count`` frames (the recording itself when it is not longer, or ``count``
        is None); ``metadata["cut_to_frames"]`` records the cut."""
        if count is None or self.num_frames <= count:
            return self
        if count < 1:
            raise ValueError(f"count: expected at least 1 frame, got {count}")
        truth, occluded = self.ground_truth, self.occluded
        return Recording(
            positions=self.positions[:count],
            states=self.states[:count],
            timestamps=self.timestamps[:count],
            ground_truth=None if truth is None else truth[:count],
            metadata={**self.metadata, "cut_to_frames": int(count)},
            occluded=None if occluded is None else occluded[:count],
        )

    def __repr__(self) -> str:
        truth = ", ground_truth" if self.ground_truth is not None else ""
        source = self.metadata.get("source", "")
        return f"Recording(frames={self.num_frames}, fps={self.fps:.3g}{truth}, source={source!r})"


def write_recording(path: str | Path, recording: Recording) -> Path:
    """Write a recording as a compressed ``.npz`` file (see the module docstring).

    The file is written beside its target and renamed into place (a crash never leaves a
    half-written recording).

    Returns
    -------
    Path
        The path written (``.npz`` is appended when the name lacks it, numpy's rule).
    """
    path = Path(path)
    arrays: dict[str, npt.NDArray[Any]] = {
        "positions": recording.positions.astype(np.float32),
        "states": recording.states.astype(np.int8),
        "timestamps": recording.timestamps.astype(np.float64),
        "metadata": np.array(json.dumps(recording.metadata, sort_keys=True)),
    }
    if recording.ground_truth is not None:
        arrays["ground_truth"] = recording.ground_truth.astype(np.float32)
    if recording.occluded is not None:
        arrays["occluded"] = recording.occluded.astype(bool)
    return save_npz(path, arrays)


def load_recording(path: str | Path) -> Recording:
    """Read a recording ``.npz`` file written by :func:`write_recording` (or by anyone).

    Raises
    ------
    DataFormatError
        If the file is not an ``.npz`` archive, a key is missing or unknown, an array is pickled,
        has the wrong shape or holds NaN, a state is not 0/1/2, or the metadata is not a JSON
        object.
    """
    path = check_input_file(path)
    with path.open("rb") as handle:
        magic = handle.read(4)
    if magic[:2] != b"PK":
        raise DataFormatError(path, "not a readable .npz archive (no zip header)")
    # Forged array headers, pickled arrays, shapes that do not fit one another and archives
    # declaring more than the memory ceiling: refused before numpy inflates anything.
    check_npz(path, shapes=_SHAPES)
    try:
        with np.load(path, allow_pickle=False) as archive:
            keys = set(archive.files)
            missing = [key for key in _REQUIRED if key not in keys]
            if missing:
                hint = (
                    " (a positions clip? simulate it with `fpg-gym simulate`)"
                    if ("fps" in keys)
                    else ""
                )
                raise DataFormatError(
                    path,
                    f"not a recording: missing key(s) {missing}, found {sorted(keys)}{hint}",
                    field=missing[0],
                )
            unknown = sorted(keys - set(RECORDING_KEYS))
            if unknown:
                raise DataFormatError(
                    path, f"unexpected key(s) {unknown}; a recording holds {list(RECORDING_KEYS)}"
                )
            arrays = {key: np.asarray(archive[key]) for key in keys}
    except (zipfile.BadZipFile, OSError, EOFError, zlib.error) as error:
        raise DataFormatError(path, f"not a readable .npz archive ({error})") from None
    except ValueError as error:  # pickled object arrays
        raise DataFormatError(path, f"unreadable array ({error})") from None
    raw_metadata = arrays["metadata"]
    if raw_metadata.shape != () or raw_metadata.dtype.kind not in "US":
        raise DataFormatError(path, "expected a JSON string", field="metadata")
    try:
        metadata = json.loads(str(raw_metadata))
    except json.JSONDecodeError as error:
        raise DataFormatError(path, f"invalid JSON ({error})", field="metadata") from None
    if not isinstance(metadata, dict):
        raise DataFormatError(path, "expected a JSON object", field="metadata")
    for key in ("positions", "states", "timestamps", "ground_truth"):
        if key in arrays and not np.issubdtype(arrays[key].dtype, np.number):
            raise DataFormatError(path, f"expected numbers, got {arrays[key].dtype}", field=key)
    try:
        recording = Recording(
            positions=arrays["positions"],
            states=arrays["states"],
            timestamps=arrays["timestamps"],
            ground_truth=arrays.get("ground_truth"),
            metadata=metadata,
            occluded=arrays.get("occluded"),
        )
    except ValueError as error:
        field_name = str(error).split(":", 1)[0]
        raise DataFormatError(path, str(error), field=field_name) from None
    check_recording(path, recording)
    return recording
