"""The Kinect v1 20-joint skeleton: the one definition every other module derives from.

Joint order is the Kinect for Windows SDK v1 order (``NUI_SKELETON_POSITION_INDEX``), which is
also the order of MSRC-12 files. Every parent index is smaller than its child's index, so walking
the joints in order visits each parent before its children.

Examples
--------
>>> from fpg_gym.core import skeleton
>>> skeleton.NUM_JOINTS, skeleton.NUM_BONES
(20, 19)
>>> skeleton.JOINT_NAMES[skeleton.PARENTS[skeleton.joint_index("ElbowLeft")]]
'ShoulderLeft'
"""

from __future__ import annotations

from typing import Final

import numpy as np
import numpy.typing as npt

#: Joint names in Kinect SDK v1 order.
JOINT_NAMES: Final[tuple[str, ...]] = (
    "HipCenter",
    "Spine",
    "ShoulderCenter",
    "Head",
    "ShoulderLeft",
    "ElbowLeft",
    "WristLeft",
    "HandLeft",
    "ShoulderRight",
    "ElbowRight",
    "WristRight",
    "HandRight",
    "HipLeft",
    "KneeLeft",
    "AnkleLeft",
    "FootLeft",
    "HipRight",
    "KneeRight",
    "AnkleRight",
    "FootRight",
)
NUM_JOINTS: Final[int] = len(JOINT_NAMES)
ROOT: Final[int] = 0

_PARENT_NAMES: Final[dict[str, str | None]] = {
    "HipCenter": None,
    "Spine": "HipCenter",
    "ShoulderCenter": "Spine",
    "Head": "ShoulderCenter",
    "ShoulderLeft": "ShoulderCenter",
    "ElbowLeft": "ShoulderLeft",
    "WristLeft": "ElbowLeft",
    "HandLeft": "WristLeft",
    "ShoulderRight": "ShoulderCenter",
    "ElbowRight": "ShoulderRight",
    "WristRight": "ElbowRight",
    "HandRight": "WristRight",
    "HipLeft": "HipCenter",
    "KneeLeft": "HipLeft",
    "AnkleLeft": "KneeLeft",
    "FootLeft": "AnkleLeft",
    "HipRight": "HipCenter",
    "KneeRight": "HipRight",
    "AnkleRight": "KneeRight",
    "FootRight": "AnkleRight",
}

_INDEX: Final[dict[str, int]] = {name: i for i, name in enumerate(JOINT_NAMES)}


def joint_index(name: str) -> int:
    """Return the index of a joint given its name.

    Parameters
    ----------
    name : str
        A name from :data:`JOINT_NAMES` (case-sensitive).

    Raises
    ------
    KeyError
        If the name is not a Kinect-20 joint; the message lists the valid names.
    """
    try:
        return _INDEX[name]
    except KeyError:
        raise KeyError(
            f"unknown Kinect-20 joint {name!r}; expected one of {', '.join(JOINT_NAMES)}"
        ) from None


#: Parent index of each joint; -1 for the root (HipCenter).
PARENTS: Final[npt.NDArray[np.intp]] = np.array(
    [-1 if p is None else _INDEX[p] for p in (_PARENT_NAMES[n] for n in JOINT_NAMES)],
    dtype=np.intp,
)
PARENTS.flags.writeable = False

#: The 19 bones as (parent, child) index pairs, ordered by child index.
BONES: Final[npt.NDArray[np.intp]] = np.array(
    [(int(PARENTS[j]), j) for j in range(NUM_JOINTS) if PARENTS[j] >= 0], dtype=np.intp
)
BONES.flags.writeable = False
NUM_BONES: Final[int] = len(BONES)

#: Bone names "Parent-Child", in the order of :data:`BONES`.
BONE_NAMES: Final[tuple[str, ...]] = tuple(f"{JOINT_NAMES[p]}-{JOINT_NAMES[c]}" for p, c in BONES)

#: For each non-root joint, the index of the bone that ends at it; -1 for the root.
BONE_OF_JOINT: Final[npt.NDArray[np.intp]] = np.full(NUM_JOINTS, -1, dtype=np.intp)
BONE_OF_JOINT[BONES[:, 1]] = np.arange(NUM_BONES)
BONE_OF_JOINT.flags.writeable = False


def _depth_levels() -> tuple[npt.NDArray[np.intp], ...]:
    depth = np.zeros(NUM_JOINTS, dtype=np.intp)
    for joint in range(1, NUM_JOINTS):  # parents have smaller indices
        depth[joint] = depth[PARENTS[joint]] + 1
    return tuple(np.flatnonzero(depth == d) for d in range(1, int(depth.max()) + 1))


#: The non-root joints grouped by depth in the tree, parents' level before children's: a
#: computation down the chains runs one vectorised step per level.
JOINT_LEVELS: Final[tuple[npt.NDArray[np.intp], ...]] = _depth_levels()

#: Left/right joint pairs as (left, right) indices.
MIRROR_PAIRS: Final[npt.NDArray[np.intp]] = np.array(
    [
        (_INDEX[name], _INDEX[name.replace("Left", "Right")])
        for name in JOINT_NAMES
        if name.endswith("Left")
    ],
    dtype=np.intp,
)
MIRROR_PAIRS.flags.writeable = False

#: Permutation that swaps every left joint with its right counterpart.
MIRROR_PERMUTATION: Final[npt.NDArray[np.intp]] = np.arange(NUM_JOINTS)
MIRROR_PERMUTATION[MIRROR_PAIRS[:, 0]] = MIRROR_PAIRS[:, 1]
MIRROR_PERMUTATION[MIRROR_PAIRS[:, 1]] = MIRROR_PAIRS[:, 0]
MIRROR_PERMUTATION.flags.writeable = False


def _ancestor_bone_matrix() -> npt.NDArray[np.float64]:
    """(NUM_JOINTS, NUM_BONES) matrix: 1 where the bone lies on the path root -> joint."""
    matrix = np.zeros((NUM_JOINTS, NUM_BONES))
    for joint in range(NUM_JOINTS):
        node = joint
        while PARENTS[node] >= 0:
            matrix[joint, BONE_OF_JOINT[node]] = 1.0
            node = int(PARENTS[node])
    return matrix


#: Joint position = root position + ``PATH_MATRIX @ bone_vectors`` (bone vector = child − parent).
PATH_MATRIX: Final[npt.NDArray[np.float64]] = _ancestor_bone_matrix()
PATH_MATRIX.flags.writeable = False

#: Kinect joint tracking states, as the SDKs report them (``NUI_SKELETON_POSITION_TRACKING_STATE``
#: in SDK v1, ``TrackingState`` in SDK 2.0).
NOT_TRACKED: Final[int] = 0
INFERRED: Final[int] = 1
TRACKED: Final[int] = 2
#: The valid tracking states, in value order.
TRACKING_STATES: Final[tuple[int, ...]] = (NOT_TRACKED, INFERRED, TRACKED)


def body_present(states: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Whether a body is in view: tracking states ``(..., J)`` -> ``(...)`` bool, True where at
    least one joint is tracked or inferred."""
    return np.asarray((np.asarray(states) > NOT_TRACKED).any(axis=-1))


#: Kinect v2 ``JointType`` names (25 joints), in SDK 2.0 order.
KINECT_V2_JOINT_NAMES: Final[tuple[str, ...]] = (
    "SpineBase",
    "SpineMid",
    "Neck",
    "Head",
    "ShoulderLeft",
    "ElbowLeft",
    "WristLeft",
    "HandLeft",
    "ShoulderRight",
    "ElbowRight",
    "WristRight",
    "HandRight",
    "HipLeft",
    "KneeLeft",
    "AnkleLeft",
    "FootLeft",
    "HipRight",
    "KneeRight",
    "AnkleRight",
    "FootRight",
    "SpineShoulder",
    "HandTipLeft",
    "ThumbLeft",
    "HandTipRight",
    "ThumbRight",
)

_V2_SOURCE: Final[dict[str, str]] = {
    "HipCenter": "SpineBase",
    "Spine": "SpineMid",
    "ShoulderCenter": "SpineShoulder",
}

#: For each Kinect-20 joint, the index of the Kinect v2 joint it is read from.
FROM_KINECT_V2: Final[npt.NDArray[np.intp]] = np.array(
    [KINECT_V2_JOINT_NAMES.index(_V2_SOURCE.get(name, name)) for name in JOINT_NAMES],
    dtype=np.intp,
)
FROM_KINECT_V2.flags.writeable = False

#: Azure Kinect Body Tracking joints (``k4abt_joint_id_t``), in SDK order.
AZURE_KINECT_JOINT_NAMES: Final[tuple[str, ...]] = (
    "PELVIS",
    "SPINE_NAVEL",
    "SPINE_CHEST",
    "NECK",
    "CLAVICLE_LEFT",
    "SHOULDER_LEFT",
    "ELBOW_LEFT",
    "WRIST_LEFT",
    "HAND_LEFT",
    "HANDTIP_LEFT",
    "THUMB_LEFT",
    "CLAVICLE_RIGHT",
    "SHOULDER_RIGHT",
    "ELBOW_RIGHT",
    "WRIST_RIGHT",
    "HAND_RIGHT",
    "HANDTIP_RIGHT",
    "THUMB_RIGHT",
    "HIP_LEFT",
    "KNEE_LEFT",
    "ANKLE_LEFT",
    "FOOT_LEFT",
    "HIP_RIGHT",
    "KNEE_RIGHT",
    "ANKLE_RIGHT",
    "FOOT_RIGHT",
    "HEAD",
    "NOSE",
    "EYE_LEFT",
    "EAR_LEFT",
    "EYE_RIGHT",
    "EAR_RIGHT",
)

#: Kinect-20 joint -> the Azure Kinect joint it is read from.
AZURE_KINECT_TO_KINECT20: Final[dict[str, str]] = {
    "HipCenter": "PELVIS",
    "Spine": "SPINE_NAVEL",
    "ShoulderCenter": "NECK",
    "Head": "HEAD",
    **{
        f"{part}{side}": f"{azure}_{side.upper()}"
        for side in ("Left", "Right")
        for part, azure in (
            ("Shoulder", "SHOULDER"),
            ("Elbow", "ELBOW"),
            ("Wrist", "WRIST"),
            ("Hand", "HAND"),
            ("Hip", "HIP"),
            ("Knee", "KNEE"),
            ("Ankle", "ANKLE"),
            ("Foot", "FOOT"),
        )
    },
}

#: For each Kinect-20 joint, its index in MSRC-12 / Kinect SDK v1 files (the same order).
FROM_KINECT_V1: Final[npt.NDArray[np.intp]] = np.arange(NUM_JOINTS, dtype=np.intp)
FROM_KINECT_V1.flags.writeable = False


def is_left(joint: int) -> bool:
    """Whether a joint is on the body's left side."""
    return JOINT_NAMES[joint].endswith("Left")


def is_right(joint: int) -> bool:
    """Whether a joint is on the body's right side."""
    return JOINT_NAMES[joint].endswith("Right")
