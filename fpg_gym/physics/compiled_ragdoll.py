"""The ragdoll's per-frame arithmetic compiled (numba); imported only with ``fpg-gym[fast]``.

:class:`~fpg_gym.physics.ragdoll.Ragdoll` spends a frame in pybullet (the physics steps and one
constraint update per body part and step) and in some two hundred numpy calls on ``(19, 4)``
quaternions around it: the target's bone frames, their interpolation over the physics steps,
the capsules' goals and the forward kinematics of the simulated capsules. Each of those is one
call here, with the same formulas in the same order as the numpy code it stands for
(:mod:`fpg_gym.physics.ragdoll_kinematics`: ``bone_frames``, ``substep_goals``, ``pose_and_gap``;
:mod:`fpg_gym.physics.ragdoll_guards`: the measures of ``divergence``); the results agree to
rounding (a joint is its parent joint plus its bone vector here, a product with ``PATH_MATRIX``
there). The tests compare both paths.

Quaternions are (x, y, z, w). Module-level functions so that numba's disk cache
(``cache=True``) finds them in a new process.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from fpg_gym.core.compiled import JIT_OPTIONS

__all__ = ["bone_frames", "divergence_measures", "pose_from", "substep_goals"]


@numba.njit(**JIT_OPTIONS)
def _mul(a, b):
    """Quaternion product ``a b`` of two 4-tuples (``ragdoll_kinematics.quat_mul``)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


@numba.njit(**JIT_OPTIONS)
def _cross(u, v):
    return (
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    )


@numba.njit(**JIT_OPTIONS)
def _rotate(q, v):
    """``v`` rotated by the unit quaternion ``q`` (``ragdoll_kinematics.quat_rotate``)."""
    u = (q[0], q[1], q[2])
    c = _cross(u, v)
    t = (2.0 * c[0], 2.0 * c[1], 2.0 * c[2])
    d = _cross(u, t)
    return (v[0] + q[3] * t[0] + d[0], v[1] + q[3] * t[1] + d[1], v[2] + q[3] * t[2] + d[2])


@numba.njit(**JIT_OPTIONS)
def _arc(a, b):
    """Shortest-arc quaternion turning unit ``a`` onto unit ``b``
    (:func:`fpg_gym.core.rotations.shortest_arc`)."""
    c = _cross(a, b)
    w = 1.0 + (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
    norm = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] + w * w)
    if norm < 1e-6:  # opposite: a half turn about an axis perpendicular to a
        helper = (1.0, 0.0, 0.0) if abs(a[0]) < 0.9 else (0.0, 1.0, 0.0)
        axis = _cross(a, helper)
        length = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
        return (axis[0] / length, axis[1] / length, axis[2] / length, 0.0)
    return (c[0] / norm, c[1] / norm, c[2] / norm, w / norm)


@numba.njit(**JIT_OPTIONS)
def _matrix_quat(m):
    """A rotation matrix ``(3, 3)`` to a unit quaternion (``ragdoll_kinematics.matrix_to_quat``)."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    q = np.empty(4)
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q[0] = (m[2, 1] - m[1, 2]) / s
        q[1] = (m[0, 2] - m[2, 0]) / s
        q[2] = (m[1, 0] - m[0, 1]) / s
        q[3] = s / 4
    else:
        i = 0
        if m[1, 1] > m[i, i]:
            i = 1
        if m[2, 2] > m[i, i]:
            i = 2
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-12))
        q[3] = (m[k, j] - m[j, k]) / s
        q[i] = s / 4
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
    return q / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


@numba.njit(**JIT_OPTIONS)
def bone_frames(pose, directions, root_frame, rest_directions, root_arc, bones, parent_bone, lines):
    """The target's bone frames (``ragdoll_kinematics.bone_frames``).

    Parameters
    ----------
    pose : ndarray (20, 3) float64
    directions : ndarray (19, 3)
        The previous frame's unit bone directions (kept for a bone shorter than 1e-6 m).
    root_frame : ndarray (4,)
        The previous root frame (its X axis when neither the hips nor the shoulders give one).
    rest_directions : ndarray (19, 3)
    root_arc : ndarray (4,)
        ``shortest_arc((0, 1, 0), rest_directions[0])``.
    bones : ndarray (19, 2) int
        (start, end) joints; ``parent_bone`` the parent of each bone (parents first, -1 for 0).
    lines : ndarray (2, 2) int
        The hips' and the shoulders' (left, right) joints.

    Returns
    -------
    world : ndarray (19, 4)
        World orientations of the bones relative to the rest pose.
    new_directions : ndarray (19, 3)
    """
    nb = bones.shape[0]
    new_directions = np.empty((nb, 3))
    for b in range(nb):
        s, e = bones[b, 0], bones[b, 1]
        vx, vy, vz = pose[e, 0] - pose[s, 0], pose[e, 1] - pose[s, 1], pose[e, 2] - pose[s, 2]
        norm = math.sqrt(vx * vx + vy * vy + vz * vz)
        if norm > 1e-6:
            new_directions[b, 0], new_directions[b, 1], new_directions[b, 2] = (
                vx / norm,
                vy / norm,
                vz / norm,
            )
        else:
            for c in range(3):
                new_directions[b, c] = directions[b, c]
    up = (new_directions[0, 0], new_directions[0, 1], new_directions[0, 2])
    found = False
    left = (0.0, 0.0, 0.0)
    for line in range(lines.shape[0]):
        a, c = lines[line, 0], lines[line, 1]
        lx, ly, lz = pose[a, 0] - pose[c, 0], pose[a, 1] - pose[c, 1], pose[a, 2] - pose[c, 2]
        along = lx * up[0] + ly * up[1] + lz * up[2]
        lx, ly, lz = lx - up[0] * along, ly - up[1] * along, lz - up[2] * along
        if lx * lx + ly * ly + lz * lz > 1e-6:
            left = (lx, ly, lz)
            found = True
            break
    if not found:
        x = _rotate((root_frame[0], root_frame[1], root_frame[2], root_frame[3]), (1.0, 0.0, 0.0))
        along = x[0] * up[0] + x[1] * up[1] + x[2] * up[2]
        left = (x[0] - up[0] * along, x[1] - up[1] * along, x[2] - up[2] * along)
    length = math.sqrt(left[0] * left[0] + left[1] * left[1] + left[2] * left[2])
    left = (left[0] / length, left[1] / length, left[2] / length)
    forward = _cross(left, up)
    frame = np.empty((3, 3))  # columns: rest X, Y, Z
    for r in range(3):
        frame[r, 0], frame[r, 1], frame[r, 2] = left[r], up[r], forward[r]
    q = _matrix_quat(frame)
    world = np.empty((nb, 4))
    w0 = _mul((q[0], q[1], q[2], q[3]), (root_arc[0], root_arc[1], root_arc[2], root_arc[3]))
    world[0, 0], world[0, 1], world[0, 2], world[0, 3] = w0
    for b in range(1, nb):
        p = parent_bone[b]
        parent = (world[p, 0], world[p, 1], world[p, 2], world[p, 3])
        conj = (-parent[0], -parent[1], -parent[2], parent[3])
        direction = (new_directions[b, 0], new_directions[b, 1], new_directions[b, 2])
        in_parent = _rotate(conj, direction)
        rest = (rest_directions[b, 0], rest_directions[b, 1], rest_directions[b, 2])
        world[b, 0], world[b, 1], world[b, 2], world[b, 3] = _mul(parent, _arc(rest, in_parent))
    return world, new_directions


@numba.njit(**JIT_OPTIONS)
def substep_goals(root0, world0, root1, world1, substeps, rest_vectors, capsule_frames, bones):
    """The capsules' goals at each physics step of a frame (``ragdoll_kinematics.substep_goals``):
    the root moves linearly and each bone frame by normalised quaternion
    interpolation, the short way round, from ``(root0, world0)`` to ``(root1, world1)``.

    Returns
    -------
    centres : ndarray (substeps, 19, 3)
    orientations : ndarray (substeps, 19, 4)
    world1 : ndarray (19, 4)
        ``world1`` with each quaternion's sign on the side of ``world0``'s.
    """
    nb = bones.shape[0]
    signed = world1.copy()
    for b in range(nb):
        dot = 0.0
        for c in range(4):
            dot += world0[b, c] * world1[b, c]
        if dot < 0:
            for c in range(4):
                signed[b, c] = -world1[b, c]
    centres = np.empty((substeps, nb, 3))
    orientations = np.empty((substeps, nb, 4))
    joints = np.empty((nb + 1, 3))
    for k in range(substeps):
        f = (k + 1) / substeps
        for c in range(3):
            joints[0, c] = root0[c] + f * (root1[c] - root0[c])
        for b in range(nb):
            x = (1 - f) * world0[b, 0] + f * signed[b, 0]
            y = (1 - f) * world0[b, 1] + f * signed[b, 1]
            z = (1 - f) * world0[b, 2] + f * signed[b, 2]
            w = (1 - f) * world0[b, 3] + f * signed[b, 3]
            norm = math.sqrt(x * x + y * y + z * z + w * w)
            q = (x / norm, y / norm, z / norm, w / norm)
            v = _rotate(q, (rest_vectors[b, 0], rest_vectors[b, 1], rest_vectors[b, 2]))
            s, e = bones[b, 0], bones[b, 1]
            for c in range(3):
                joints[e, c] = joints[s, c] + v[c]
                centres[k, b, c] = joints[s, c] + 0.5 * v[c]
            frame = (capsule_frames[b, 0], capsule_frames[b, 1], capsule_frames[b, 2])
            o = _mul(q, (frame[0], frame[1], frame[2], capsule_frames[b, 3]))
            orientations[k, b, 0], orientations[k, b, 1] = o[0], o[1]
            orientations[k, b, 2], orientations[k, b, 3] = o[2], o[3]
    return centres, orientations, signed


@numba.njit(**JIT_OPTIONS)
def pose_from(centres, orientations, capsule_frames, rest_vectors, bones):
    """Forward kinematics of the simulated capsules (``ragdoll_kinematics.pose_and_gap``).

    Returns
    -------
    joints : ndarray (20, 3) float64
        The root (the start of capsule 0) plus each capsule's axis times its bone length.
    gap : float
        The largest distance between a capsule's start and the joint it shares with its parent.
    """
    nb = bones.shape[0]
    vectors = np.empty((nb, 3))
    for b in range(nb):
        f = capsule_frames[b]
        frame = _mul(
            (orientations[b, 0], orientations[b, 1], orientations[b, 2], orientations[b, 3]),
            (-f[0], -f[1], -f[2], f[3]),
        )
        v = _rotate(frame, (rest_vectors[b, 0], rest_vectors[b, 1], rest_vectors[b, 2]))
        vectors[b, 0], vectors[b, 1], vectors[b, 2] = v
    joints = np.empty((nb + 1, 3))
    for c in range(3):
        joints[0, c] = centres[0, c] - 0.5 * vectors[0, c]
    gap2 = 0.0
    for b in range(nb):
        s, e = bones[b, 0], bones[b, 1]
        d2 = 0.0
        for c in range(3):
            joints[e, c] = joints[s, c] + vectors[b, c]
            d = centres[b, c] - 0.5 * vectors[b, c] - joints[s, c]
            d2 += d * d
        if d2 > gap2 or d2 != d2:  # a NaN stays, as in numpy's max
            gap2 = d2
    return joints, math.sqrt(gap2)


@numba.njit(**JIT_OPTIONS)
def divergence_measures(output, target, offset, previous):
    """What ``Ragdoll._divergence`` checks of an output ``(20, 3)`` float32: whether it is
    finite, the largest distance of a joint from ``target + offset`` and from ``previous``
    (equal to numpy's to rounding)."""
    finite = True
    distance = 0.0
    moved = 0.0
    for j in range(output.shape[0]):
        d2 = 0.0
        m2 = 0.0
        for c in range(3):
            if not math.isfinite(output[j, c]):
                finite = False
            d = output[j, c] - (target[j, c] + offset[c])
            m = output[j, c] - previous[j, c]
            d2 += d * d
            m2 += m * m
        distance = max(distance, math.sqrt(d2))
        moved = max(moved, math.sqrt(m2))
    return finite, distance, moved
