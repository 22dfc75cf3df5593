"""BVH motion capture files (plain or gzip) as Kinect-20 clips.

Any hierarchy is read; forward kinematics applies each joint's own channel order. Where a joint
has position channels they replace its ``OFFSET`` on the axes they name (this is how the Bandai
Namco files, whose every joint has six channels, must be read). Rotations are intrinsic, in
channel order: ``Zrotation Xrotation Yrotation`` is ``R_Z @ R_X @ R_Y``.

A joint map tells, for every Kinect-20 joint, which BVH point to take: a joint name, or a
:class:`BvhPoint` that extends past a joint along a bone (for points the hierarchy lacks, such as
a hand past the wrist). :data:`BANDAI_NAMCO_MAP` is shipped; pass your own ``joint_map`` for
another hierarchy.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.poses import resample
from fpg_gym.core.rotations import euler_to_matrix
from fpg_gym.io._compression import read_input_bytes
from fpg_gym.io.clip import Clip
from fpg_gym.io.files import decode_text
from fpg_gym.io.plausibility import check_plausible

_UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001}
_CHANNEL_NAMES = {
    "Xposition",
    "Yposition",
    "Zposition",
    "Xrotation",
    "Yrotation",
    "Zrotation",
}


@dataclass(frozen=True)
class BvhPoint:
    """A point ``metres`` past ``joint`` along the bone from ``extend_from`` to ``joint``.

    ``BvhPoint("Hand_L", extend_from="LowerArm_L", metres=0.08)`` is 8 cm past the left wrist
    along the forearm. With ``metres=0`` (or no ``extend_from``) it is the joint itself.
    """

    joint: str
    extend_from: str | None = None
    metres: float = 0.0


JointSource = str | BvhPoint

#: Kinect-20 joints from the Bandai Namco Research Motion Dataset hierarchy
#: (see ``../shared/data/README.md``). Head is 7 cm past the Head joint (which sits at the base
#: of the skull) towards the head centre; Hand is 8 cm past the wrist along the forearm.
BANDAI_NAMCO_MAP: Mapping[str, JointSource] = {
    "HipCenter": "Hips",
    "Spine": "Chest",
    "ShoulderCenter": "Neck",
    "Head": BvhPoint("Head", extend_from="Neck", metres=0.07),
    "ShoulderLeft": "UpperArm_L",
    "ElbowLeft": "LowerArm_L",
    "WristLeft": "Hand_L",
    "HandLeft": BvhPoint("Hand_L", extend_from="LowerArm_L", metres=0.08),
    "ShoulderRight": "UpperArm_R",
    "ElbowRight": "LowerArm_R",
    "WristRight": "Hand_R",
    "HandRight": BvhPoint("Hand_R", extend_from="LowerArm_R", metres=0.08),
    "HipLeft": "UpperLeg_L",
    "KneeLeft": "LowerLeg_L",
    "AnkleLeft": "Foot_L",
    "FootLeft": "Toes_L",
    "HipRight": "UpperLeg_R",
    "KneeRight": "LowerLeg_R",
    "AnkleRight": "Foot_R",
    "FootRight": "Toes_R",
}


@dataclass(frozen=True)
class BvhHierarchy:
    """Parsed ``HIERARCHY`` section: joints in file order (parents first).

    Attributes
    ----------
    names : tuple of str
    parents : ndarray of int, (J,), -1 for the root
    offsets : ndarray, (J, 3), file units
    channels : tuple of tuple of str, the channel names of each joint in file order
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]

    @property
    def num_channels(self) -> int:
        """Total number of channels per frame."""
        return sum(len(c) for c in self.channels)


@dataclass(frozen=True)
class BvhMotion:
    """A parsed BVH file: hierarchy, frame time and the channel values ``(F, C)``."""

    hierarchy: BvhHierarchy
    frame_time: float
    values: np.ndarray


def _read_text(path: Path) -> str:
    """The file's text: gzip inflated (within the memory ceiling), a UTF-8 byte-order mark
    dropped, Latin-1 where it is not UTF-8."""
    return decode_text(read_input_bytes(path), path, latin1=True)


def _offset(path: Path, tokens: list[str], number: int) -> list[float]:
    """An OFFSET line's three finite, plausible numbers."""
    try:
        values = [float(v) for v in tokens[1:4]]
    except ValueError:
        raise DataFormatError(path, "OFFSET needs three numbers", line=number) from None
    if len(values) != 3 or not np.all(np.isfinite(values)):
        raise DataFormatError(path, "OFFSET needs three finite numbers", line=number)
    if max(abs(v) for v in values) > MAX_CHANNEL_VALUE:
        raise DataFormatError(
            path,
            f"OFFSET beyond the plausible range ±{MAX_CHANNEL_VALUE:g} file units",
            line=number,
        )
    return values


def _channels(path: Path, tokens: list[str], number: int) -> tuple[str, ...]:
    """A CHANNELS line's channel names (as many as its count says, each a known channel)."""
    try:
        count = int(tokens[1])
    except (IndexError, ValueError):
        raise DataFormatError(path, "CHANNELS needs a count", line=number) from None
    names_here = tuple(tokens[2:])
    if len(names_here) != count or not set(names_here) <= _CHANNEL_NAMES:
        raise DataFormatError(
            path,
            f"CHANNELS {count} must be followed by {count} of "
            f"{sorted(_CHANNEL_NAMES)}, got {list(names_here)}",
            line=number,
        )
    return names_here


def _parse_hierarchy(path: Path, lines: list[str]) -> tuple[BvhHierarchy, int]:
    """Parse up to the MOTION line; return the hierarchy and the index of the MOTION line."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    stack: list[int] = []
    pending: int | None = None  # joint opened but its "{" not yet seen
    in_end_site = 0
    if not lines or lines[0].strip() != "HIERARCHY":
        raise DataFormatError(path, "expected 'HIERARCHY' as the first line", line=1)
    for index in range(1, len(lines)):
        tokens = lines[index].split()
        if not tokens:
            continue
        number = index + 1
        keyword = tokens[0]
        if keyword == "MOTION":
            if stack or in_end_site:
                raise DataFormatError(path, "MOTION before the hierarchy was closed", line=number)
            if not names:
                raise DataFormatError(path, "the hierarchy has no joints", line=number)
            return (
                BvhHierarchy(
                    tuple(names),
                    np.array(parents, dtype=np.intp),
                    np.array(offsets, dtype=np.float64),
                    tuple(channels),
                ),
                index,
            )
        if keyword in ("ROOT", "JOINT"):
            if len(tokens) < 2:
                raise DataFormatError(path, f"{keyword} without a name", line=number)
            if keyword == "ROOT" and stack:
                raise DataFormatError(path, "ROOT inside another joint", line=number)
            if keyword == "JOINT" and not stack:
                raise DataFormatError(path, "JOINT outside any ROOT", line=number)
            name = " ".join(tokens[1:])
            if name in names:
                raise DataFormatError(
                    path,
                    f"duplicate joint name {name!r} (first at joint {names.index(name) + 1}); "
                    "every joint needs its own name",
                    line=number,
                )
            names.append(name)
            parents.append(stack[-1] if stack else -1)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            pending = len(names) - 1
        elif keyword == "End":
            in_end_site += 1
            pending = -1
        elif keyword == "{":
            if pending is None:
                raise DataFormatError(path, "'{' without a joint", line=number)
            if pending >= 0:
                stack.append(pending)
            pending = None
        elif keyword == "}":
            if in_end_site:
                in_end_site -= 1
            elif stack:
                stack.pop()
            else:
                raise DataFormatError(path, "unbalanced '}'", line=number)
        elif keyword in ("OFFSET", "CHANNELS") and not names:
            raise DataFormatError(path, f"{keyword} before any ROOT or JOINT", line=number)
        elif keyword == "OFFSET":
            values = _offset(path, tokens, number)
            if not in_end_site:
                offsets[-1] = values
        elif keyword == "CHANNELS":
            channels[-1] = _channels(path, tokens, number)
        else:
            raise DataFormatError(path, f"unexpected {keyword!r} in the hierarchy", line=number)
    raise DataFormatError(path, "no MOTION section (truncated file?)", line=len(lines))


#: Plausible frame times (seconds): 10 kHz to 1 Hz.
MIN_FRAME_TIME, MAX_FRAME_TIME = 1.0e-4, 1.0
#: Longest clip (seconds) read; a longer one is a corrupt header.
MAX_DURATION_S = 24 * 3600.0
#: Largest magnitude accepted for a channel value (file units or degrees): 10 km in centimetres,
#: or a rotation of thousands of turns. Beyond it a value is a corrupt file, not a motion.
MAX_CHANNEL_VALUE = 1.0e6


def _parse_frames(
    path: Path, lines: list[str], first_line: int, frames: int, hierarchy: BvhHierarchy
) -> np.ndarray:
    """The ``(frames, channels)`` values of the motion lines, checked line by line: each
    non-blank line holds exactly one frame of finite numbers of plausible magnitude
    (:data:`MAX_CHANNEL_VALUE`), and there are exactly ``frames`` of them."""
    channel_count = hierarchy.num_channels
    numbered = [(n, line) for n, line in enumerate(lines, start=first_line) if line.strip()]
    if len(numbered) < frames:
        raise DataFormatError(
            path,
            f"truncated: header says {frames} frames of {channel_count} channels, found "
            f"{len(numbered)} frame lines",
            line=first_line + len(lines),
        )
    if len(numbered) > frames:
        raise DataFormatError(
            path,
            f"{len(numbered) - frames} frame line(s) more than the {frames} the header declares",
            line=numbered[frames][0],
        )
    rows = [line.split() for _, line in numbered]
    for (number, _), fields in zip(numbered, rows, strict=True):
        if len(fields) != channel_count:
            raise DataFormatError(
                path,
                f"expected {channel_count} values per frame line (the hierarchy's channels), "
                f"got {len(fields)}",
                line=number,
            )
    with np.errstate(all="ignore"):
        try:
            values = np.array(rows, dtype=np.float64).reshape(frames, channel_count)
        except ValueError:
            for (number, _), fields in zip(numbered, rows, strict=True):
                for field_text in fields:
                    try:
                        float(field_text)
                    except ValueError:
                        raise DataFormatError(
                            path, f"a frame holds a non-number ({field_text!r})", line=number
                        ) from None
            raise  # pragma: no cover - one of the fields must have failed
    finite = np.isfinite(values)
    if not finite.all():
        frame = int(np.argwhere(~finite)[0, 0])
        raise DataFormatError(path, "NaN or inf value", line=numbered[frame][0])
    large = np.abs(values) > MAX_CHANNEL_VALUE
    if large.any():
        frame, column = (int(i) for i in np.argwhere(large)[0])
        raise DataFormatError(
            path,
            f"value {values[frame, column]:g} is beyond the plausible range "
            f"±{MAX_CHANNEL_VALUE:g} (file units or degrees)",
            line=numbered[frame][0],
        )
    return values


_HEADER_NUMBER = re.compile(r"^\s*(Frames|Frame Time)\s*:\s*(\S+)\s*$")


def parse_bvh(path: str | Path) -> BvhMotion:
    """Parse a BVH file (plain text or gzip) without interpreting it.

    Raises
    ------
    DataFormatError
        For a malformed hierarchy (duplicate joint names included), a bad header, a truncated
        motion section, a frame line without exactly one value per channel, NaN/inf values or
        values beyond :data:`MAX_CHANNEL_VALUE`; the message names the file and line.
    """
    path = Path(path)
    text = _read_text(path)
    head, separator, _ = text.partition("\nMOTION")
    head_lines = head.splitlines()
    lines = [*head_lines, "MOTION"] if separator else head_lines
    hierarchy, motion_index = _parse_hierarchy(path, lines)
    # remaining[0] is what follows MOTION on its line, then the "Frames:" and "Frame Time:" lines.
    header: dict[str, str] = {}
    remaining = text[len(head) + len(separator) :].splitlines()
    consumed = 1
    for offset_line, line in enumerate(remaining[1:3], start=1):
        match = _HEADER_NUMBER.match(line)
        if not match:
            raise DataFormatError(
                path,
                f"expected 'Frames: N' and 'Frame Time: S' after MOTION, got {line.strip()!r}",
                line=motion_index + 1 + offset_line,
            )
        header[match.group(1)] = match.group(2)
        consumed += 1
    if len(header) != 2:
        raise DataFormatError(
            path, "missing 'Frames:' / 'Frame Time:' header", line=motion_index + 1 + consumed
        )
    try:
        frames = int(header["Frames"])
        frame_time = float(header["Frame Time"])
    except ValueError:
        raise DataFormatError(
            path, "'Frames' must be an integer and 'Frame Time' a number", line=motion_index + 2
        ) from None
    if frames <= 0:
        raise DataFormatError(path, "the clip has no frames (Frames: 0)", line=motion_index + 2)
    if not (np.isfinite(frame_time) and MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME):
        raise DataFormatError(
            path,
            f"frame time {frame_time:g} s is outside the plausible {MIN_FRAME_TIME:g}-"
            f"{MAX_FRAME_TIME:g} s",
            line=motion_index + 3,
        )
    if frames * frame_time > MAX_DURATION_S:
        raise DataFormatError(
            path,
            f"{frames} frames of {frame_time:g} s last {frames * frame_time / 3600:.1f} h, more "
            f"than the {MAX_DURATION_S / 3600:g} h a clip may last",
            line=motion_index + 2,
        )
    first_data_line = motion_index + consumed + 1  # 1-based number of the first frame line
    values = _parse_frames(path, remaining[consumed:], first_data_line, frames, hierarchy)
    return BvhMotion(hierarchy, frame_time, values)


def detect_scale(hierarchy: BvhHierarchy) -> float:
    """Metres per file unit, guessed from the bone offsets (a human bone is 5-50 cm):
    millimetres when the median non-zero offset exceeds 80 units, centimetres when it exceeds
    2 units, metres otherwise."""
    lengths = np.linalg.norm(hierarchy.offsets, axis=1)
    lengths = lengths[lengths > 0]
    if len(lengths) == 0:
        return 1.0
    median = float(np.median(lengths))
    return 0.001 if median > 80.0 else 0.01 if median > 2.0 else 1.0


def joint_positions(motion: BvhMotion) -> np.ndarray:
    """World positions of every BVH joint, ``(F, J, 3)`` in file units."""
    hierarchy = motion.hierarchy
    frames = len(motion.values)
    count = len(hierarchy.names)
    translations = np.broadcast_to(hierarchy.offsets, (frames, count, 3)).copy()
    rotations = np.broadcast_to(np.eye(3), (frames, count, 3, 3)).copy()
    column = 0
    by_order: dict[str, list[tuple[int, list[int]]]] = {}
    for joint, joint_channels in enumerate(hierarchy.channels):
        order = ""
        rotation_columns: list[int] = []
        for name in joint_channels:
            axis = "XYZ".index(name[0])
            if name.endswith("position"):
                translations[:, joint, axis] = motion.values[:, column]
            else:
                order += name[0]
                rotation_columns.append(column)
            column += 1
        if order:
            by_order.setdefault(order, []).append((joint, rotation_columns))
    for order, entries in by_order.items():  # one batched Euler conversion per channel order
        joints = [joint for joint, _ in entries]
        angles = motion.values[:, [cols for _, cols in entries]]  # (F, n, len(order))
        rotations[:, joints] = euler_to_matrix(angles, order)
    world_rotation = np.empty_like(rotations)
    world_position = np.empty_like(translations)
    for joint, parent in enumerate(hierarchy.parents):  # tree walk, vectorised over frames
        if parent < 0:
            world_rotation[:, joint] = rotations[:, joint]
            world_position[:, joint] = translations[:, joint]
        else:
            world_rotation[:, joint] = world_rotation[:, parent] @ rotations[:, joint]
            world_position[:, joint] = world_position[:, parent] + np.einsum(
                "fij,fj->fi", world_rotation[:, parent], translations[:, joint]
            )
    return world_position


def _resolve(
    path: Path, hierarchy: BvhHierarchy, joint_map: Mapping[str, JointSource]
) -> list[BvhPoint]:
    missing = [name for name in skeleton.JOINT_NAMES if name not in joint_map]
    extra = [name for name in joint_map if name not in skeleton.JOINT_NAMES]
    if missing or extra:
        raise DataFormatError(
            path,
            "the joint map must name every Kinect-20 joint exactly once"
            + (f"; missing {missing}" if missing else "")
            + (f"; not Kinect-20 joints: {extra}" if extra else ""),
        )
    points = []
    for name in skeleton.JOINT_NAMES:
        source = joint_map[name]
        point = BvhPoint(source) if isinstance(source, str) else source
        for joint in (point.joint, point.extend_from):
            if joint is not None and joint not in hierarchy.names:
                raise DataFormatError(
                    path,
                    f"joint map entry {name!r} names BVH joint {joint!r}, which this file does "
                    f"not have (its joints: {', '.join(hierarchy.names)})",
                )
        points.append(point)
    return points


def read_bvh(
    path: str | Path,
    joint_map: Mapping[str, JointSource] = BANDAI_NAMCO_MAP,
    *,
    units: str = "auto",
    fps: float | None = 30.0,
) -> Clip:
    """Read a BVH file (``.bvh`` or gzip ``.bvh.gz``) as a Kinect-20 clip in metres, Y up.

    Parameters
    ----------
    path : str or Path
    joint_map : mapping
        Kinect-20 joint name -> BVH joint name or :class:`BvhPoint`;
        :data:`BANDAI_NAMCO_MAP` by default.
    units : {"auto", "m", "cm", "mm"}
        Length unit of the file; ``"auto"`` uses :func:`detect_scale`.
    fps : float or None
        Resample to this rate (30 Hz by default); ``None`` keeps the file's rate.

    Raises
    ------
    DataFormatError
        For malformed or truncated files, NaN/inf values, or a joint map naming joints the file
        lacks.
    """
    path = Path(path)
    if units != "auto" and units not in _UNIT_SCALE:
        raise ValueError(f"units: expected 'auto', 'm', 'cm' or 'mm', got {units!r}")
    motion = parse_bvh(path)
    points = _resolve(path, motion.hierarchy, joint_map)
    scale = detect_scale(motion.hierarchy) if units == "auto" else _UNIT_SCALE[units]
    world = joint_positions(motion) * scale
    index = {name: i for i, name in enumerate(motion.hierarchy.names)}
    positions = world[:, [index[p.joint] for p in points]]
    extend = [(j, p) for j, p in enumerate(points) if p.extend_from is not None and p.metres]
    if extend:
        joints = [j for j, _ in extend]
        base = world[:, [index[p.joint] for _, p in extend]]
        start = world[:, [index[p.extend_from] for _, p in extend if p.extend_from is not None]]
        direction = base - start
        direction /= np.maximum(np.linalg.norm(direction, axis=-1, keepdims=True), 1e-12)
        positions[:, joints] = base + direction * np.array([p.metres for _, p in extend])[:, None]
    source_fps = 1.0 / motion.frame_time
    check_plausible(path, positions, fps=source_fps, field=None)
    if fps is not None:
        positions = resample(positions, source_fps, fps)
    name = path.name.removesuffix(".gz").removesuffix(".bvh")
    return Clip(
        name=name,
        positions=positions.astype(np.float32),
        fps=float(fps if fps is not None else source_fps),
        source=str(path),
        metadata={"format": "bvh", "scale": scale, "source_fps": source_fps},
    )
