"""Pose kernels compiled (numba); imported only when ``fpg-gym[fast]`` is installed.

:func:`retarget_pose` is :func:`fpg_gym.core.poses.retarget` for one pose: the same directions (a
bone shorter than 1e-9 m takes its rest direction) and the same sums along the tree (each joint
is its root plus the bone vectors of its path, in bone order, as ``PATH_MATRIX``'s product adds
them), in one call instead of about fifteen numpy calls. :func:`assemble_nodes` builds a pose
database's candidates from their directions the same way
(:meth:`~fpg_gym.reconstruct.node_database.NodeDatabase.poses_for`), :func:`bone_lengths_pose`
and :func:`vector_angles` are :func:`fpg_gym.core.poses.bone_lengths` of one pose (the same sums)
and :func:`fpg_gym.reconstruct.reliability.behaviour_angles` (equal to rounding);
:func:`facing_yaw_pose` and :func:`place_pose` are :func:`fpg_gym.core.poses.facing_yaw`, and the
rotations of :func:`~fpg_gym.core.poses.normalise`, :func:`~fpg_gym.core.poses.into_placement` and
:func:`~fpg_gym.core.poses.denormalise`, for one pose (equal to rounding: numpy's 3 x 3 products may
fuse their multiply-adds). Module-level functions so that numba's disk cache (``cache=True``)
finds them in a new process.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core.compiled import JIT_OPTIONS

__all__ = [
    "assemble_nodes",
    "bone_frame_turns",
    "bone_lengths_pose",
    "facing_yaw_pose",
    "normalise_pose",
    "offset_pose",
    "place_pose",
    "retarget_pose",
    "scalar_maximum",
    "scalar_minimum",
    "unit_and_norm",
    "vector_angles",
]


@numba.njit(**JIT_OPTIONS)
def retarget_pose(pose, lengths, bones, rest_directions):
    """``pose`` ``(20, 3)`` float64 with bone lengths ``lengths`` ``(19,)``; ``bones`` the
    ``(parent, child)`` pairs, parents first; float32 ``(20, 3)``."""
    joints = pose.shape[0]
    offset = np.zeros((joints, 3))
    for b in range(bones.shape[0]):
        parent, child = bones[b, 0], bones[b, 1]
        vx = pose[child, 0] - pose[parent, 0]
        vy = pose[child, 1] - pose[parent, 1]
        vz = pose[child, 2] - pose[parent, 2]
        norm = np.sqrt(vx * vx + vy * vy + vz * vz)
        if norm > 1e-9:
            vx, vy, vz = vx / norm, vy / norm, vz / norm
        else:
            vx, vy, vz = rest_directions[b, 0], rest_directions[b, 1], rest_directions[b, 2]
        offset[child, 0] = offset[parent, 0] + vx * lengths[b]
        offset[child, 1] = offset[parent, 1] + vy * lengths[b]
        offset[child, 2] = offset[parent, 2] + vz * lengths[b]
    out = np.empty((joints, 3), dtype=np.float32)
    for j in range(joints):
        for c in range(3):
            out[j, c] = pose[0, c] + offset[j, c]
    return out


@numba.njit(**JIT_OPTIONS)
def assemble_nodes(directions, roots, nodes, lengths, bones):
    """Poses ``(M, 20, 3)`` float32 of the database rows ``nodes``: each root plus, along its
    path, the unit bone ``directions`` ``(N, 19, 3)`` float32 scaled by ``lengths`` ``(19,)``
    float64 rounded to float32 (the bone vectors in float32, their sums in float64)."""
    count = nodes.shape[0]
    joints = bones.shape[0] + 1
    out = np.empty((count, joints, 3), dtype=np.float32)
    offset = np.zeros((joints, 3))
    scale = lengths.astype(np.float32)
    for i in range(count):
        node = nodes[i]
        for b in range(bones.shape[0]):
            parent, child = bones[b, 0], bones[b, 1]
            for c in range(3):
                vector = directions[node, b, c] * scale[b]  # float32, as the numpy path
                offset[child, c] = offset[parent, c] + vector
        for j in range(joints):
            for c in range(3):
                out[i, j, c] = offset[j, c] + roots[node, c]
    return out


@numba.njit(**JIT_OPTIONS)
def bone_lengths_pose(pose, bones):
    """Bone lengths ``(19,)`` float64 of one pose ``(20, 3)`` float64."""
    out = np.empty(bones.shape[0])
    for b in range(bones.shape[0]):
        s = 0.0
        for c in range(3):
            v = pose[bones[b, 1], c] - pose[bones[b, 0], c]
            s += v * v
        out[b] = np.sqrt(s)
    return out


@numba.njit(**JIT_OPTIONS)
def vector_angles(a, b, min_length):
    """Angle in radians between the rows of ``a`` and ``b`` ``(J, 3)`` float64, 0 where either
    is shorter than ``min_length``."""
    out = np.zeros(a.shape[0])
    for j in range(a.shape[0]):
        na = np.sqrt(a[j, 0] * a[j, 0] + a[j, 1] * a[j, 1] + a[j, 2] * a[j, 2])
        nb = np.sqrt(b[j, 0] * b[j, 0] + b[j, 1] * b[j, 1] + b[j, 2] * b[j, 2])
        if na >= min_length and nb >= min_length:
            cos = (a[j, 0] * b[j, 0] + a[j, 1] * b[j, 1] + a[j, 2] * b[j, 2]) / (na * nb)
            out[j] = np.arccos(min(max(cos, -1.0), 1.0))
    return out


@numba.njit(**JIT_OPTIONS)
def facing_yaw_pose(pose, hip_left, hip_right, shoulder_left, shoulder_right, degenerate):
    """Heading of one pose ``(20, 3)`` float64 from its hip line (the shoulder line when the
    hips' horizontal extent is under ``degenerate``), radians; 0 when both are degenerate."""
    rx = pose[hip_right, 0] - pose[hip_left, 0]
    rz = pose[hip_right, 2] - pose[hip_left, 2]
    if not np.hypot(rx, rz) > degenerate:
        rx = pose[shoulder_right, 0] - pose[shoulder_left, 0]
        rz = pose[shoulder_right, 2] - pose[shoulder_left, 2]
    forward_x, forward_z = rz, -rx  # up x right; yaw from +Z towards +X
    if np.hypot(forward_x, forward_z) > degenerate:
        return np.arctan2(forward_x, forward_z)
    return 0.0


@numba.njit(**JIT_OPTIONS)
def normalise_pose(pose, root, hip_left, hip_right, shoulder_left, shoulder_right, degenerate):
    """:func:`fpg_gym.core.poses.normalise` of one pose ``(20, 3)`` float64: its heading
    (:func:`facing_yaw_pose`) and the pose turned into it about its ``root`` joint
    (:func:`place_pose`) as float32."""
    yaw = facing_yaw_pose(pose, hip_left, hip_right, shoulder_left, shoulder_right, degenerate)
    placed = place_pose(pose, pose[root], yaw, np.bool_(False))
    out = np.empty(placed.shape, dtype=np.float32)
    for j in range(placed.shape[0]):
        for c in range(3):
            out[j, c] = np.float32(placed[j, c])
    return out, yaw


@numba.njit(**JIT_OPTIONS)
def place_pose(pose, root, yaw, inverse):
    """One pose ``(20, 3)`` float64 turned about +Y: ``(p - root) R_y(yaw)`` (row vectors: into
    the placement's frame), or with ``inverse`` ``p R_y(yaw)^T + root`` (back to camera space);
    float64."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.empty_like(pose)
    for j in range(pose.shape[0]):
        if inverse:
            x, y, z = pose[j, 0], pose[j, 1], pose[j, 2]
            out[j, 0] = (x * c + z * s) + root[0]
            out[j, 1] = y + root[1]
            out[j, 2] = (z * c - x * s) + root[2]
        else:
            x, y, z = pose[j, 0] - root[0], pose[j, 1] - root[1], pose[j, 2] - root[2]
            out[j, 0] = x * c - z * s
            out[j, 1] = y
            out[j, 2] = x * s + z * c
    return out


@numba.njit(**JIT_OPTIONS)
def unit_and_norm(x, y, z):
    """A vector's norm (its squares summed in order, as numpy's) and the vector over
    ``np.maximum(norm, 1e-9)`` (:func:`fpg_gym.definitions._unit`)."""
    norm = np.sqrt((x * x + y * y) + z * z)
    scale = scalar_maximum(norm, 1e-9)
    return norm, x / scale, y / scale, z / scale


@numba.njit(**JIT_OPTIONS)
def _trunk_frame(pose, left_end, right_end, top, bottom, out):
    """:func:`fpg_gym.definitions._trunk_frame` of ``left = p[left_end] - p[right_end]`` and
    ``up = p[top] - p[bottom]`` into ``out`` ``(3, 3)`` (columns: left, up, forward)."""
    _, x0, x1, x2 = unit_and_norm(
        pose[left_end, 0] - pose[right_end, 0],
        pose[left_end, 1] - pose[right_end, 1],
        pose[left_end, 2] - pose[right_end, 2],
    )
    u0 = pose[top, 0] - pose[bottom, 0]
    u1 = pose[top, 1] - pose[bottom, 1]
    u2 = pose[top, 2] - pose[bottom, 2]
    along = (u0 * x0 + u1 * x1) + u2 * x2
    _, y0, y1, y2 = unit_and_norm(u0 - along * x0, u1 - along * x1, u2 - along * x2)
    out[0, 0], out[1, 0], out[2, 0] = x0, x1, x2
    out[0, 1], out[1, 1], out[2, 1] = y0, y1, y2
    out[0, 2] = x1 * y2 - x2 * y1  # np.cross's products
    out[1, 2] = x2 * y0 - x0 * y2
    out[2, 2] = x0 * y1 - x1 * y0


@numba.njit(**JIT_OPTIONS)
def bone_frame_turns(pose, trunk_joints, ends, parents, on_thorax, rest):
    """The first half of :func:`fpg_gym.definitions.joint_frames` for one pose ``(20, 3)``
    float64 (the numpy code's operations in its order): the pelvis and thorax frames ``(2, 3,
    3)`` (``trunk_joints``: HipLeft, HipRight, ShoulderCenter, HipCenter, ShoulderLeft,
    ShoulderRight, Spine), each bone's base frame ``(B, 3, 3)`` and the rotation ``(B, 3, 3)``
    that takes its rest direction onto its direction in that base (the shortest arc); the
    caller multiplies the two (numpy's product). ``ok`` is False when a bone points opposite
    its rest direction (the numpy code then picks a half turn: the caller takes its path)."""
    trunks = np.empty((2, 3, 3))
    _trunk_frame(
        pose, trunk_joints[0], trunk_joints[1], trunk_joints[2], trunk_joints[3], trunks[0]
    )
    _trunk_frame(
        pose, trunk_joints[4], trunk_joints[5], trunk_joints[2], trunk_joints[6], trunks[1]
    )
    count = ends.shape[0]
    base = np.empty((count, 3, 3))
    turn = np.empty((count, 3, 3))
    local = np.empty(3)
    for b in range(count):
        t = 1 if on_thorax[b] else 0
        for r in range(3):
            for c in range(3):
                base[b, r, c] = trunks[t, r, c]
        end, parent = ends[b], parents[b]
        _, d0, d1, d2 = unit_and_norm(
            pose[end, 0] - pose[parent, 0],
            pose[end, 1] - pose[parent, 1],
            pose[end, 2] - pose[parent, 2],
        )
        for i in range(3):  # the direction in the base frame's coordinates
            local[i] = (trunks[t, 0, i] * d0 + trunks[t, 1, i] * d1) + trunks[t, 2, i] * d2
        a0, a1, a2 = rest[b, 0], rest[b, 1], rest[b, 2]
        qx = a1 * local[2] - a2 * local[1]  # shortest_arc: (a x b, 1 + a.b), normalised
        qy = a2 * local[0] - a0 * local[2]
        qz = a0 * local[1] - a1 * local[0]
        qw = 1.0 + ((a0 * local[0] + a1 * local[1]) + a2 * local[2])
        norm = np.sqrt(((qx * qx + qy * qy) + qz * qz) + qw * qw)
        if norm < 1e-6:
            return trunks, base, turn, False
        w, x, y, z = qw / norm, qx / norm, qy / norm, qz / norm
        norm = np.sqrt(((w * w + x * x) + y * y) + z * z)  # quaternion_to_matrix normalises
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        turn[b, 0, 0] = 1 - 2 * (y * y + z * z)
        turn[b, 0, 1] = 2 * (x * y - w * z)
        turn[b, 0, 2] = 2 * (x * z + w * y)
        turn[b, 1, 0] = 2 * (x * y + w * z)
        turn[b, 1, 1] = 1 - 2 * (x * x + z * z)
        turn[b, 1, 2] = 2 * (y * z - w * x)
        turn[b, 2, 0] = 2 * (x * z - w * y)
        turn[b, 2, 1] = 2 * (y * z + w * x)
        turn[b, 2, 2] = 1 - 2 * (x * x + y * y)
    return trunks, base, turn, True


@numba.njit(**JIT_OPTIONS)
def offset_pose(pose, trunks, turned, pelvis_joints, thorax_joints, bone_joints, offsets):
    """``p(j) + F_j · o_j`` of one pose ``(20, 3)`` float64 (:meth:`DefinitionMap.apply
    <fpg_gym.definitions.DefinitionMap.apply>`, its product summed in ``np.einsum``'s
    order), the frames ``F_j`` being the pelvis's, the thorax's (``trunks``) or the bones'
    ``turned`` ``(B, 3, 3)`` (:func:`bone_frame_turns`'s base times turn)."""
    out = np.empty_like(pose)
    for j in range(pose.shape[0]):
        for a in range(3):
            out[j, a] = pose[j, a]
    for k in range(pelvis_joints.shape[0] + thorax_joints.shape[0] + bone_joints.shape[0]):
        if k < pelvis_joints.shape[0]:
            j, source, row = pelvis_joints[k], trunks, 0
        elif k < pelvis_joints.shape[0] + thorax_joints.shape[0]:
            j, source, row = thorax_joints[k - pelvis_joints.shape[0]], trunks, 1
        else:
            row = k - pelvis_joints.shape[0] - thorax_joints.shape[0]
            j, source = bone_joints[row], turned
        for a in range(3):
            out[j, a] = pose[j, a] + (
                (source[row, a, 0] * offsets[j, 0] + source[row, a, 2] * offsets[j, 2])
                + source[row, a, 1] * offsets[j, 1]
            )
    return out


@numba.njit(**JIT_OPTIONS)
def scalar_maximum(a, b):
    """``np.maximum`` of two floats (NaN when either is)."""
    return a if (a >= b or a != a) else b


@numba.njit(**JIT_OPTIONS)
def scalar_minimum(a, b):
    """``np.minimum`` of two floats (NaN when either is)."""
    return a if (a <= b or a != a) else b
