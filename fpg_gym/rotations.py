"""Small vectorised rotation helpers used by the mocap readers (matrices act on column vectors)."""

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
