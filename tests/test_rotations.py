"""Batched rotation helpers of :mod:`fpg_gym.core.rotations` (x, y, z, w quaternions)."""

from __future__ import annotations

import numpy as np

from fpg_gym.core.rotations import (
    axis_angle_matrix,
    axis_rotation,
    matrix_to_quaternion_xyzw,
    quaternion_to_matrix,
    shortest_arc,
)


def _rotate(q_xyzw: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...ab,...b->...a", quaternion_to_matrix(q_xyzw[..., [3, 0, 1, 2]]), v)


def _unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    v = rng.normal(size=(*shape, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_shortest_arc_turns_a_onto_b_even_when_opposite() -> None:
    rng = np.random.default_rng(0)
    a, b = _unit(rng, (50,)), _unit(rng, (50,))
    b[:3] = -a[:3]
    q = shortest_arc(a, b)
    assert q.shape == (50, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0)
    np.testing.assert_allclose(_rotate(q, a), b, atol=1e-12)
    # From +Z (a capsule's axis), broadcast over the targets.
    np.testing.assert_allclose(_rotate(shortest_arc(np.array([0.0, 0.0, 1.0]), b), [0, 0, 1]), b)


def test_matrix_to_quaternion_round_trip() -> None:
    rng = np.random.default_rng(1)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    matrices = quaternion_to_matrix(q[:, [3, 0, 1, 2]])
    back = matrix_to_quaternion_xyzw(matrices)
    assert back.shape == (200, 4)
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=-1)), 1.0)  # q or -q
    assert matrix_to_quaternion_xyzw(np.eye(3)).tolist() == [0.0, 0.0, 0.0, 1.0]


def test_axis_angle_matches_principal_axes() -> None:
    angles = np.linspace(-3.0, 3.0, 7)
    for axis, name in ((0, "X"), (1, "Y"), (2, "Z")):
        unit = np.zeros((7, 3))
        unit[:, axis] = 1.0
        np.testing.assert_allclose(
            axis_angle_matrix(unit, angles), axis_rotation(name, angles), atol=1e-15
        )
