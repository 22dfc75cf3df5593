"""Readers of real Kinect skeleton streams -> :class:`~fpg_gym.io.recording.Recording`.

Formats (:data:`KINECT_FORMATS`), detected from the extension and the first data line unless
``format=`` says otherwise:

``msrc12``
    MSRC-12 / Kinect SDK v1 text: one frame per line, whitespace separated, a timestamp then
    20 x (x y z w) in SDK v1 joint order. ``w`` is the homogeneous coordinate (1), not a
    tracking state: every reported joint is marked tracked. The timestamp unit is not stated by
    the export; it is taken as the unit (ms, µs or 100 ns) that makes the median frame step
    closest to 1/30 s and recorded in ``metadata["timestamp_unit_s"]``.
``kinect_v2``
    Kinect SDK 2.0 text: one frame per line, comma separated, optional trailing comma: a
    timestamp in 100 ns ticks then 25 x (x, y, z, state) in ``JointType`` order. The layout
    ``index, time_ms, 25 x (state, x, y, z, qw, qx, qy, qz)`` (202 fields) is accepted too,
    chosen per file by the field count of most lines.
``ntu``
    NTU RGB+D ``.skeleton``: a frame-count line; per frame a body-count line; per body a line of
    10 values (bodyID, clippedEdges, handLeftConfidence, handLeftState, handRightConfidence,
    handRightState, isRestricted, leanX, leanY, trackingState), a joint-count line (25) and 25
    lines of 12 values (x y z depthX depthY colorX colorY orientationW X Y Z trackingState).
    ``body=k`` picks the k-th distinct bodyID in order of first appearance; 30 Hz is assumed.
``csv``
    The documented CSV (:func:`write_csv` writes it): optional ``#`` comment lines, a header
    ``timestamp,HipCenter_x,HipCenter_y,HipCenter_z,HipCenter_state,...`` naming every
    Kinect-20 joint (:data:`fpg_gym.core.skeleton.JOINT_NAMES`) in any column order, then one row
    per frame: seconds, metres in camera space, state 2/1/0. ``timestamp`` is optional (30 Hz then).
``npz``
    A recording file written by :func:`~fpg_gym.io.recording.write_recording`.
``azure_kinect``, ``mapped``
    Azure Kinect Body Tracking JSON (detected from a ``.json`` file's content) and any per-joint
    CSV/JSON through a user-given joint map (``joint_map=``): :mod:`fpg_gym.io.trackers`.

Kinect v2 joints map to the Kinect-20 set with :data:`fpg_gym.core.skeleton.FROM_KINECT_V2`
(SpineBase -> HipCenter, SpineMid -> Spine, SpineShoulder -> ShoulderCenter; hand tips, thumbs
and Neck are dropped).

No data is lost silently: lines that do not fit the layout (wrong field count, a value that is
not a number or not finite, a state outside 0/1/2, a timestamp going back) are skipped, counted
by reason in ``metadata["skipped_lines"]`` and announced by one :class:`SkippedLinesWarning` per
file. A file with no usable line, or where most lines are unusable, raises
:class:`~fpg_gym.core.errors.DataFormatError` naming the first bad line. Frames without a body (all
coordinates zero, or the picked NTU body absent) are kept with every joint not tracked and
counted in ``metadata["no_body_frames"]``; a joint reported at exactly (0, 0, 0) is not tracked
too. Such joints take their last known position (``metadata["untracked_positions"] ==
"last_known"``; before the first sighting, the first known position), other not-tracked joints
keep what the sensor reported.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import atomic_path
from fpg_gym.io.files import check_input_file
from fpg_gym.io.lines import (
    DEFAULT_FPS,
    LineLog,
    SkippedLinesWarning,
    coordinate_columns,
    finish_recording,
    implausible,
    numeric_lines,
    parse_numbers,
    read_text,
    timestamp_unit,
)
from fpg_gym.io.plausibility import MAX_COORDINATE_M
from fpg_gym.io.recording import TRACKED, Recording, load_recording
from fpg_gym.io.trackers import JointMap, is_azure_kinect_json, read_azure_kinect, read_mapped

__all__ = [
    "KINECT_FORMATS",
    "SkippedLinesWarning",
    "detect_format",
    "read_csv",
    "read_kinect_v2",
    "read_msrc12",
    "read_ntu",
    "read_recording",
    "write_csv",
]

#: Formats :func:`read_recording` understands.
KINECT_FORMATS: tuple[str, ...] = (
    "msrc12",
    "kinect_v2",
    "ntu",
    "csv",
    "npz",
    "azure_kinect",
    "mapped",
)

_V1_FIELDS = 1 + skeleton.NUM_JOINTS * 4  # 81
_V2_JOINTS = len(skeleton.KINECT_V2_JOINT_NAMES)
_V2_FIELDS = 1 + _V2_JOINTS * 4  # 101
_V2_ALT_FIELDS = 2 + _V2_JOINTS * 8  # 202: index, time ms, 25 x (state x y z qw qx qy qz)
_NTU_BODY_FIELDS = 10
_NTU_JOINT_FIELDS = 12
_STATE_COLUMNS = ("x", "y", "z", "state")
#: Data lines :func:`detect_format` looks at.
_DETECT_LINES = 64


# --------------------------------------------------------------------------- MSRC-12 / SDK v1


def read_msrc12(path: str | Path) -> Recording:
    """Read an MSRC-12 / Kinect SDK v1 skeleton text file (see the module docstring).

    Raises
    ------
    DataFormatError
        If no line (or under half of the lines) has 81 finite numbers.
    """
    path = Path(path)
    lines = read_text(path)
    log = LineLog()
    rows: list[np.ndarray] = []
    last_tick = -math.inf
    numbered = ((n, text.split()) for n, text in enumerate(lines, start=1) if text.split())
    coordinates = coordinate_columns(1, skeleton.NUM_JOINTS, 4, 0)
    for number, values in numeric_lines(numbered, _V1_FIELDS, log, coordinates=coordinates):
        if values[0] < last_tick:
            log.skip(number, "timestamp goes back")
            continue
        last_tick = values[0]
        rows.append(values)
    log.check(path, len(rows), "msrc12")
    data = np.stack(rows)
    ticks = data[:, 0]
    joints = data[:, 1:].reshape(len(data), skeleton.NUM_JOINTS, 4)[:, skeleton.FROM_KINECT_V1]
    positions = joints[..., :3]
    body = ~np.all(positions == 0.0, axis=(1, 2))
    unit = timestamp_unit(ticks, (1e-3, 1e-6, 1e-7))
    states = np.full(positions.shape[:2], TRACKED, dtype=np.int8)
    metadata: dict[str, Any] = {
        "format": "msrc12",
        "source_joint_set": "kinect_v1",
        "states_in_file": False,
        "states_note": "the export has no tracking state: reported joints are marked tracked",
        "timestamp_unit_s": unit,
        "timestamp_origin_ticks": float(ticks[0]),
        "skipped_lines": log.report(path, len(rows) + log.count),
    }
    return finish_recording(path, positions, states, (ticks - ticks[0]) * unit, body, metadata)


# --------------------------------------------------------------------------- Kinect v2 text


def read_kinect_v2(path: str | Path) -> Recording:
    """Read a Kinect SDK 2.0 skeleton text file (see the module docstring).

    Raises
    ------
    DataFormatError
        If no line (or under half of the lines) fits the layout.
    """
    path = Path(path)
    lines = read_text(path)
    split = [
        (n, [f.strip() for f in t.strip().rstrip(",").split(",")])
        for n, t in enumerate(lines, start=1)
        if t.strip()
    ]
    counts = Counter(len(fields) for _, fields in split)
    layout = _V2_ALT_FIELDS if counts[_V2_ALT_FIELDS] > counts[_V2_FIELDS] else _V2_FIELDS
    log = LineLog()
    rows: list[np.ndarray] = []
    last_tick = -math.inf
    coordinates = (
        coordinate_columns(1, _V2_JOINTS, 4, 0)
        if layout == _V2_FIELDS
        else coordinate_columns(2, _V2_JOINTS, 8, 1)
    )
    for number, values in numeric_lines(split, layout, log, coordinates=coordinates):
        if layout == _V2_FIELDS:
            tick, joints = values[0], values[1:].reshape(_V2_JOINTS, 4)
            state = joints[:, 3]
        else:
            tick, joints = values[1], values[2:].reshape(_V2_JOINTS, 8)
            state = joints[:, 0]
        if not np.all(np.isin(state, skeleton.TRACKING_STATES)):
            log.skip(number, "tracking state not 0, 1 or 2")
            continue
        if tick < last_tick:
            log.skip(number, "timestamp goes back")
            continue
        last_tick = tick
        rows.append(values)
    log.check(path, len(rows), "kinect_v2")
    data = np.stack(rows)
    if layout == _V2_FIELDS:
        ticks = data[:, 0]
        table = data[:, 1:].reshape(len(data), _V2_JOINTS, 4)
        positions, states = table[..., :3], table[..., 3]
        unit = 1e-7  # TimeSpan ticks of 100 ns
    else:
        ticks = data[:, 1]
        table = data[:, 2:].reshape(len(data), _V2_JOINTS, 8)
        positions, states = table[..., 1:4], table[..., 0]
        unit = 1e-3
    positions = positions[:, skeleton.FROM_KINECT_V2]
    states = states[:, skeleton.FROM_KINECT_V2].astype(np.int8)
    body = ~np.all(positions == 0.0, axis=(1, 2))
    metadata: dict[str, Any] = {
        "format": "kinect_v2",
        "layout": "timestamp+25x(x,y,z,state)"
        if layout == _V2_FIELDS
        else "index,time_ms+25x(state,x,y,z,qw,qx,qy,qz)",
        "source_joint_set": "kinect_v2",
        "states_in_file": True,
        "timestamp_unit_s": unit,
        "timestamp_origin_ticks": float(ticks[0]),
        "skipped_lines": log.report(path, len(rows) + log.count),
    }
    return finish_recording(path, positions, states, (ticks - ticks[0]) * unit, body, metadata)


# --------------------------------------------------------------------------- NTU RGB+D


class _NtuLines:
    """The lines of an NTU ``.skeleton`` file read in order (blank lines skipped), with checks
    that name the file and the line."""

    def __init__(self, path: Path, lines: list[str]) -> None:
        self.path = path
        self.lines = lines
        self.position = 0

    def next_fields(self, what: str) -> tuple[int, list[str]]:
        """The next non-blank line's number and fields (``what``: the expected line)."""
        lines = self.lines
        while self.position < len(lines) and not lines[self.position].strip():
            self.position += 1
        if self.position >= len(lines):
            raise DataFormatError(
                self.path, f"file ends early: expected {what}", line=self.position + 1
            )
        self.position += 1
        return self.position, lines[self.position - 1].split()

    def integer(self, fields: list[str], number: int, what: str) -> int:
        """A line holding one integer."""
        if len(fields) != 1:
            raise DataFormatError(
                self.path, f"expected {what} (one integer), got {len(fields)} fields", line=number
            )
        try:
            return int(fields[0])
        except ValueError:
            raise DataFormatError(
                self.path, f"expected {what}, got {fields[0]!r}", line=number
            ) from None

    def remaining(self) -> int:
        """Non-blank lines left."""
        return sum(1 for text in self.lines[self.position :] if text.strip())

    def joints(self) -> np.ndarray:
        """A body's joint-count line and its joint lines: ``(25, 12)`` values."""
        number, count_fields = self.next_fields("the joint count")
        joint_count = self.integer(count_fields, number, "the joint count")
        if joint_count != _V2_JOINTS:
            raise DataFormatError(
                self.path,
                f"expected {_V2_JOINTS} joints (Kinect v2), got {joint_count}",
                line=number,
            )
        joints = np.empty((_V2_JOINTS, _NTU_JOINT_FIELDS))
        for joint in range(_V2_JOINTS):
            number, fields = self.next_fields(f"joint line {joint + 1}")
            values = parse_numbers(fields) if len(fields) == _NTU_JOINT_FIELDS else None
            if values is None or not np.all(np.isfinite(values)):
                raise DataFormatError(
                    self.path,
                    f"expected {_NTU_JOINT_FIELDS} finite numbers (x y z depthX depthY colorX "
                    "colorY orientationW X Y Z trackingState)"
                    + (f", got {len(fields)} fields" if len(fields) != _NTU_JOINT_FIELDS else ""),
                    line=number,
                )
            if implausible(values[:3]):
                raise DataFormatError(
                    self.path,
                    f"a coordinate beyond ±{MAX_COORDINATE_M:g} m ({' '.join(fields[:3])})",
                    line=number,
                )
            if values[-1] not in skeleton.TRACKING_STATES:
                raise DataFormatError(
                    self.path, f"tracking state must be 0, 1 or 2, got {values[-1]:g}", line=number
                )
            joints[joint] = values
        return joints

    def check_end(self, frame_count: int) -> None:
        """Refuse content after the declared frames."""
        while self.position < len(self.lines):
            if self.lines[self.position].strip():
                raise DataFormatError(
                    self.path,
                    f"unexpected content after the {frame_count} declared frames",
                    line=self.position + 1,
                )
            self.position += 1


def read_ntu(path: str | Path, body: int = 0) -> Recording:
    """Read an NTU RGB+D ``.skeleton`` file; ``body`` picks the k-th distinct bodyID.

    Raises
    ------
    DataFormatError
        On a truncated or malformed file (line named), or when the file holds fewer than
        ``body + 1`` bodies.
    """
    path = Path(path)
    if body < 0:
        raise ValueError(f"body: expected a non-negative index, got {body}")
    reader = _NtuLines(path, read_text(path))
    number, fields = reader.next_fields("the frame count")
    frame_count = reader.integer(fields, number, "the frame count")
    if frame_count < 1:
        raise DataFormatError(path, f"frame count must be positive, got {frame_count}", line=number)
    remaining = reader.remaining()
    if frame_count > remaining:
        raise DataFormatError(
            path,
            f"the header declares {frame_count} frames, but only {remaining} lines follow (each "
            "frame needs at least its body-count line): truncated or corrupt file",
            line=number,
        )
    body_order: list[str] = []
    positions = np.zeros((frame_count, _V2_JOINTS, 3))
    states = np.zeros((frame_count, _V2_JOINTS), dtype=np.int8)
    present = np.zeros(frame_count, dtype=bool)
    frames_by_body: dict[str, list[tuple[int, np.ndarray]]] = {}
    for frame in range(frame_count):
        number, fields = reader.next_fields(f"the body count of frame {frame + 1}")
        body_count = reader.integer(fields, number, "the body count")
        if body_count < 0:
            raise DataFormatError(path, f"negative body count {body_count}", line=number)
        for _ in range(body_count):
            number, fields = reader.next_fields("a body line")
            if len(fields) != _NTU_BODY_FIELDS:
                raise DataFormatError(
                    path,
                    f"expected a body line of {_NTU_BODY_FIELDS} values, got {len(fields)}",
                    line=number,
                )
            body_id = fields[0]
            if body_id not in frames_by_body:
                frames_by_body[body_id] = []
                body_order.append(body_id)
            frames_by_body[body_id].append((frame, reader.joints()))
    reader.check_end(frame_count)
    if body >= len(body_order):
        raise DataFormatError(
            path,
            f"body {body} requested, but the file holds {len(body_order)} distinct "
            f"bod{'y' if len(body_order) == 1 else 'ies'}",
        )
    chosen = body_order[body]
    for frame, joints in frames_by_body[chosen]:
        positions[frame] = joints[:, :3]
        states[frame] = joints[:, 11].astype(np.int8)
        present[frame] = True
    metadata: dict[str, Any] = {
        "format": "ntu",
        "source_joint_set": "kinect_v2",
        "states_in_file": True,
        "body": body,
        "body_id": chosen,
        "bodies_in_file": len(body_order),
        "timestamps_note": "the format has no timestamps: 30 Hz assumed",
        "skipped_lines": {"count": 0, "reasons": {}, "first_lines": []},
    }
    positions = positions[:, skeleton.FROM_KINECT_V2]
    states = states[:, skeleton.FROM_KINECT_V2]
    timestamps = np.arange(frame_count) / DEFAULT_FPS
    return finish_recording(path, positions, states, timestamps, present, metadata)


# --------------------------------------------------------------------------- documented CSV


def _csv_columns() -> list[str]:
    return [f"{name}_{axis}" for name in skeleton.JOINT_NAMES for axis in _STATE_COLUMNS]


def write_csv(path: str | Path, recording: Recording) -> Path:
    """Write a recording in the documented CSV layout (ground truth and metadata are dropped)."""
    path = Path(path)
    count = recording.num_frames
    table = np.concatenate(
        [
            recording.positions.astype(np.float64),
            recording.states.astype(np.float64)[..., None],
        ],
        axis=-1,
    ).reshape(count, -1)
    with atomic_path(path) as temporary, temporary.open("w", encoding="utf-8") as handle:
        handle.write(
            "# fpg-gym Kinect-20 recording: seconds; metres in camera space (Y up, Z away "
            "from the sensor); state 2 tracked, 1 inferred, 0 not tracked\n"
        )
        handle.write(",".join(["timestamp", *_csv_columns()]) + "\n")
        for stamp, row in zip(recording.timestamps, table, strict=True):
            cells = [f"{stamp:.6f}"]
            for index, value in enumerate(row):
                cells.append(f"{int(value)}" if index % 4 == 3 else f"{value:.6g}")
            handle.write(",".join(cells) + "\n")
    return path


def read_csv(path: str | Path) -> Recording:
    """Read the documented CSV layout (see the module docstring and :func:`write_csv`).

    Raises
    ------
    DataFormatError
        If the header lacks a joint column, or no (or under half of the) rows are usable.
    """
    path = Path(path)
    lines = read_text(path)
    body_lines = [
        (n, t) for n, t in enumerate(lines, start=1) if t.strip() and not t.lstrip().startswith("#")
    ]
    if not body_lines:
        raise DataFormatError(path, "no header line (empty CSV file)")
    header_line, header_text = body_lines[0]
    header = [h.strip() for h in header_text.strip().rstrip(",").split(",")]
    index = {name: i for i, name in enumerate(header)}
    missing = [c for c in _csv_columns() if c not in index]
    if missing:
        raise DataFormatError(
            path,
            f"header lacks {len(missing)} joint column(s), e.g. {missing[:4]}; expected "
            "'timestamp' and '<Joint>_x,<Joint>_y,<Joint>_z,<Joint>_state' for every Kinect-20 "
            "joint",
            line=header_line,
        )
    columns = np.array([index[c] for c in _csv_columns()])
    has_time = "timestamp" in index
    known = set(_csv_columns()) | {"timestamp"}
    ignored = [h for h in header if h not in known]
    log = LineLog()
    rows: list[np.ndarray] = []
    stamps: list[float] = []
    numbered = (
        (n, [f.strip() for f in text.strip().rstrip(",").split(",")]) for n, text in body_lines[1:]
    )
    for number, values in numeric_lines(numbered, len(header), log, finite=False):
        if not np.all(np.isfinite(values[columns])) or (
            has_time and not math.isfinite(values[index["timestamp"]])
        ):
            log.skip(number, "NaN or inf value")
            continue
        joints = values[columns].reshape(skeleton.NUM_JOINTS, 4)
        if implausible(joints[:, :3]):
            log.skip(number, f"a coordinate beyond ±{MAX_COORDINATE_M:g} m")
            continue
        if not np.all(np.isin(joints[:, 3], skeleton.TRACKING_STATES)):
            log.skip(number, "tracking state not 0, 1 or 2")
            continue
        stamp = values[index["timestamp"]] if has_time else len(rows) / DEFAULT_FPS
        if stamps and stamp < stamps[-1]:
            log.skip(number, "timestamp goes back")
            continue
        rows.append(joints)
        stamps.append(float(stamp))
    log.check(path, len(rows), "csv")
    data = np.stack(rows)
    positions, states = data[..., :3], data[..., 3].astype(np.int8)
    body = ~np.all(positions == 0.0, axis=(1, 2))
    metadata: dict[str, Any] = {
        "format": "csv",
        "source_joint_set": "kinect20",
        "states_in_file": True,
        "skipped_lines": log.report(path, len(rows) + log.count),
    }
    if ignored:
        metadata["ignored_columns"] = ignored
    if not has_time:
        metadata["timestamps_note"] = "no timestamp column: 30 Hz assumed"
    return finish_recording(path, positions, states, np.asarray(stamps), body, metadata)


# --------------------------------------------------------------------------- detection


def _numeric_token(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _line_layout(text: str) -> str | None:
    """The layout one data line fits (None when it fits none)."""
    comma = text.rstrip(",").split(",")
    if len(comma) in (_V2_FIELDS, _V2_ALT_FIELDS):
        return "kinect_v2"
    fields = text.split()
    if len(fields) == _V1_FIELDS:
        return "msrc12"
    if len(comma) == 1 and len(fields) in (1, _NTU_BODY_FIELDS, _NTU_JOINT_FIELDS):
        return "ntu"
    return None


def detect_format(path: str | Path) -> str:
    """Guess a Kinect file's format from its extension and data lines.

    A header line of names (its fields mostly not numbers) means ``csv``; otherwise the first
    :data:`_DETECT_LINES` data lines vote by their field counts, so a cut or NaN first line
    does not decide alone. Pass ``format=`` (``--format``) to skip the guess.

    Raises
    ------
    DataFormatError
        If the content matches no known layout.
    """
    path = Path(path)
    name = path.name.lower()
    if name.endswith(".npz"):
        return "npz"
    if name.endswith((".skeleton", ".skeleton.gz")):
        return "ntu"
    if name.endswith((".json", ".json.gz")) and is_azure_kinect_json(path):
        return "azure_kinect"
    lines = read_text(path)
    sample = [t.strip() for t in lines if t.strip() and not t.lstrip().startswith("#")][
        :_DETECT_LINES
    ]
    if not sample:
        raise DataFormatError(path, "empty file: cannot detect its format")
    tokens = [t for t in sample[0].replace(",", " ").split() if t]
    if sum(not _numeric_token(t) for t in tokens) * 2 > len(tokens):
        return "csv"
    votes = Counter(layout for layout in map(_line_layout, sample) if layout is not None)
    if votes:
        return votes.most_common(1)[0][0]
    first = sample[0]
    raise DataFormatError(
        path,
        f"unknown Kinect layout ({len(first.rstrip(',').split(','))} comma-separated or "
        f"{len(first.split())} space-separated fields on the first data line, and no line of "
        f"the first {len(sample)} fits a layout); expected msrc12 ({_V1_FIELDS} "
        f"space-separated), kinect_v2 ({_V2_FIELDS} or {_V2_ALT_FIELDS} comma-separated), ntu "
        "(.skeleton) or csv (a header of joint names); pass format= (--format)",
        line=1,
    )


def read_recording(
    path: str | Path,
    format: str | None = None,
    body: int = 0,
    joint_map: JointMap | Sequence[str] | None = None,
) -> Recording:
    """Read a Kinect recording in any supported format.

    Parameters
    ----------
    path : str or Path
    format : {"msrc12", "kinect_v2", "ntu", "csv", "npz", "azure_kinect", "mapped"}, optional
        Overrides detection (:func:`detect_format`); a ``joint_map`` implies ``"mapped"``.
    body : int
        Which body of an NTU or Azure Kinect file (k-th distinct body id); other formats hold
        one body.
    joint_map : JointMap or sequence of str, optional
        How a generic per-joint file's joints map to Kinect-20
        (:class:`fpg_gym.io.trackers.JointMap`, or ``"source=KinectName"`` strings).

    Returns
    -------
    Recording

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    DataFormatError
        If the content does not fit the format (file and line named).
    ValueError
        If ``format`` is unknown.
    """
    path = check_input_file(path)  # a folder, a link loop, an unreadable file: named as such
    kind = format or ("mapped" if joint_map is not None else detect_format(path))
    if kind not in KINECT_FORMATS:
        raise ValueError(f"format: expected one of {', '.join(KINECT_FORMATS)}, got {format!r}")
    if kind not in ("ntu", "azure_kinect") and body != 0:
        raise ValueError(
            f"body: only NTU files (and Azure Kinect ones) hold several bodies; got body={body} "
            f"for {kind}"
        )
    if (kind == "mapped") != (joint_map is not None):
        raise ValueError("joint_map: needed by format 'mapped', and only by it")
    if kind == "mapped":
        assert joint_map is not None
        return read_mapped(path, joint_map)
    if kind == "azure_kinect":
        return read_azure_kinect(path, body=body)
    if kind == "msrc12":
        return read_msrc12(path)
    if kind == "kinect_v2":
        return read_kinect_v2(path)
    if kind == "ntu":
        return read_ntu(path, body=body)
    if kind == "csv":
        return read_csv(path)
    return load_recording(path)
