"""Small vectorised rotation helpers (matrices act on column vectors).

Quaternions are in (w, x, y, z) order for the mocap readers (:func:`quaternion_to_matrix`) and
in pybullet's (x, y, z, w) order for the simulator and the ragdoll (:func:`shortest_arc`,
:func:`matrix_to_quaternion_xyzw`); :func:`slerp` takes either.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.floating]

_AXES = {"X": 0, "Y": 1, "Z": 2}


def axis_rotation(axis: str, angle: FloatArray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` about the principal ``axis`` ("X", "Y" or "Z") by
    ``angle`` radians (right-handed)."""
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros((*angle.shape, 3, 3))
    i = _AXES[axis.upper()]
    j, k = (i + 1) % 3, (i + 2) % 3
    out[..., i, i] = 1.0
    out[..., j, j] = c
    out[..., k, k] = c
    out[..., j, k] = -s
    out[..., k, j] = s
    return out


def euler_to_matrix(angles_deg: FloatArray, order: str) -> np.ndarray:
    """Intrinsic Euler angles in degrees, as BVH writes them, to matrices ``(..., 3, 3)``.

    ``order`` names the axes in channel order, e.g. ``"ZXY"``: the matrix is
    ``R_Z(a0) @ R_X(a1) @ R_Y(a2)``.
    """
    angles = np.radians(np.asarray(angles_deg, dtype=np.float64))
    if angles.shape[-1] != len(order):
        raise ValueError(f"expected {len(order)} angles for order {order!r}, got {angles.shape}")
    result = axis_rotation(order[0], angles[..., 0])
    for position, axis in enumerate(order[1:], start=1):
        result = result @ axis_rotation(axis, angles[..., position])
    return result


def quaternion_to_matrix(quaternion_wxyz: FloatArray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` in (w, x, y, z) order to matrices ``(..., 3, 3)``.

    The quaternions are normalised first.
    """
    q = np.asarray(quaternion_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def slerp(q0: FloatArray, q1: FloatArray, fraction: FloatArray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions ``(..., 4)`` (any component order).

    ``fraction`` broadcasts against the leading axes; the shorter arc is taken.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    t = np.asarray(fraction, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-6
    safe = np.where(small, 1.0, sin_theta)
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(small, t, np.sin(t * theta) / safe)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def axis_angle_matrix(axes: FloatArray, angles: FloatArray) -> np.ndarray:
    """Rodrigues: rotation matrices ``(..., 3, 3)`` about unit ``axes`` ``(..., 3)`` by
    ``angles`` ``(...)`` radians (right-handed)."""
    axes = np.asarray(axes, dtype=np.float64)
    x, y, z = axes[..., 0], axes[..., 1], axes[..., 2]
    zero = np.zeros_like(x)
    cross = np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2
    )
    c, s = np.cos(angles)[..., None, None], np.sin(angles)[..., None, None]
    return c * np.eye(3) + s * cross + (1.0 - c) * axes[..., :, None] * axes[..., None, :]


def cross_product(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``u x v`` over the last axis (broadcasting)."""

    # Component by component: cheaper than np.cross on the small arrays used every frame.
    out = np.empty(np.broadcast_shapes(u.shape, v.shape))
    out[..., 0] = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    out[..., 1] = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    out[..., 2] = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    return out


def shortest_arc(a: FloatArray, b: FloatArray) -> np.ndarray:
    """Unit quaternions (x, y, z, w) turning unit vectors ``a`` onto unit vectors ``b``
    (``(..., 3)``, broadcast) by the smallest angle.

    When ``a`` and ``b`` are opposite, a half turn about an axis perpendicular to ``a``.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    q = np.empty((*np.broadcast_shapes(a.shape[:-1], b.shape[:-1]), 4))
    q[..., :3] = cross_product(a, b)
    q[..., 3] = 1.0 + np.sum(a * b, axis=-1)
    norm = np.sqrt(np.sum(q * q, axis=-1, keepdims=True))
    opposite = norm[..., 0] < 1e-6
    if np.any(opposite):
        helper = np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        axis = cross_product(a, helper)
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        flip = np.concatenate([axis, np.zeros((*axis.shape[:-1], 1))], axis=-1)
        q = np.where(opposite[..., None], flip, q)
        norm = np.where(opposite[..., None], 1.0, norm)
    return q / norm


def matrix_to_quaternion_xyzw(matrices: FloatArray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` to unit quaternions ``(..., 4)`` in (x, y, z, w) order.

    Shepperd's method, vectorised: each matrix uses whichever of the four classic formulas is
    best conditioned for it (the largest of the trace and the diagonal entries). ``q`` and
    ``-q`` are the same rotation; the sign is that of the chosen formula.
    """
    m = np.asarray(matrices, dtype=np.float64)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    candidates = np.stack(
        [
            np.stack(
                [
                    m[..., 2, 1] - m[..., 1, 2],
                    m[..., 0, 2] - m[..., 2, 0],
                    m[..., 1, 0] - m[..., 0, 1],
                    1.0 + trace,
                ],
                -1,
            ),
            np.stack(
                [
                    1.0 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2],
                    m[..., 0, 1] + m[..., 1, 0],
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 2, 1] - m[..., 1, 2],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 1] + m[..., 1, 0],
                    1.0 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2],
                    m[..., 1, 2] + m[..., 2, 1],
                    m[..., 0, 2] - m[..., 2, 0],
                ],
                -1,
            ),
            np.stack(
                [
                    m[..., 0, 2] + m[..., 2, 0],
                    m[..., 1, 2] + m[..., 2, 1],
                    1.0 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2],
                    m[..., 1, 0] - m[..., 0, 1],
                ],
                -1,
            ),
        ],
        axis=-2,
    )  # (..., 4, 4): the four formulas, each well conditioned in its own region
    diagonal = np.stack([trace, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], -1)
    best = np.argmax(diagonal, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
