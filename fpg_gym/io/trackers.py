"""Today's body trackers -> Kinect-20 :class:`~fpg_gym.io.recording.Recording`.

``azure_kinect``
    The JSON written by the offline processor of Microsoft's Azure Kinect body-tracking samples
    (``Azure-Kinect-Samples/body-tracking-samples/offline_processor``): ``joint_names`` (the 32
    names it writes, ``PELVIS``, ``SPINE_NAVEL``, ..., ``EAR_RIGHT``; ``K4ABT_JOINT_PELVIS`` and
    so on are read too), ``frames`` -> ``timestamp_usec``, ``bodies`` -> ``body_id``,
    ``joint_positions`` (32 x [x, y, z] in millimetres, depth camera space: X right, Y down, Z
    forward) and ``joint_orientations`` (ignored). Positions become metres in the Kinect camera
    space (Y up, Z forward, X to the sensor's left): ``(x, y, z) -> (-x, -y, z) / 1000``, a
    rotation by 180° about Z. A body's per-joint confidence (``k4abt_joint_confidence_level_t``),
    where a file carries it as ``joint_confidences`` / ``confidence_levels`` (numbers 0–3 or names
    ``NONE``/``LOW``/``MEDIUM``/``HIGH``), becomes the tracking state: NONE (out of range) -> not
    tracked, LOW (predicted, not observed) -> inferred, MEDIUM and HIGH -> tracked; without it
    every joint is tracked. ``body=k`` picks the k-th distinct ``body_id`` in order of first
    appearance; frames without it are kept with every joint not tracked.
``mapped``
    Any per-joint CSV or JSON with a user-given joint map (:class:`JointMap`). CSV: optional
    ``#`` lines, a header ``timestamp,<name>_x,<name>_y,<name>_z[,<name>_state],...``, one row
    per frame. JSON: a list of frames (or ``{"frames": [...]}``), each
    ``{"timestamp": s, "joints": {name: [x, y, z]}, "states": {name: 0|1|2}}``. The map names, for
    each Kinect-20 joint, one source joint or several (their mean, e.g. a pelvis from two hips);
    ``units`` and ``axes`` turn the source's coordinates into metres in Kinect camera space
    (:meth:`JointMap.load` reads them from JSON or from ``name=KinectName`` lines).

Joint maps to Kinect-20 (:data:`fpg_gym.core.skeleton.AZURE_KINECT_TO_KINECT20`; docs/input.md has
the table): PELVIS -> HipCenter, SPINE_NAVEL -> Spine, NECK -> ShoulderCenter, HEAD -> Head, and
the limbs by name (SHOULDER/ELBOW/WRIST/HAND, HIP/KNEE/ANKLE/FOOT, each side); SPINE_CHEST, the
clavicles, hand tips, thumbs, nose, eyes and ears are dropped. Like every joint-set map this moves
body points by a few centimetres (Azure's NECK sits higher than a Kinect v1 ShoulderCenter): fit a
definition map (``fpg-gym fit-map``) where it matters.

Bad frames (a missing field, a wrong shape, a non-finite or implausible value, a timestamp going
back) are skipped and counted in ``metadata["skipped_lines"]`` (the "line" is the frame's
1-based position in the file); a file with no usable frame, or mostly unusable ones, raises
:class:`~fpg_gym.core.errors.DataFormatError`.
"""

from __future__ import annotations

import json
import math
import warnings
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.validation import check_choice, check_integer
from fpg_gym.io._compression import read_input_bytes
from fpg_gym.io.files import decode_text
from fpg_gym.io.lines import DEFAULT_FPS, MAX_BAD_SHARE
from fpg_gym.io.plausibility import MAX_COORDINATE_M, check_recording
from fpg_gym.io.recording import INFERRED, NOT_TRACKED, TRACKED, Recording

__all__ = [
    "JointMap",
    "is_azure_kinect_json",
    "read_azure_kinect",
    "read_mapped",
]

#: ``k4abt_joint_confidence_level_t`` -> tracking state.
CONFIDENCE_STATES: dict[str, int] = {
    "NONE": NOT_TRACKED,
    "LOW": INFERRED,
    "MEDIUM": TRACKED,
    "HIGH": TRACKED,
}
_CONFIDENCE_BY_VALUE = (NOT_TRACKED, INFERRED, TRACKED, TRACKED)
_CONFIDENCE_KEYS = ("joint_confidences", "confidence_levels", "joint_confidence")
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}


class _FrameLog:
    """Skipped frames by reason, the first few positions (1-based), one warning."""

    def __init__(self) -> None:
        self.reasons: Counter[str] = Counter()
        self.first: list[int] = []

    def skip(self, number: int, reason: str) -> None:
        self.reasons[reason] += 1
        if len(self.first) < 10:
            self.first.append(number)

    def finish(self, path: Path, kept: int, fmt: str, unit: str = "frames") -> dict[str, Any]:
        count = int(sum(self.reasons.values()))
        total = kept + count
        if total == 0:
            raise DataFormatError(path, f"no {unit} (empty {fmt} file)")
        if kept == 0 or count > MAX_BAD_SHARE * total:
            reason = next(iter(self.reasons))
            raise DataFormatError(
                path,
                f"{count} of {total} {unit} do not fit the {fmt} layout; first bad: {reason}",
                line=self.first[0],
            )
        if count:
            reasons = "; ".join(f"{n} x {r}" for r, n in self.reasons.most_common())
            warnings.warn(f"{path}: skipped {count} of {total} {unit} ({reasons})", stacklevel=3)
        return {"count": count, "reasons": dict(self.reasons), "first_lines": self.first}


def _number(value: Any) -> float | None:
    """A JSON number as a finite float; None for anything else (text, bool, NaN, overflow)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None


def _load_json(path: Path) -> Any:
    try:
        return json.loads(read_input_bytes(path))
    except UnicodeDecodeError:
        raise DataFormatError(path, "not UTF-8 text") from None
    except json.JSONDecodeError as error:
        raise DataFormatError(path, f"not JSON ({error.msg})", line=error.lineno) from None
    except RecursionError:
        raise DataFormatError(path, "JSON nested too deeply") from None


def _build(
    path: Path,
    positions: np.ndarray,
    states: np.ndarray,
    timestamps: np.ndarray,
    metadata: dict[str, Any],
) -> Recording:
    """Not-tracked joints of empty frames take their last known position (the first known one
    before it), as the Kinect readers do; then the recording."""
    present = skeleton.body_present(states)
    if not present.any():
        raise DataFormatError(path, "no frame holds a body (every frame is empty)")
    missing = ~present[:, None] | np.all(positions == 0.0, axis=-1)
    states = np.where(missing, NOT_TRACKED, states).astype(np.int8)
    if missing.any():
        frame = np.arange(len(positions))[:, None]
        last = np.maximum.accumulate(np.where(missing, -1, frame), axis=0)
        known = ~missing
        first = np.where(known.any(axis=0), np.argmax(known, axis=0), 0)
        source = np.where(last >= 0, last, first[None, :])
        fill = positions[source, np.arange(skeleton.NUM_JOINTS)[None, :]]
        positions = np.where(missing[..., None], fill, positions)
    metadata.update(
        source=str(path),
        joint_set="kinect20",
        no_body_frames=int((~present).sum()),
        filled_joint_frames=int(missing.sum()),
        untracked_positions="last_known" if missing.any() else "sensor",
    )
    recording = Recording(
        positions=positions.astype(np.float32),
        states=states,
        timestamps=np.asarray(timestamps, dtype=np.float64),
        metadata=metadata,
    )
    check_recording(path, recording)
    return recording


# --------------------------------------------------------------------------- Azure Kinect


def is_azure_kinect_json(path: str | Path) -> bool:
    """Whether a file starts like the offline processor's JSON (cheap: reads 64 kB)."""
    try:
        with Path(path).open("rb") as handle:
            head = handle.read(65536)
    except OSError:
        return False
    return (b'"joint_names"' in head and b"PELVIS" in head) or b'"k4abt_sdk_version"' in head


def _confidence_states(value: Any, count: int) -> np.ndarray | None:
    """Per-joint confidence levels (numbers 0–3 or names) as tracking states; None if bad."""
    if not isinstance(value, list) or len(value) != count:
        return None
    states = np.empty(count, dtype=np.int8)
    for i, level in enumerate(value):
        if isinstance(level, str):
            name = level.upper().removeprefix("K4ABT_JOINT_CONFIDENCE_")
            if name not in CONFIDENCE_STATES:
                return None
            states[i] = CONFIDENCE_STATES[name]
        elif isinstance(level, int | float) and not isinstance(level, bool) and level in range(4):
            states[i] = _CONFIDENCE_BY_VALUE[int(level)]
        else:
            return None
    return states


def _azure_joints(path: Path, data: dict[str, Any]) -> tuple[np.ndarray, int]:
    """The file's column of each Kinect-20 joint (from ``joint_names``, else the 32 Azure
    Kinect joints in SDK order) and its number of joints."""
    names = data.get("joint_names", list(skeleton.AZURE_KINECT_JOINT_NAMES))
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise DataFormatError(path, "'joint_names': expected a list of joint names")
    index = {n.upper().removeprefix("K4ABT_JOINT_"): i for i, n in enumerate(names)}
    lacking = [a for a in skeleton.AZURE_KINECT_TO_KINECT20.values() if a not in index]
    if lacking:
        raise DataFormatError(
            path,
            f"'joint_names' lacks {lacking[:4]}; expected the 32 Azure Kinect joint names "
            "(PELVIS, SPINE_NAVEL, ...)",
        )
    source = np.array([index[skeleton.AZURE_KINECT_TO_KINECT20[n]] for n in skeleton.JOINT_NAMES])
    count = len(names)
    return source, count


def read_azure_kinect(path: str | Path, body: int = 0) -> Recording:
    """Read the Azure Kinect offline processor's JSON (see the module docstring).

    Parameters
    ----------
    path : str or Path
    body : int
        Which body: the k-th distinct ``body_id`` in order of first appearance.

    Raises
    ------
    DataFormatError
        Not JSON, no ``frames`` list, an unknown joint set, no (or too few) usable frames, or
        no body ``body``.
    """
    path = Path(path)
    body = check_integer(body, "body", low=0)
    data = _load_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise DataFormatError(path, "expected a JSON object with a 'frames' list (Azure Kinect)")
    source, count = _azure_joints(path, data)

    log = _FrameLog()
    body_ids: list[Any] = []
    rows: list[tuple[float, np.ndarray | None, np.ndarray | None]] = []
    confidences = False
    last = -math.inf
    for number, frame in enumerate(data["frames"], start=1):
        if not isinstance(frame, dict):
            log.skip(number, "a frame is not an object")
            continue
        stamp = _number(frame.get("timestamp_usec"))
        if stamp is None:
            log.skip(number, "no numeric 'timestamp_usec'")
            continue
        if stamp < last:
            log.skip(number, "timestamp goes back")
            continue
        bodies = frame.get("bodies", [])
        if not isinstance(bodies, list):
            log.skip(number, "'bodies' is not a list")
            continue
        for entry in bodies:
            if isinstance(entry, dict) and entry.get("body_id") not in body_ids:
                body_ids.append(entry.get("body_id"))
        wanted = body_ids[body] if body < len(body_ids) else object()
        chosen = next((b for b in bodies if isinstance(b, dict) and b["body_id"] == wanted), None)
        last = stamp
        if chosen is None:
            rows.append((last, None, None))
            continue
        try:
            joints = np.asarray(chosen.get("joint_positions"), dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            log.skip(number, "'joint_positions' not numbers")
            continue
        if joints.shape != (count, 3):
            log.skip(number, f"'joint_positions' not {count} x 3")
            continue
        if not np.all(np.isfinite(joints)):
            log.skip(number, "NaN or inf position")
            continue
        if np.abs(joints).max() > 1000.0 * MAX_COORDINATE_M:
            log.skip(number, f"a coordinate beyond ±{MAX_COORDINATE_M:g} m")
            continue
        levels = next((chosen[k] for k in _CONFIDENCE_KEYS if k in chosen), None)
        frame_states = None
        if levels is not None:
            frame_states = _confidence_states(levels, count)
            if frame_states is None:
                log.skip(number, "confidence levels not 0-3 or NONE/LOW/MEDIUM/HIGH")
                continue
            confidences = True
        rows.append((last, joints, frame_states))
    skipped = log.finish(path, len(rows), "azure_kinect")
    if body >= len(body_ids):
        raise DataFormatError(path, f"body {body}: the file holds {len(body_ids)} distinct body_id")
    frames = len(rows)
    positions = np.zeros((frames, skeleton.NUM_JOINTS, 3))
    states = np.zeros((frames, skeleton.NUM_JOINTS), dtype=np.int8)
    for i, (_, found, levels) in enumerate(rows):
        if found is None:
            continue
        # depth camera (mm; X right, Y down, Z forward) -> Kinect camera space (m; Y up)
        positions[i] = found[source] * np.array([-1.0, -1.0, 1.0]) / 1000.0
        states[i] = TRACKED if levels is None else levels[source]
    stamps = np.array([r[0] for r in rows])
    metadata: dict[str, Any] = {
        "format": "azure_kinect",
        "source_joint_set": "azure_kinect32",
        "states_in_file": confidences,
        "body_id": body_ids[body] if isinstance(body_ids[body], int | str) else None,
        "timestamp_origin_usec": float(stamps[0]),
        "skipped_lines": skipped,
    }
    if not confidences:
        metadata["states_note"] = "no confidence levels in the file: every joint marked tracked"
    return _build(path, positions, states, (stamps - stamps[0]) / 1e6, metadata)


# --------------------------------------------------------------------------- mapped CSV / JSON


def _parse_axes(text: str) -> tuple[np.ndarray, np.ndarray]:
    """``"-x,-y,z"`` -> (source column per output axis, sign per output axis)."""
    parts = [p.strip().lower() for p in text.split(",")]
    letters = [p.lstrip("+-") for p in parts]
    if len(parts) != 3 or sorted(letters) != ["x", "y", "z"]:
        raise ValueError(f"axes: expected a permutation of x,y,z with signs, got {text!r}")
    columns = np.array(["xyz".index(c) for c in letters])
    signs = np.array([-1.0 if p.startswith("-") else 1.0 for p in parts])
    return columns, signs


@dataclass(frozen=True)
class JointMap:
    """How a tracker's joints become Kinect-20 joints.

    Attributes
    ----------
    joints : dict of str to tuple of str
        Kinect-20 joint -> the source joints whose mean it is (usually one). Every Kinect-20
        joint must be covered.
    units : {"m", "cm", "mm"}
        Unit of the source's coordinates.
    axes : str
        Kinect axes from the source's, e.g. ``"-x,-y,z"`` for a camera with Y down and X right
        (Kinect camera space: Y up, Z away from the sensor, X to its left).

    Examples
    --------
    >>> pairs = [f"{n}={n}" for n in skeleton.JOINT_NAMES[1:]]
    >>> m = JointMap.from_pairs(["pelvis=HipCenter", *pairs], units="mm", axes="-x,-y,z")
    >>> m.joints["HipCenter"]
    ('pelvis',)
    """

    joints: dict[str, tuple[str, ...]]
    units: str = "m"
    axes: str = "x,y,z"
    _columns: np.ndarray = field(init=False, repr=False, compare=False)
    _signs: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        check_choice(self.units, "joint map units", tuple(UNITS))
        columns, signs = _parse_axes(self.axes)
        unknown = [k for k in self.joints if k not in skeleton.JOINT_NAMES]
        if unknown:
            raise ValueError(
                f"joint map: {unknown[:3]} are not Kinect-20 joints; expected names from "
                + ", ".join(skeleton.JOINT_NAMES)
            )
        lacking = [k for k in skeleton.JOINT_NAMES if not self.joints.get(k)]
        if lacking:
            raise ValueError(f"joint map: no source joint for {', '.join(lacking)}")
        object.__setattr__(self, "_columns", columns)
        object.__setattr__(self, "_signs", signs)

    @property
    def sources(self) -> list[str]:
        """Every source joint named, in first-use order."""
        return list(dict.fromkeys(s for k in skeleton.JOINT_NAMES for s in self.joints[k]))

    @classmethod
    def from_pairs(cls, pairs: Sequence[str], units: str = "m", axes: str = "x,y,z") -> JointMap:
        """From ``source=KinectName`` strings: a Kinect joint named twice averages its sources,
        a source named twice feeds both joints. ``units=U`` and ``axes=A`` items set
        :attr:`units` and :attr:`axes` (overriding the arguments).

        Examples
        --------
        >>> pairs = [f"{n}={n}" for n in skeleton.JOINT_NAMES if n != "HipCenter"]
        >>> m = JointMap.from_pairs(
        ...     [*pairs, "HipLeft=HipCenter", "HipRight=HipCenter", "units=mm", "axes=-x,-y,z"]
        ... )
        >>> m.joints["HipCenter"], m.units, m.axes
        (('HipLeft', 'HipRight'), 'mm', '-x,-y,z')
        """
        joints: dict[str, list[str]] = {}
        options = {"units": units, "axes": axes}
        for pair in pairs:
            source, sep, target = (part.strip() for part in pair.partition("="))
            if not sep or not source or not target:
                raise ValueError(f"joint map: expected name=KinectName, got {pair!r}")
            if source in options:
                options[source] = target
            else:
                joints.setdefault(target, []).append(source)
        return cls({k: tuple(v) for k, v in joints.items()}, **options)

    @classmethod
    def load(cls, path: str | Path) -> JointMap:
        """From a JSON file or a text file of ``source=KinectName`` lines.

        JSON: ``{"joints": {"source": "KinectName" or ["KinectName", ...], ...}, "units":
        "mm", "axes": "-x,-y,z"}`` (or just the ``joints`` object, ``units`` and ``axes``
        beside the names); a source listing several Kinect joints feeds each, and a Kinect
        joint fed by several sources is their mean (``{"l_hip": ["HipLeft", "HipCenter"],
        "r_hip": ["HipRight", "HipCenter"]}``: a pelvis from two hips). Text: one
        ``source=KinectName`` per line (a Kinect joint on several lines: the mean), ``units=mm``
        and ``axes=-x,-y,z`` lines, ``#`` comments.

        Raises
        ------
        DataFormatError
            Naming the file (and the line of a text map) when it does not fit.
        """
        path = Path(path)
        text = decode_text(read_input_bytes(path), path)  # a byte-order mark dropped
        try:
            if text.lstrip().startswith("{"):
                return cls._from_json(json.loads(text))
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"not JSON ({error.msg})", line=error.lineno) from None
        except RecursionError:
            raise DataFormatError(path, "JSON nested too deeply") from None
        except ValueError as error:
            raise DataFormatError(path, str(error)) from None
        pairs: list[str] = []
        for number, line in enumerate(text.splitlines(), start=1):
            item = line.split("#")[0].strip()
            if not item:
                continue
            if "=" not in item:
                raise DataFormatError(
                    path,
                    f"expected name=KinectName, units=U or axes=A, got {item[:60]!r}",
                    line=number,
                )
            pairs.append(item)
        try:
            return cls.from_pairs(pairs)
        except ValueError as error:
            raise DataFormatError(path, str(error)) from None

    @classmethod
    def _from_json(cls, data: Any) -> JointMap:
        """From a JSON map's data (see :meth:`load`)."""
        if not isinstance(data, dict):
            raise ValueError("expected a JSON object")
        pairs = data.get("joints", data)
        expected = "'joints': expected an object of source name -> Kinect name or list of names"
        if not isinstance(pairs, dict):
            raise ValueError(expected)
        items: list[str] = []
        for source, targets in pairs.items():
            if source in ("units", "axes") and pairs is data:
                continue
            names = [targets] if isinstance(targets, str) else targets
            if (
                not isinstance(names, list)
                or not names
                or not all(isinstance(n, str) for n in names)
            ):
                raise ValueError(f"{expected}; got {source!r}: {str(targets)[:60]}")
            items += [f"{source}={name}" for name in names]
        for option, default in (("units", "m"), ("axes", "x,y,z")):
            value = data.get(option, default)
            if not isinstance(value, str):
                raise ValueError(f"'{option}': expected text, e.g. {default!r}, got {value!r}")
            items.append(f"{option}={value}")
        return cls.from_pairs(items)

    def apply(self, values: np.ndarray, names: Sequence[str]) -> np.ndarray:
        """Source positions ``(T, S, 3)`` named ``names`` -> Kinect-20 positions ``(T, 20, 3)``
        in metres and Kinect axes."""
        index = {n: i for i, n in enumerate(names)}
        out = np.stack(
            [
                values[:, [index[s] for s in self.joints[k]]].mean(axis=1)
                for k in skeleton.JOINT_NAMES
            ],
            axis=1,
        )
        return out[..., self._columns] * self._signs * UNITS[self.units]

    def combine_states(self, states: np.ndarray, names: Sequence[str]) -> np.ndarray:
        """Source states ``(T, S)`` -> Kinect-20 states: the lowest of a joint's sources."""
        index = {n: i for i, n in enumerate(names)}
        return np.stack(
            [
                states[:, [index[s] for s in self.joints[k]]].min(axis=1)
                for k in skeleton.JOINT_NAMES
            ],
            axis=1,
        )


def _mapped_csv(path: Path, joint_map: JointMap, log: _FrameLog) -> tuple[Any, ...]:
    text = read_input_bytes(path).decode("utf-8", errors="replace").removeprefix("\ufeff")
    numbered = [
        (n, t) for n, t in enumerate(text.splitlines(), start=1) if t.strip() and t[0] != "#"
    ]
    if not numbered:
        raise DataFormatError(path, "no header line (empty CSV file)")
    header_line, header_text = numbered[0]
    header = [h.strip() for h in header_text.strip().rstrip(",").split(",")]
    column = {h: i for i, h in enumerate(header)}
    names = joint_map.sources
    lacking = [f"{n}_{a}" for n in names for a in "xyz" if f"{n}_{a}" not in column]
    if lacking:
        raise DataFormatError(
            path, f"header lacks {lacking[:4]}: the joint map names these joints", line=header_line
        )
    xyz = np.array([[column[f"{n}_{a}"] for a in "xyz"] for n in names])
    state_columns = [column.get(f"{n}_state") for n in names]
    has_time = "timestamp" in column
    rows: list[tuple[float, np.ndarray, np.ndarray]] = []
    for number, line in numbered[1:]:
        fields = [f.strip() for f in line.strip().rstrip(",").split(",")]
        if len(fields) != len(header):
            log.skip(number, f"expected {len(header)} fields, got {len(fields)}")
            continue
        try:
            values = np.array([float(f) if f else math.nan for f in fields])
        except ValueError:
            log.skip(number, "a field is not a number")
            continue
        stamp = values[column["timestamp"]] if has_time else len(rows) / DEFAULT_FPS
        joints = values[xyz]
        states = np.array(
            [TRACKED if c is None else values[c] for c in state_columns], dtype=np.float64
        )
        rows.append((float(stamp), joints, states))
    return names, rows, any(c is not None for c in state_columns), "csv"


def _mapped_json(path: Path, joint_map: JointMap, log: _FrameLog) -> tuple[Any, ...]:
    data = _load_json(path)
    frames = data.get("frames") if isinstance(data, dict) else data
    if not isinstance(frames, list):
        raise DataFormatError(path, "expected a list of frames (or an object with 'frames')")
    names = joint_map.sources
    rows: list[tuple[float, np.ndarray, np.ndarray]] = []
    has_states = False
    for number, frame in enumerate(frames, start=1):
        joints = frame.get("joints") if isinstance(frame, dict) else None
        if not isinstance(joints, dict) or not all(n in joints for n in names):
            log.skip(number, "'joints' lacks a joint of the map")
            continue
        try:
            values = np.array([joints[n] for n in names], dtype=np.float64)
            given = frame.get("states") or {}
            states = np.array([given.get(n, TRACKED) for n in names], dtype=np.float64)
        except (TypeError, ValueError, AttributeError, OverflowError):
            log.skip(number, "a value is not a number")
            continue
        if values.shape != (len(names), 3):
            log.skip(number, "a joint is not [x, y, z]")
            continue
        has_states |= bool(frame.get("states"))
        stamp = _number(frame.get("timestamp", len(rows) / DEFAULT_FPS))
        if stamp is None:
            log.skip(number, "'timestamp' is not a finite number")
            continue
        rows.append((stamp, values, states))
    return names, rows, has_states, "json"


def read_mapped(
    path: str | Path, joint_map: JointMap | Mapping[str, str] | Sequence[str]
) -> Recording:
    """Read a generic per-joint CSV or JSON file through a joint map (module docstring).

    Parameters
    ----------
    path : str or Path
        ``.csv`` or ``.json`` (``.gz`` accepted); the layout is chosen by the first character.
    joint_map : JointMap, mapping or sequence of str
        A :class:`JointMap`, ``{source: KinectName}`` or ``["source=KinectName", ...]``.

    Raises
    ------
    DataFormatError
        A header lacking a mapped joint, or no (or too few) usable frames.
    """
    path = Path(path)
    if isinstance(joint_map, Mapping):
        joint_map = JointMap.from_pairs([f"{k}={v}" for k, v in joint_map.items()])
    elif not isinstance(joint_map, JointMap):
        joint_map = JointMap.from_pairs(list(joint_map))
    log = _FrameLog()
    head = read_input_bytes(path).lstrip()[:1]
    reader = _mapped_json if head in (b"{", b"[") else _mapped_csv
    names, rows, has_states, layout = reader(path, joint_map, log)
    kept: list[tuple[float, np.ndarray, np.ndarray]] = []
    last = -math.inf
    positions_list = []
    for number, (stamp, values, states) in enumerate(rows, start=1):
        if not (
            math.isfinite(stamp) and np.all(np.isfinite(values)) and np.all(np.isfinite(states))
        ):
            log.skip(number, "NaN or inf value")
            continue
        if not np.all(np.isin(states, skeleton.TRACKING_STATES)):
            log.skip(number, "tracking state not 0, 1 or 2")
            continue
        if stamp < last:
            log.skip(number, "timestamp goes back")
            continue
        mapped = joint_map.apply(values[None], names)[0]
        if np.abs(mapped).max() > MAX_COORDINATE_M:
            log.skip(number, f"a coordinate beyond ±{MAX_COORDINATE_M:g} m")
            continue
        last = stamp
        kept.append((stamp, values, states))
        positions_list.append(mapped)
    skipped = log.finish(path, len(kept), f"mapped {layout}")
    states = joint_map.combine_states(np.stack([k[2] for k in kept]), names).astype(np.int8)
    metadata: dict[str, Any] = {
        "format": "mapped",
        "layout": layout,
        "source_joint_set": "mapped",
        "joint_map": {k: list(v) for k, v in joint_map.joints.items()},
        "units": joint_map.units,
        "axes": joint_map.axes,
        "states_in_file": has_states,
        "skipped_lines": skipped,
    }
    stamps = np.array([k[0] for k in kept])
    return _build(path, np.stack(positions_list), states, stamps - stamps[0], metadata)
