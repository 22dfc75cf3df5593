"""DeepMimic motion files (``humanoid3d_*.txt``) on pybullet's humanoid, as Kinect-20 clips.

A DeepMimic frame holds 44 numbers: the frame's duration in seconds, the root position (3), the
root orientation (quaternion w, x, y, z) and the local rotations of chest, neck, right hip,
right knee (1 angle), right ankle, right shoulder, right elbow (1 angle), left hip, left knee,
left ankle, left shoulder and left elbow, in that order. Knees and elbows turn about their local
Z axis, every other joint is spherical (quaternion w, x, y, z).

Forward kinematics uses the joint offsets of ``pybullet_data/humanoid/humanoid.urdf`` as pybullet
loads it with ``globalScaling=0.25`` (kept in :data:`HUMANOID_TABLE`: this reader needs no physics
engine) (how pybullet's DeepMimic environment loads it): metres,
Y up, the character facing +X with its right side at +Z. Points the humanoid has no joint for
come from its link geometry:

* Head: the centre of the neck link's head sphere;
* Hand*: one wrist-sphere diameter past the wrist along the forearm;
* Foot*: midway between the centre and the front face of the foot box, at the box centre height.

Clips are resampled to 30 Hz by spherical interpolation of the joint rotations (frame durations
vary between clips: 16, 24, 30 and 60 Hz), then forward kinematics, so bone lengths stay exact.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pybullet_data

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.rotations import axis_rotation, quaternion_to_matrix, slerp
from fpg_gym.io.clip import Clip
from fpg_gym.io.files import read_json
from fpg_gym.io.plausibility import (
    MAX_COORDINATE_M,
    check_frame_rate,
    check_plausible,
    unusual_accepted,
)

#: The 15 DeepMimic humanoid clips shipped inside the pybullet wheel (the embedded default).
DEFAULT_CLIP_NAMES: tuple[str, ...] = (
    "walk",
    "run",
    "jump",
    "kick",
    "spinkick",
    "punch",
    "dance_a",
    "dance_b",
    "cartwheel",
    "backflip",
    "crawl",
    "roll",
    "spin",
    "getup_faceup",
    "getup_facedown",
)

URDF_SCALE = 0.25
TARGET_FPS = 30.0

# (link name, number of values) after duration, root position and root orientation.
_MOTION_LAYOUT: tuple[tuple[str, int], ...] = (
    ("chest", 4),
    ("neck", 4),
    ("right_hip", 4),
    ("right_knee", 1),
    ("right_ankle", 4),
    ("right_shoulder", 4),
    ("right_elbow", 1),
    ("left_hip", 4),
    ("left_knee", 1),
    ("left_ankle", 4),
    ("left_shoulder", 4),
    ("left_elbow", 1),
)
FRAME_SIZE = 1 + 3 + 4 + sum(size for _, size in _MOTION_LAYOUT)  # 44

# Kinect-20 joint -> (humanoid link, which point of it: "joint" frame origin or a geometry point).
_KINECT_SOURCE: dict[str, tuple[str, str]] = {
    "HipCenter": ("root", "joint"),
    "Spine": ("chest", "joint"),
    "ShoulderCenter": ("neck", "joint"),
    "Head": ("neck", "head"),
    "ShoulderLeft": ("left_shoulder", "joint"),
    "ElbowLeft": ("left_elbow", "joint"),
    "WristLeft": ("left_wrist", "joint"),
    "HandLeft": ("left_wrist", "hand"),
    "ShoulderRight": ("right_shoulder", "joint"),
    "ElbowRight": ("right_elbow", "joint"),
    "WristRight": ("right_wrist", "joint"),
    "HandRight": ("right_wrist", "hand"),
    "HipLeft": ("left_hip", "joint"),
    "KneeLeft": ("left_knee", "joint"),
    "AnkleLeft": ("left_ankle", "joint"),
    "FootLeft": ("left_ankle", "foot"),
    "HipRight": ("right_hip", "joint"),
    "KneeRight": ("right_knee", "joint"),
    "AnkleRight": ("right_ankle", "joint"),
    "FootRight": ("right_ankle", "foot"),
}


@dataclass(frozen=True)
class HumanoidModel:
    """Kinematic tree of pybullet's humanoid as loaded with ``globalScaling=0.25``.

    Attributes
    ----------
    links : tuple of str
        Link names, parents before children, ``"root"`` first.
    parents : tuple of int
        Index into ``links`` of each link's parent (-1 for the root).
    offsets : ndarray, shape (L, 3)
        Joint frame origin in the parent link's frame, metres.
    points : dict
        ``(link, kind) -> (3,) offset`` in that link's frame for the Kinect-20 points.
    """

    links: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    points: dict[tuple[str, str], np.ndarray]


#: The humanoid's kinematic tree as pybullet loads it (:func:`humanoid_model`), read once from
#: pybullet by :func:`fpg_gym.physics.humanoid.humanoid_model_from_pybullet` and checked
#: against it by the tests, so that reading a clip needs no physics engine.
HUMANOID_TABLE = Path(__file__).resolve().parents[1] / "data" / "deepmimic-humanoid.json"


def model_table(model: HumanoidModel) -> dict[str, Any]:
    """``model`` as the JSON document of :data:`HUMANOID_TABLE` (floats written exactly)."""
    return {
        "description": "pybullet_data/humanoid/humanoid.urdf loaded with globalScaling="
        f"{URDF_SCALE}: links (parents first), parent indices, joint offsets in the parent's "
        "frame (m) and the Kinect-20 points taken from the link geometry "
        "(fpg_gym.physics.humanoid.humanoid_model_from_pybullet)",
        "links": list(model.links),
        "parents": list(model.parents),
        "offsets": np.asarray(model.offsets, dtype=np.float64).tolist(),
        "points": [
            {"link": link, "kind": kind, "offset": np.asarray(offset, np.float64).tolist()}
            for (link, kind), offset in model.points.items()
            if kind != "joint"
        ],
    }


def model_from_table(document: dict[str, Any]) -> HumanoidModel:
    """The :class:`HumanoidModel` of a :func:`model_table` document (every link's ``"joint"``
    point is its frame origin)."""
    links = tuple(str(link) for link in document["links"])
    points = {(link, "joint"): np.zeros(3) for link in links}
    for point in document["points"]:
        points[(str(point["link"]), str(point["kind"]))] = np.array(point["offset"], np.float64)
    return HumanoidModel(
        links,
        tuple(int(parent) for parent in document["parents"]),
        np.array(document["offsets"], dtype=np.float64),
        points,
    )


@lru_cache(maxsize=1)
def humanoid_model() -> HumanoidModel:
    """The humanoid's joint offsets and link geometry (:data:`HUMANOID_TABLE`, cached)."""
    return model_from_table(read_json(HUMANOID_TABLE))


#: Longest clip (seconds) read; a longer one is a corrupt file (its resampling would not fit
#: in memory).
MAX_DURATION_S = 24 * 3600.0


def _parse(path: Path) -> tuple[np.ndarray, bool]:
    """Frames array (T, 44) and whether the clip loops, checked: finite numbers, durations of
    a plausible frame rate (:data:`~fpg_gym.io.plausibility.FRAME_RATE_HZ`) lasting at most
    :data:`MAX_DURATION_S`, root positions within
    :data:`~fpg_gym.io.plausibility.MAX_COORDINATE_M` and rotations that are quaternions."""
    document = read_json(path)
    if not isinstance(document, dict) or "Frames" not in document:
        raise DataFormatError(path, "expected a JSON object with a 'Frames' list", field="Frames")
    frames = document["Frames"]
    if not isinstance(frames, list) or not frames:
        raise DataFormatError(path, "the clip has no frames", field="Frames")
    for index, frame in enumerate(frames):
        if not isinstance(frame, list) or len(frame) != FRAME_SIZE:
            size = len(frame) if isinstance(frame, list) else type(frame).__name__
            raise DataFormatError(
                path, f"frame {index} has {size} values, expected {FRAME_SIZE}", field="Frames"
            )
    try:
        array = np.array(frames, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataFormatError(path, "frames must hold numbers only", field="Frames") from None
    if not np.all(np.isfinite(array)):
        index = int(np.argwhere(~np.isfinite(array))[0, 0])
        raise DataFormatError(path, f"frame {index} holds NaN or inf", field="Frames")
    if np.any(array[:-1, 0] <= 0):
        index = int(np.argmax(array[:-1, 0] <= 0))
        raise DataFormatError(path, f"frame {index} has a non-positive duration", field="Frames")
    if len(array) > 1:
        durations = array[:-1, 0]
        for index in (int(np.argmin(durations)), int(np.argmax(durations))):
            check_frame_rate(path, 1.0 / durations[index], field=f"Frames[{index}][0]")
        if durations.sum() > MAX_DURATION_S:
            raise DataFormatError(
                path,
                f"the frames last {durations.sum() / 3600:.3g} h, more than "
                f"{MAX_DURATION_S / 3600:g} h: a corrupt file",
                field="Frames",
            )
    root = np.abs(array[:, 1:4]).max(axis=1)
    if not unusual_accepted() and root.max() > MAX_COORDINATE_M:
        index = int(np.argmax(root))
        raise DataFormatError(
            path,
            f"frame {index}: root position {root[index]:g} m; expected metres within "
            f"±{MAX_COORDINATE_M:g} m (--accept-unusual reads it as it is)",
            field="Frames",
        )
    column = 4
    for link, size in (("root", 4), *_MOTION_LAYOUT):
        if size == 4:
            norms = np.linalg.norm(array[:, column : column + 4], axis=1)
            if norms.min() < 1e-6:
                index = int(np.argmin(norms))
                raise DataFormatError(
                    path,
                    f"frame {index}: the {link} rotation (values {column}-{column + 3}) is "
                    "zero; expected a quaternion (w, x, y, z)",
                    field="Frames",
                )
        column += size
    return array, document.get("Loop") == "wrap"


def _resample_frames(frames: np.ndarray, fps: float) -> np.ndarray:
    """Frames resampled at ``fps`` by linear (root) and spherical (rotations) interpolation."""
    times = np.concatenate([[0.0], np.cumsum(frames[:-1, 0])])
    count = int(np.floor(times[-1] * fps + 1e-3)) + 1
    query = np.arange(count) / fps
    upper = np.clip(np.searchsorted(times, query, side="right"), 1, len(times) - 1)
    lower = upper - 1
    span = times[upper] - times[lower]
    fraction = np.clip((query - times[lower]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    if len(times) == 1:
        lower = upper = np.zeros(count, dtype=np.intp)
    a, b = frames[lower], frames[upper]
    out = a + (b - a) * fraction[:, None]  # correct for position and the revolute angles
    column = 4
    for _, size in (("root", 4), *_MOTION_LAYOUT):
        if size == 4:
            out[:, column : column + 4] = slerp(
                a[:, column : column + 4], b[:, column : column + 4], fraction
            )
        column += size
    return out


def forward_kinematics(frames: np.ndarray) -> np.ndarray:
    """Kinect-20 positions ``(T, 20, 3)`` from DeepMimic frames ``(T, 44)``."""
    model = humanoid_model()
    count = len(frames)
    rotations: dict[str, np.ndarray] = {"root": quaternion_to_matrix(frames[:, 4:8])}
    column = 8
    for link, size in _MOTION_LAYOUT:
        values = frames[:, column : column + size]
        rotations[link] = (
            quaternion_to_matrix(values) if size == 4 else axis_rotation("Z", values[:, 0])
        )
        column += size
    identity = np.broadcast_to(np.eye(3), (count, 3, 3))
    world_rotation: list[np.ndarray] = []
    world_position: list[np.ndarray] = []
    for index, (link, parent) in enumerate(zip(model.links, model.parents, strict=True)):
        local = rotations.get(link, identity)  # wrists are fixed joints
        if parent < 0:
            world_rotation.append(local)
            world_position.append(frames[:, 1:4])
            continue
        world_position.append(
            world_position[parent]
            + np.einsum("tij,j->ti", world_rotation[parent], model.offsets[index])
        )
        world_rotation.append(world_rotation[parent] @ local)
    out = np.empty((count, skeleton.NUM_JOINTS, 3))
    for joint, name in enumerate(skeleton.JOINT_NAMES):
        link, kind = _KINECT_SOURCE[name]
        index = model.links.index(link)
        out[:, joint] = world_position[index] + np.einsum(
            "tij,j->ti", world_rotation[index], model.points[(link, kind)]
        )
    return out


def read_deepmimic(path: str | Path, *, fps: float = TARGET_FPS) -> Clip:
    """Read a DeepMimic humanoid motion file as a Kinect-20 clip resampled to ``fps``.

    Parameters
    ----------
    path : str or Path
        A ``humanoid3d_*.txt`` file (JSON with ``"Frames"``, 44 numbers per frame).
    fps : float
        Output frame rate (30 Hz by default, the Kinect's).

    Raises
    ------
    DataFormatError
        If the file is not valid JSON, a frame has the wrong number of values, holds NaN/inf,
        a zero quaternion, a root beyond ±1000 m or a duration of an implausible frame rate,
        or the clip is not a person in metres
        (:func:`fpg_gym.io.plausibility.check_plausible`).
    """
    path = Path(path)
    frames, loops = _parse(path)
    positions = forward_kinematics(_resample_frames(frames, fps))
    with np.errstate(over="ignore", invalid="ignore"):
        finite = np.isfinite(positions.astype(np.float32))
    if not finite.all():
        frame = int(np.argwhere(~finite)[0, 0])
        raise DataFormatError(
            path, f"output frame {frame} is beyond float32 (a corrupt clip)", field="Frames"
        )
    check_plausible(path, positions, field="Frames")
    name = path.stem.removeprefix("humanoid3d_")
    return Clip(
        name=name,
        positions=positions.astype(np.float32),
        fps=fps,
        source=str(path),
        metadata={"format": "deepmimic", "loops": loops, "source_frames": len(frames)},
    )


def default_clip_path(name: str) -> Path:
    """Path of one embedded DeepMimic clip inside the pybullet wheel."""
    if name not in DEFAULT_CLIP_NAMES:
        raise ValueError(
            f"unknown default clip {name!r}; expected one of {', '.join(DEFAULT_CLIP_NAMES)}"
        )
    return Path(pybullet_data.getDataPath()) / "data" / "motions" / f"humanoid3d_{name}.txt"


def load_default_clips(names: tuple[str, ...] | list[str] | None = None) -> list[Clip]:
    """The embedded default database: DeepMimic clips shipped inside the pybullet wheel.

    Parameters
    ----------
    names : sequence of str, optional
        Which clips (from :data:`DEFAULT_CLIP_NAMES`); all 15 when omitted.
    """
    return [read_deepmimic(default_clip_path(name)) for name in (names or DEFAULT_CLIP_NAMES)]
