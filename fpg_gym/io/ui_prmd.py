"""Readers for UI-PRMD: real Kinect v2 streams with simultaneous Vicon markers.

UI-PRMD (Vakanski, Jun, Paul & Baker, *Data* 3(1):2, 2018; ODC-PDDL) recorded rehabilitation
exercises with a Kinect v2 (30 Hz) and a Vicon system (39 Plug-in-Gait markers, 100 Hz) at the
same time. File names are ``mMM_sSS_eEE_positions.txt.gz`` (movement, subject, repetition).

Kinect files (:func:`read_kinect_repetition`)
    ``Positions`` hold 22 joints × 3 values a line, centimetres: joint 0 is the absolute waist
    position, joints 1–21 are offsets in the parent's local frame; ``Angles`` hold each joint's
    local rotation in degrees, columns (x, y, z). Forward kinematics:
    ``R_local = Rz(z) Rx(x) Ry(y)``, ``R_global = R_global(parent) R_local``,
    ``p = p(parent) + R_global(parent) offset`` (the order that reproduces the Vicon data). The
    result (Y up, subject facing +Z, left at +X) is turned half a turn about Y into the Kinect
    SDK's camera convention (subject facing the sensor, i.e. −Z, left shoulder at −X).

Kinect-20 mapping
    HipCenter 0, Spine 1, ShoulderCenter 2, **Head 5** (the head tip; joint 4 sits near the
    Kinect v2 Neck), Shoulder/Elbow/Wrist 7/8/9 and 11/12/13, Hip/Knee/Ankle/Foot 14–17 and
    18–21. The files have no hand joint and no tracking states: ``HandLeft``/``HandRight`` are
    placed :data:`HAND_EXTENSION_M` past the wrist along the forearm and marked *inferred*; every
    other joint is *tracked*.

Vicon files (:func:`read_vicon_markers`, :func:`vicon_joint_centres`)
    39 markers × 3 values a line, millimetres, Z up. Marker gaps (0, 0, 0) are filled by linear
    interpolation in time. Joint centres, which define the ground truth, follow
    :data:`JOINT_CENTRE_RULE`:

    ==============  ================================================================
    Kinect-20       rule
    ==============  ================================================================
    Hip L/R         Harrington et al. (2007) regression from LASI, RASI, LPSI, RPSI:
                    0.24 PD + 9.9 mm posterior, 0.30 PW + 10.9 mm inferior,
                    0.33 PW + 7.3 mm lateral of the mid-ASIS (PW inter-ASIS width,
                    PD mid-ASIS to mid-PSIS depth)
    HipCenter       midpoint of the two hip joint centres
    Spine           midpoint of T10 and STRN
    ShoulderCenter  midpoint of C7 and CLAV
    Head            mean of LFHD, RFHD, LBHD, RBHD
    Shoulder L/R    Rab et al. (2002): the acromion marker (LSHO/RSHO) moved down the
                    thorax axis by 17 % of the inter-acromion distance
    Elbow L/R       the lateral epicondyle marker (LELB/RELB); no medial offset (the
                    data set has neither elbow widths nor medial markers)
    Wrist L/R       midpoint of the wrist markers (LWRA/LWRB)
    Hand L/R        the finger marker (LFIN/RFIN, second metacarpal head)
    Knee L/R        the lateral knee marker moved 57 mm medially (half a 100 mm knee
                    width plus a 7 mm marker radius), perpendicular to the thigh, along
                    the pelvis's left-right axis
    Ankle L/R       the lateral malleolus marker moved 42 mm medially (half a 70 mm
                    ankle width plus 7 mm), perpendicular to the shank, same axis
    Foot L/R        the toe marker (LTOE/RTOE)
    ==============  ================================================================

    Vicon positions are returned in metres, Y up (Vicon ``(x, y, z)`` → ``(x, z, −y)``).

See ``../shared/data/ui_prmd/README.md`` of the project for the pairing facts.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.rotations import euler_to_matrix
from fpg_gym.io._compression import read_input_bytes
from fpg_gym.io.recording import Recording

__all__ = [
    "HAND_EXTENSION_M",
    "JOINT_CENTRE_RULE",
    "KINECT_FPS",
    "KINECT_PARENTS",
    "PLAUSIBLE_PELVIS_WIDTH_M",
    "VICON_FPS",
    "VICON_MARKERS",
    "RepetitionId",
    "kinect_forward_kinematics",
    "kinect_to_kinect20",
    "parse_repetition_name",
    "pelvis_width",
    "read_kinect_repetition",
    "read_vicon_markers",
    "vicon_joint_centres",
]

KINECT_FPS = 30.0
VICON_FPS = 100.0
#: Parents of the 22 UI-PRMD Kinect joints (each joint is named for the segment that starts at it).
KINECT_PARENTS: tuple[int, ...] = (
    -1, 0, 1, 2, 3, 4, 2, 6, 7, 8, 2, 10, 11, 12, 0, 14, 15, 16, 0, 18, 19, 20,
)  # fmt: skip
NUM_KINECT_JOINTS = len(KINECT_PARENTS)
#: UI-PRMD Kinect joint of each Kinect-20 joint; -1 for the hands (placed past the wrist).
KINECT20_SOURCE: tuple[int, ...] = (
    0, 1, 2, 5,          # HipCenter, Spine, ShoulderCenter, Head (head tip)
    7, 8, 9, -1,         # left arm
    11, 12, 13, -1,      # right arm
    14, 15, 16, 17,      # left leg
    18, 19, 20, 21,      # right leg
)  # fmt: skip
#: How far past the wrist, along the forearm, the missing Kinect hand joint is placed (metres).
HAND_EXTENSION_M = 0.07
#: Plug-in-Gait marker names, in file order.
VICON_MARKERS: tuple[str, ...] = tuple(
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA "
    "RELB RFRM RWRA RWRB RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB "
    "RANK RHEE RTOE".split()
)
#: Name of the joint-centre rule of :func:`vicon_joint_centres` (stored in imported files).
JOINT_CENTRE_RULE = "harrington2007-hips+rab2002-shoulders+lateral-markers-v1"
#: Inter-ASIS widths (LASI to RASI, metres) the hip rule is trusted with: beyond adult pelvises
#: at both ends (UI-PRMD's sessions of s01-s04 and s06-s08 measure 0.24-0.28 m; s05's markers
#: sit 0.43-0.46 m apart, which puts its Harrington hip centres 0.29-0.32 m apart).
PLAUSIBLE_PELVIS_WIDTH_M = (0.18, 0.34)
_KNEE_OFFSET_M = 0.057
_ANKLE_OFFSET_M = 0.042
_NAME = re.compile(r"^m(\d+)_s(\d+)_e(\d+)_(positions|angles)\.txt(\.gz)?$")
_MARKER = {name: i for i, name in enumerate(VICON_MARKERS)}


@dataclass(frozen=True, order=True)
class RepetitionId:
    """One UI-PRMD repetition: movement (exercise), subject and repetition numbers."""

    movement: int
    subject: int
    repetition: int

    @property
    def session(self) -> str:
        """``mMM_sSS``: one exercise of one subject (one camera placement)."""
        return f"m{self.movement:02d}_s{self.subject:02d}"

    @property
    def name(self) -> str:
        """``mMM_sSS_eEE``."""
        return f"{self.session}_e{self.repetition:02d}"

    @property
    def subject_name(self) -> str:
        """``sSS``."""
        return f"s{self.subject:02d}"


def parse_repetition_name(path: str | Path) -> RepetitionId:
    """The repetition a UI-PRMD file holds, from its name (``mMM_sSS_eEE_positions.txt.gz``).

    Raises
    ------
    DataFormatError
        If the name does not follow the pattern.
    """
    match = _NAME.match(Path(path).name)
    if match is None:
        raise DataFormatError(
            path, "not a UI-PRMD file name; expected mMM_sSS_eEE_positions.txt[.gz]"
        )
    return RepetitionId(int(match[1]), int(match[2]), int(match[3]))


def _read_table(path: Path, columns: int) -> np.ndarray:
    """A comma-separated numeric table (gzip or plain) with ``columns`` values a line."""
    raw = read_input_bytes(path)  # gzip inflated within the memory ceiling
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise DataFormatError(path, "not a text file (non-ASCII bytes)") from None
    rows: list[list[float]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        fields = [f for f in line.strip().rstrip(",").split(",")] if line.strip() else []
        if not fields:
            continue
        if len(fields) != columns:
            raise DataFormatError(
                path, f"expected {columns} comma-separated values, got {len(fields)}", line=number
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise DataFormatError(path, "a value is not a number", line=number) from None
        if not all(np.isfinite(values)) or max(abs(v) for v in values) > 1e5:
            raise DataFormatError(
                path, "expected finite values below 1e5 (cm, mm or degrees)", line=number
            )
        rows.append(values)
    if not rows:
        raise DataFormatError(path, "no data line")
    return np.asarray(rows, dtype=np.float64)


# --------------------------------------------------------------------------- Kinect


def kinect_forward_kinematics(offsets_cm: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """Joint positions ``(T, 22, 3)`` in metres from UI-PRMD positions and angles.

    Parameters
    ----------
    offsets_cm : ndarray, shape (T, 22, 3)
        Joint 0 absolute, the others offsets in the parent's local frame, centimetres.
    angles_deg : ndarray, shape (T, 22, 3)
        Local rotations, columns (x, y, z), degrees.

    Returns
    -------
    ndarray, shape (T, 22, 3)
        Y up, the subject facing +Z, left at +X (the data set's own space).
    """
    # R_local = Rz(z) Rx(x) Ry(y): channels in "ZXY" order.
    local = euler_to_matrix(angles_deg[..., [2, 0, 1]], "ZXY")  # (T, 22, 3, 3)
    count = offsets_cm.shape[0]
    glob = np.empty((count, NUM_KINECT_JOINTS, 3, 3))
    positions = np.empty((count, NUM_KINECT_JOINTS, 3))
    glob[:, 0] = local[:, 0]
    positions[:, 0] = offsets_cm[:, 0]
    for joint in range(1, NUM_KINECT_JOINTS):  # a tree walk over 22 fixed joints, vectorised in T
        parent = KINECT_PARENTS[joint]
        glob[:, joint] = glob[:, parent] @ local[:, joint]
        positions[:, joint] = positions[:, parent] + np.einsum(
            "tij,tj->ti", glob[:, parent], offsets_cm[:, joint]
        )
    return positions * 0.01


def kinect_to_kinect20(joints22: np.ndarray) -> np.ndarray:
    """UI-PRMD's 22 Kinect joints (data-set space) to Kinect-20 in camera convention.

    Hands are placed :data:`HAND_EXTENSION_M` past the wrist along the forearm; the result is
    turned half a turn about Y (``(x, y, z) -> (-x, y, -z)``).
    """
    source = np.asarray(KINECT20_SOURCE)
    out = joints22[:, np.maximum(source, 0)].copy()
    for hand, wrist, elbow in ((7, 6, 5), (11, 10, 9)):
        forearm = out[:, wrist] - out[:, elbow]
        norm = np.linalg.norm(forearm, axis=-1, keepdims=True)
        out[:, hand] = out[:, wrist] + HAND_EXTENSION_M * forearm / np.maximum(norm, 1e-9)
    out[..., 0] *= -1.0
    out[..., 2] *= -1.0
    return out


def read_kinect_repetition(positions_path: str | Path, angles_path: str | Path) -> Recording:
    """Read one UI-PRMD Kinect repetition (positions + angles files) as a :class:`Recording`.

    Every joint is *tracked* but the hands (*inferred*, see the module docstring); timestamps
    are at 30 Hz from 0.

    Raises
    ------
    DataFormatError
        On a malformed file, or when the two files differ in length.
    """
    positions_path, angles_path = Path(positions_path), Path(angles_path)
    offsets = _read_table(positions_path, 3 * NUM_KINECT_JOINTS).reshape(-1, NUM_KINECT_JOINTS, 3)
    angles = _read_table(angles_path, 3 * NUM_KINECT_JOINTS).reshape(-1, NUM_KINECT_JOINTS, 3)
    if len(offsets) != len(angles):
        raise DataFormatError(
            angles_path, f"{len(angles)} frames, but {positions_path.name} has {len(offsets)}"
        )
    joints = kinect_to_kinect20(kinect_forward_kinematics(offsets, angles))
    states = np.full((len(joints), skeleton.NUM_JOINTS), skeleton.TRACKED, dtype=np.int8)
    states[:, [skeleton.joint_index("HandLeft"), skeleton.joint_index("HandRight")]] = (
        skeleton.INFERRED
    )
    rep = parse_repetition_name(positions_path)
    return Recording(
        positions=joints.astype(np.float32),
        states=states,
        timestamps=np.arange(len(joints)) / KINECT_FPS,
        metadata={
            "source": str(positions_path),
            "format": "ui-prmd-kinect",
            "joint_set": "kinect20",
            "sensor": "kinect-v2",
            "untracked_positions": "sensor",
            "repetition": rep.name,
            "subject": rep.subject_name,
        },
    )


# --------------------------------------------------------------------------- Vicon


def read_vicon_markers(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a UI-PRMD Vicon file: markers ``(T, 39, 3)`` in metres, Y up, gaps filled.

    Returns
    -------
    markers : ndarray, shape (T, 39, 3)
    gaps : ndarray, shape (T, 39), bool
        Samples that were (0, 0, 0) in the file and were interpolated.

    Raises
    ------
    DataFormatError
        On a malformed file, or a marker missing in every frame.
    """
    path = Path(path)
    raw = _read_table(path, 3 * len(VICON_MARKERS)).reshape(-1, len(VICON_MARKERS), 3) * 0.001
    gaps = np.all(raw == 0.0, axis=-1)
    if gaps.all(axis=0).any():
        marker = VICON_MARKERS[int(np.argmax(gaps.all(axis=0)))]
        raise DataFormatError(path, f"marker {marker} is missing in every frame")
    if gaps.any():
        frames = np.arange(len(raw))
        for column in np.flatnonzero(gaps.any(axis=0)):  # a few markers, each once
            ok = ~gaps[:, column]
            for axis in range(3):
                raw[~ok, column, axis] = np.interp(frames[~ok], frames[ok], raw[ok, column, axis])
    # Z up (Vicon) to Y up: (x, y, z) -> (x, z, -y), a proper rotation.
    markers = np.stack([raw[..., 0], raw[..., 2], -raw[..., 1]], axis=-1)
    return markers, gaps


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)


def _medial(marker: np.ndarray, proximal: np.ndarray, lateral_axis: np.ndarray) -> np.ndarray:
    """Unit vector from a lateral marker towards the body's midline, perpendicular to the
    segment ``proximal -> marker``; ``lateral_axis`` points from the midline to this side."""
    axis = _unit(marker - proximal)
    medial = -lateral_axis
    medial = medial - np.sum(medial * axis, axis=-1, keepdims=True) * axis
    return _unit(medial)


def pelvis_width(markers: np.ndarray) -> np.ndarray:
    """The inter-ASIS width ``PW`` (LASI to RASI) of each frame ``(T,)``, in the markers' unit;
    the Harrington hip rule scales with it (:func:`vicon_joint_centres`).

    Parameters
    ----------
    markers : ndarray, shape (T, 39, 3)
        Markers in :data:`VICON_MARKERS` order.
    """
    return np.linalg.norm(markers[:, _MARKER["LASI"]] - markers[:, _MARKER["RASI"]], axis=-1)


def vicon_joint_centres(markers: np.ndarray) -> np.ndarray:
    """Kinect-20 joint centres ``(T, 20, 3)`` from Plug-in-Gait markers (:data:`JOINT_CENTRE_RULE`).

    Parameters
    ----------
    markers : ndarray, shape (T, 39, 3)
        Markers in metres, in :data:`VICON_MARKERS` order (any right-handed frame).
    """
    m = {name: markers[:, i] for name, i in _MARKER.items()}
    mid_asis = 0.5 * (m["LASI"] + m["RASI"])
    mid_psis = 0.5 * (m["LPSI"] + m["RPSI"])
    left = _unit(m["LASI"] - m["RASI"])
    forward = mid_asis - mid_psis
    depth = np.linalg.norm(forward, axis=-1, keepdims=True)
    forward = _unit(forward - np.sum(forward * left, axis=-1, keepdims=True) * left)
    up = np.cross(forward, left)
    width = pelvis_width(markers)[:, None]
    # Harrington et al. 2007 (mm in the paper; the constants in metres here).
    back = -(0.24 * depth + 0.0099) * forward
    down = -(0.30 * width + 0.0109) * up
    side = (0.33 * width + 0.0073) * left
    hip_left = mid_asis + back + down + side
    hip_right = mid_asis + back + down - side

    neck = 0.5 * (m["C7"] + m["CLAV"])
    spine = 0.5 * (m["T10"] + m["STRN"])
    thorax_up = _unit(neck - spine)
    acromion_width = np.linalg.norm(m["LSHO"] - m["RSHO"], axis=-1, keepdims=True)
    shoulder_left = m["LSHO"] - 0.17 * acromion_width * thorax_up  # Rab et al. 2002
    shoulder_right = m["RSHO"] - 0.17 * acromion_width * thorax_up

    knee_left = m["LKNE"] + _KNEE_OFFSET_M * _medial(m["LKNE"], hip_left, left)
    knee_right = m["RKNE"] + _KNEE_OFFSET_M * _medial(m["RKNE"], hip_right, -left)
    ankle_left = m["LANK"] + _ANKLE_OFFSET_M * _medial(m["LANK"], knee_left, left)
    ankle_right = m["RANK"] + _ANKLE_OFFSET_M * _medial(m["RANK"], knee_right, -left)

    head = 0.25 * (m["LFHD"] + m["RFHD"] + m["LBHD"] + m["RBHD"])
    joints = {
        "HipCenter": 0.5 * (hip_left + hip_right),
        "Spine": spine,
        "ShoulderCenter": neck,
        "Head": head,
        "ShoulderLeft": shoulder_left,
        "ElbowLeft": m["LELB"],
        "WristLeft": 0.5 * (m["LWRA"] + m["LWRB"]),
        "HandLeft": m["LFIN"],
        "ShoulderRight": shoulder_right,
        "ElbowRight": m["RELB"],
        "WristRight": 0.5 * (m["RWRA"] + m["RWRB"]),
        "HandRight": m["RFIN"],
        "HipLeft": hip_left,
        "KneeLeft": knee_left,
        "AnkleLeft": ankle_left,
        "FootLeft": m["LTOE"],
        "HipRight": hip_right,
        "KneeRight": knee_right,
        "AnkleRight": ankle_right,
        "FootRight": m["RTOE"],
    }
    return np.stack([joints[name] for name in skeleton.JOINT_NAMES], axis=1)
