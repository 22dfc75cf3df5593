"""Write Kinect-20 motion as BVH, rotations solved from the joint positions.

The hierarchy (one BVH ``JOINT`` per Kinect-20 joint, named as in
:data:`fpg_gym.core.skeleton.JOINT_NAMES`, plus zero-length connectors)::

    HipCenter (ROOT: Xposition Yposition Zposition Zrotation Xrotation Yrotation)
      SpineRoot > Spine > ShoulderCenter
                            HeadRoot > Head
                            ShoulderLeftRoot > ShoulderLeft > ElbowLeft > WristLeft > HandLeft
                            ShoulderRightRoot > ShoulderRight > ... > HandRight
      HipLeftRoot > HipLeft > KneeLeft > AnkleLeft > FootLeft
      HipRightRoot > HipRight > KneeRight > AnkleRight > FootRight

Every joint but the root has ``Zrotation Xrotation Yrotation`` (intrinsic, ``R = Rz Rx Ry``);
lengths are centimetres. The rest pose is a T-pose facing +Z with Y up and the body's left on +X
(spine and neck up, arms out sideways, legs down, feet forward); each ``OFFSET`` is the rest
direction times the clip's median length of that bone. ``<Joint>Root`` connectors sit at the
branching joint (offset 0): the root's rotation is the pelvis frame (hip line and spine) and each
connector turns its branch, so that every bone points exactly where the positions say even when
the angles between branches change. A rotation turns its joint's single child from the rest
direction by the shortest arc (no twist about the bone: positions carry none). Reading the file
back (any BVH reader) gives the positions with every bone direction exact and every bone length
the clip's median; reconstructions settle their bone lengths, so they come back within their
bone-length spread (millimetres).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from fpg_gym.core import skeleton
from fpg_gym.core.outputs import atomic_path
from fpg_gym.core.rotations import shortest_arc
from fpg_gym.core.validation import check_number

__all__ = ["BVH_JOINT_MAP", "bvh_hierarchy", "write_bvh"]

#: Centimetres per metre (the file's unit).
CM = 100.0
#: End-site length past the leaf joints (cm).
END_SITE_CM = 5.0

#: Rest direction of the bone ending at each Kinect-20 joint (T-pose, facing +Z, left +X).
_REST: dict[str, tuple[float, float, float]] = {
    "Spine": (0, 1, 0),
    "ShoulderCenter": (0, 1, 0),
    "Head": (0, 1, 0),
    "ShoulderLeft": (1, 0, 0),
    "ElbowLeft": (1, 0, 0),
    "WristLeft": (1, 0, 0),
    "HandLeft": (1, 0, 0),
    "ShoulderRight": (-1, 0, 0),
    "ElbowRight": (-1, 0, 0),
    "WristRight": (-1, 0, 0),
    "HandRight": (-1, 0, 0),
    "HipLeft": (1, 0, 0),
    "KneeLeft": (0, -1, 0),
    "AnkleLeft": (0, -1, 0),
    "FootLeft": (0, 0, 1),
    "HipRight": (-1, 0, 0),
    "KneeRight": (0, -1, 0),
    "AnkleRight": (0, -1, 0),
    "FootRight": (0, 0, 1),
}

#: Joint map of :func:`fpg_gym.io.read_bvh` for files this module writes.
BVH_JOINT_MAP: dict[str, str] = {name: name for name in skeleton.JOINT_NAMES}


@dataclass(frozen=True)
class _Node:
    """One BVH joint: a Kinect joint or a connector at its parent's position."""

    name: str
    parent: int  # node index, -1 for the root
    joint: int  # the Kinect joint at this node's position
    connector: bool


def bvh_hierarchy() -> list[_Node]:
    """The written hierarchy, parents before children, in file (depth-first) order."""
    children: dict[int, list[int]] = {j: [] for j in range(skeleton.NUM_JOINTS)}
    for parent, child in skeleton.BONES:
        children[int(parent)].append(int(child))
    nodes: list[_Node] = []

    def visit(joint: int, parent: int) -> None:
        index = len(nodes)
        nodes.append(_Node(skeleton.JOINT_NAMES[joint], parent, joint, False))
        kids = children[joint]
        for child in kids:
            if len(kids) > 1:  # a branching joint: one connector per branch
                connector = len(nodes)
                name = f"{skeleton.JOINT_NAMES[child]}Root"
                nodes.append(_Node(name, index, joint, True))
                visit(child, connector)
            else:
                visit(child, index)

    visit(skeleton.ROOT, -1)
    return nodes


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.asarray(v / np.maximum(norm, 1e-12))


def _pelvis_frame(poses: np.ndarray) -> np.ndarray:
    """``(F, 3, 3)`` rotations whose columns are the body's left, up and forward axes (the
    rest pose's +X, +Y, +Z): left from the hip line, up from the spine."""
    left = _unit(
        poses[:, skeleton.joint_index("HipLeft")] - poses[:, skeleton.joint_index("HipRight")]
    )
    up = poses[:, skeleton.joint_index("Spine")] - poses[:, skeleton.ROOT]
    forward = _unit(np.cross(left, up))
    up = np.cross(forward, left)
    return np.stack([left, up, forward], axis=-1)


def _channels(poses: np.ndarray, nodes: list[_Node]) -> np.ndarray:
    """Local rotations ``(F, nodes, 3, 3)`` reproducing every bone direction of ``poses``."""
    frames = len(poses)
    children: list[list[int]] = [[] for _ in nodes]
    for index, node in enumerate(nodes):
        if node.parent >= 0:
            children[node.parent].append(index)
    local = np.broadcast_to(np.eye(3), (frames, len(nodes), 3, 3)).copy()
    world = np.empty_like(local)
    for index, node in enumerate(nodes):
        if node.parent < 0:
            parent_world = np.broadcast_to(np.eye(3), (frames, 3, 3))
        else:
            parent_world = world[:, node.parent]
        if node.parent < 0:
            local[:, index] = _pelvis_frame(poses)
        elif len(children[index]) == 1:  # aim the single child along its bone
            child = nodes[children[index][0]]
            rest = np.array(_REST[skeleton.JOINT_NAMES[child.joint]], dtype=np.float64)
            bone = poses[:, child.joint] - poses[:, node.joint]
            target = np.einsum("fji,fj->fi", parent_world, _unit(bone))  # parent frame
            quaternion = shortest_arc(np.broadcast_to(rest, target.shape), target)
            aimed = Rotation.from_quat(quaternion).as_matrix()
            still = np.linalg.norm(bone, axis=-1) < 1e-9  # coincident joints: keep the rest
            local[:, index] = np.where(still[:, None, None], np.eye(3), aimed)
        world[:, index] = parent_world @ local[:, index]
    return local


def write_bvh(
    path: str | os.PathLike[str],
    poses: np.ndarray,
    fps: float = 30.0,
) -> Path:
    """Write Kinect-20 poses as a BVH file (hierarchy in the module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.bvh`` file to write.
    poses : array_like, shape (T, 20, 3)
        Positions in metres, Y up (camera space or normalised).
    fps : float
        Frame rate (``Frame Time`` = 1 / fps).

    Raises
    ------
    ValueError
        On a wrong shape, a NaN/inf value or ``fps`` not > 0.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (skeleton.NUM_JOINTS, 3) or len(poses) == 0:
        raise ValueError(f"poses: expected shape (T, 20, 3) with T >= 1, got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise ValueError("poses: NaN or inf value")
    fps = check_number(fps, "fps", low=0.0, low_open=True)
    nodes = bvh_hierarchy()
    lengths = np.median(
        np.linalg.norm(poses[:, skeleton.BONES[:, 1]] - poses[:, skeleton.BONES[:, 0]], axis=-1),
        axis=0,
    )
    local = _channels(poses, nodes)
    flat = local.reshape(-1, 3, 3)
    angles = Rotation.from_matrix(flat).as_euler("ZXY", degrees=True)  # R = Rz Rx Ry
    angles = angles.reshape(len(poses), len(nodes), 3)

    lines = ["HIERARCHY"]
    depth_of: list[int] = []
    has_child = {n.parent for n in nodes}
    for index, node in enumerate(nodes):
        depth = 0 if node.parent < 0 else depth_of[node.parent] + 1
        depth_of.append(depth)
        # close the blocks of the previous node's subtree down to this depth
        if index:
            previous = depth_of[index - 1]
            for level in range(previous, depth - 1, -1):
                lines.append("  " * level + "}")
        pad = "  " * depth
        if node.connector or node.parent < 0:
            offset = np.zeros(3)
        else:
            bone = skeleton.BONE_OF_JOINT[node.joint]
            offset = np.array(_REST[node.name]) * lengths[bone] * CM
        lines.append(pad + ("ROOT " if node.parent < 0 else "JOINT ") + node.name)
        lines.append(pad + "{")
        lines.append(pad + "  OFFSET " + " ".join(f"{v:.6f}" for v in offset))
        if node.parent < 0:
            lines.append(pad + "  CHANNELS 6 Xposition Yposition Zposition " + _ROTATIONS)
        else:
            lines.append(pad + "  CHANNELS 3 " + _ROTATIONS)
        if index not in has_child:
            end = np.array(_REST[node.name]) * END_SITE_CM
            lines += [
                pad + "  End Site",
                pad + "  {",
                pad + "    OFFSET " + " ".join(f"{v:.6f}" for v in end),
                pad + "  }",
            ]
    for level in range(depth_of[-1], -1, -1):
        lines.append("  " * level + "}")
    lines += ["MOTION", f"Frames: {len(poses)}", f"Frame Time: {1.0 / fps:.8f}"]
    root = poses[:, skeleton.ROOT] * CM
    values = np.concatenate([root, angles.reshape(len(poses), -1)], axis=1)
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values]
    with atomic_path(path) as partial:  # beside the target, then renamed: never half-written
        partial.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return Path(path)


_ROTATIONS = "Zrotation Xrotation Yrotation"
