"""The ragdoll's kinematics in numpy: the tree of its bones, quaternions and the frames.

:class:`~fpg_gym.physics.ragdoll.Ragdoll` turns a Kinect-20 target into the 19 capsules' goals
(:func:`bone_frames`, :func:`body_goals`) and the simulated capsules back into joints
(:func:`pose_from`). :mod:`fpg_gym.physics.compiled_ragdoll` holds the same formulas compiled
(numba); the ragdoll uses those when ``fpg-gym[fast]`` is installed. Quaternions are (x, y, z, w).
"""

from __future__ import annotations

import math

import numpy as np

from fpg_gym.core import poses, skeleton
from fpg_gym.core.rotations import cross_product, shortest_arc

NUM_BONES = skeleton.NUM_BONES
HIP_LEFT = skeleton.joint_index("HipLeft")
HIP_RIGHT = skeleton.joint_index("HipRight")
SHOULDER_LEFT = skeleton.joint_index("ShoulderLeft")
SHOULDER_RIGHT = skeleton.joint_index("ShoulderRight")
#: A bone shorter than this (m) keeps the last frame's direction.
DEGENERATE_M = 1e-6


# --------------------------------------------------------------------------- tree of the bones


def _parent_bones() -> np.ndarray:
    """Parent bone of each bone: the bone ending at its start joint; the bones leaving the root
    (the pelvis halves) hang from bone 0 (HipCenter–Spine). -1 for bone 0."""
    parents = np.array([skeleton.BONE_OF_JOINT[p] for p, _ in skeleton.BONES], dtype=np.intp)
    parents[parents < 0] = 0
    parents[0] = -1
    return parents


PARENT_BONE = _parent_bones()


def _levels() -> list[np.ndarray]:
    """Bones grouped by depth below bone 0 (a parent always sits in an earlier group)."""
    depth = np.zeros(NUM_BONES, dtype=np.intp)
    for bone in range(1, NUM_BONES):  # BONES is ordered so that a parent bone comes first
        depth[bone] = depth[PARENT_BONE[bone]] + 1
    return [np.flatnonzero(depth == d) for d in range(1, int(depth.max()) + 1)]


LEVELS = _levels()
PATH = np.array(skeleton.PATH_MATRIX)  # joint = root + PATH @ bone vectors
STARTS = np.array(skeleton.BONES[:, 0])
BONES = np.ascontiguousarray(skeleton.BONES, dtype=np.intp)
LINES = np.array([[HIP_LEFT, HIP_RIGHT], [SHOULDER_LEFT, SHOULDER_RIGHT]], dtype=np.intp)


# --------------------------------------------------------------------------- quaternions (x y z w)
# Written out component by component: these run on (19, 4) arrays every frame, where numpy's
# generic cross/moveaxis cost more than the arithmetic.


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
    out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


def quat_conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    u = q[..., :3]
    t = 2.0 * cross_product(u, v)
    return v + q[..., 3:] * t + cross_product(u, t)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """One rotation matrix ``(3, 3)`` to a unit quaternion (x, y, z, w) (Shepperd's method)."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-12))
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i] = s / 4
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
    out = np.array(q)
    return out / np.linalg.norm(out)


# --------------------------------------------------------------------------- frames


def bone_frames(
    pose64: np.ndarray,
    directions_before: np.ndarray,
    root_frame: np.ndarray,
    rest_directions: np.ndarray,
    root_arc: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """World orientations ``(19, 4)`` of the bones relative to the rest pose that put every bone
    along the target's bone direction, and those directions ``(19, 3)`` (a degenerate bone keeps
    ``directions_before``); the root frame from the spine and the hip line (the shoulder line,
    then ``root_frame``'s), every other bone by the zero-twist rule (the ragdoll's docstring)."""
    vectors = poses.bone_vectors(pose64)
    norms = np.sqrt(np.sum(vectors * vectors, axis=-1, keepdims=True))
    ok = norms > DEGENERATE_M
    directions = np.where(ok, vectors / np.where(ok, norms, 1.0), directions_before)
    # Root frame: spine direction and the hip line (shoulder line, then the last frame's).
    up = directions[0]
    left = None
    for a, b in ((HIP_LEFT, HIP_RIGHT), (SHOULDER_LEFT, SHOULDER_RIGHT)):
        line = pose64[a] - pose64[b]
        line = line - up * float(line @ up)
        if float(line @ line) > 1e-6:
            left = line
            break
    if left is None:
        line = quat_rotate(root_frame, np.array([1.0, 0.0, 0.0]))
        left = line - up * float(line @ up)
    left = left / np.linalg.norm(left)
    frame = np.stack([left, up, cross_product(left, up)], axis=1)  # columns: rest X, Y, Z
    world = np.empty((NUM_BONES, 4))
    world[0] = quat_mul(matrix_to_quat(frame), root_arc)
    for level in LEVELS:  # at most 5 groups, vectorised within each
        parent = world[PARENT_BONE[level]]
        in_parent = quat_rotate(quat_conj(parent), directions[level])
        local = shortest_arc(rest_directions[level], in_parent)
        world[level] = quat_mul(parent, local)
    return world, directions


def body_goals(
    root: np.ndarray, world: np.ndarray, rest_vectors: np.ndarray, capsule_frames: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Centre-of-mass positions and body orientations of the capsules for a root position
    ``(..., 3)`` and bone frames ``(..., 19, 4)``."""
    vectors = quat_rotate(world, rest_vectors)
    joints = root[..., None, :] + PATH @ vectors
    centres = joints[..., STARTS, :] + 0.5 * vectors
    return centres, quat_mul(world, capsule_frames)


def pose_from(
    centres: np.ndarray,
    orientations: np.ndarray,
    capsule_frames: np.ndarray,
    rest_vectors: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics of the capsules: joints ``(20, 3)`` and bone vectors ``(19, 3)``."""
    frames = quat_mul(orientations, quat_conj(capsule_frames))
    vectors = quat_rotate(frames, rest_vectors)
    root = centres[0] - 0.5 * vectors[0]
    return root + PATH @ vectors, vectors


def pose_and_gap(
    centres: np.ndarray,
    orientations: np.ndarray,
    capsule_frames: np.ndarray,
    rest_vectors: np.ndarray,
) -> tuple[np.ndarray, float]:
    """The joints ``(20, 3)`` of :func:`pose_from` and the joint gap (m): how far a capsule's
    start end lies, at most, from the joint it should share with its parent."""
    joints, vectors = pose_from(centres, orientations, capsule_frames, rest_vectors)
    # How far each capsule's start end is from the joint it should share with its parent.
    gaps = centres - 0.5 * vectors - joints[STARTS]
    return joints, float(np.sqrt(np.max(np.sum(gaps * gaps, axis=-1))))


def substep_goals(
    root0: np.ndarray,
    world0: np.ndarray,
    root1: np.ndarray,
    world1: np.ndarray,
    n: int,
    rest_vectors: np.ndarray,
    capsule_frames: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The capsules' goals ``(n, 19, 3)``, ``(n, 19, 4)`` at each of a frame's ``n`` physics
    steps: the root moves linearly and each bone frame by normalised quaternion interpolation,
    the short way round, from ``(root0, world0)`` to ``(root1, world1)``; and ``world1`` with
    each quaternion's sign on the side of ``world0``'s."""
    fractions = (np.arange(1, n + 1) / n)[:, None]
    sign = np.where(np.sum(world0 * world1, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    world1 = sign * world1
    blend = (1 - fractions[:, :, None]) * world0 + fractions[:, :, None] * world1
    blend /= np.sqrt(np.sum(blend * blend, axis=-1, keepdims=True))
    roots = root0 + fractions * (root1 - root0)
    centres, orientations = body_goals(roots, blend, rest_vectors, capsule_frames)
    return centres, orientations, world1


def joint_velocities(
    joints: np.ndarray, centres: np.ndarray, linear: np.ndarray, angular: np.ndarray
) -> np.ndarray:
    """Joint velocities ``(20, 3)`` (m/s) of capsules at ``centres`` moving at ``linear`` (m/s)
    and ``angular`` (rad/s) velocities: each joint moves with the capsule that ends there (the
    root with the HipCenter–Spine capsule)."""
    out = np.empty((skeleton.NUM_JOINTS, 3))
    out[skeleton.BONES[:, 1]] = linear + cross_product(
        angular, joints[skeleton.BONES[:, 1]] - centres
    )
    out[skeleton.ROOT] = linear[0] + cross_product(angular[0], joints[skeleton.ROOT] - centres[0])
    return out
