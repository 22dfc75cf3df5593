"""Natural posture space: whitened local PCA of the K candidates."""

from __future__ import annotations

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.reconstruct.latent import LatentSpace, principal_axes


def candidates(rng: np.random.Generator, k: int) -> np.ndarray:
    base = poses.rest_pose()
    return base[None] + rng.normal(0.0, 0.05, (k, skeleton.NUM_JOINTS, 3)).astype(np.float32)


def test_round_trip_of_the_fitted_poses_is_exact_at_full_rank(rng: np.random.Generator) -> None:
    k = 12
    data = candidates(rng, k)
    space = LatentSpace.fit(data, max_dim=20)
    assert space.dim == k - 1
    z = space.encode(data)
    assert z.shape == (k, k - 1)
    assert np.allclose(space.decode(z), data, atol=1e-5)
    assert space.explained_variance_ratio == pytest.approx(1.0)


def test_whitened_orthonormal_and_sorted(rng: np.random.Generator) -> None:
    data = candidates(rng, 30)
    space = LatentSpace.fit(data)
    assert space.dim == 20
    assert np.allclose(space.basis @ space.basis.T, np.eye(20), atol=1e-10)
    z = space.encode(data)
    assert np.allclose(z.mean(axis=0), 0.0, atol=1e-9)
    assert np.allclose(z.std(axis=0, ddof=1), 1.0, atol=1e-9)  # unit variance per axis
    assert np.all(np.diff(space.std) <= 0)
    assert 0.0 < space.explained_variance_ratio < 1.0
    # Batched decode over leading axes; projection is idempotent.
    zz = np.random.default_rng(1).normal(size=(3, 4, 20))
    assert space.decode(zz).shape == (3, 4, 20, 3)
    once = space.project(data)
    assert np.allclose(space.project(once), once, atol=1e-9)


def test_fit_is_deterministic_and_sign_fixed(rng: np.random.Generator) -> None:
    data = candidates(rng, 15)
    a, b = LatentSpace.fit(data), LatentSpace.fit(data.copy())
    assert np.array_equal(a.basis, b.basis)
    picks = np.argmax(np.abs(a.basis), axis=1)
    assert np.all(a.basis[np.arange(a.dim), picks] > 0)


def test_degenerate_spreads_stay_finite_and_inert() -> None:
    pose = poses.rest_pose()
    data = np.stack([pose] * 5 + [pose + 0.01])  # rank 1 after centring
    space = LatentSpace.fit(data, max_dim=20, min_std=1e-6)
    assert space.dim == 5
    assert space.degenerate.tolist() == [False, True, True, True, True]
    assert np.all(space.std >= 1e-6)
    z = np.zeros((1, 5))
    z[0, 1:] = 100.0  # far along the degenerate axes
    moved = space.decode(z)[0] - space.decode(np.zeros((1, 5)))[0]
    assert np.abs(moved).max() < 1e-3
    assert np.all(np.isfinite(space.encode(data)))
    one = LatentSpace.fit(pose[None])
    assert one.dim == 0 and one.decode(np.zeros(0)).shape == (20, 3)
    assert np.allclose(one.decode(np.zeros(0)), pose)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="poses"):
        LatentSpace.fit(np.zeros((3, 19, 3)))
    with pytest.raises(ValueError, match="max_dim"):
        LatentSpace.fit(np.zeros((3, 20, 3)), max_dim=-1)
    space = LatentSpace.fit(np.random.default_rng(0).normal(size=(5, 20, 3)))
    with pytest.raises(ValueError, match="z"):
        space.decode(np.zeros((2, 3)))


@pytest.mark.parametrize("k", [5, 30, 60, 90])
def test_principal_axes_agree_with_the_svd(rng: np.random.Generator, k: int) -> None:
    data = candidates(rng, k).reshape(k, -1).astype(np.float64)
    centred = data - data.mean(axis=0)
    dim = min(20, k - 1)
    singular, basis = principal_axes(centred, dim)
    _, expected, vt = np.linalg.svd(centred, full_matrices=False)
    np.testing.assert_allclose(singular[:dim], expected[:dim], rtol=1e-10)
    signs = np.sign(np.einsum("dc,dc->d", basis, vt[:dim]))
    np.testing.assert_allclose(basis * signs[:, None], vt[:dim], atol=1e-10)
    np.testing.assert_allclose(basis @ basis.T, np.eye(dim), atol=1e-10)


def test_principal_axes_of_duplicates_are_the_svds() -> None:
    pose = poses.rest_pose().reshape(-1).astype(np.float64)
    data = np.stack([pose] * 8 + [pose + 0.01, pose - 0.02])  # rank 1 after centring
    centred = data - data.mean(axis=0)
    singular, basis = principal_axes(centred, 5)  # s_5 = 0: the Gram axes would be noise
    _, expected, vt = np.linalg.svd(centred, full_matrices=False)
    np.testing.assert_array_equal(singular, expected)
    np.testing.assert_array_equal(basis, vt[:5])


@pytest.mark.parametrize("k", [5, 30, 60])
def test_fit_is_the_svd_of_the_centred_candidates(rng: np.random.Generator, k: int) -> None:
    """The whitened space against its definition, the SVD of the centred candidates: the
    compiled axes with numba, the numpy ones without (CI runs this file both ways)."""
    data = candidates(rng, k)
    space = LatentSpace.fit(data)
    flat = data.reshape(k, -1).astype(np.float64)
    mean = flat.mean(axis=0)
    np.testing.assert_array_equal(space.mean, mean)
    _, singular, vt = np.linalg.svd(flat - mean, full_matrices=False)
    dim = min(20, k - 1)
    expected = vt[:dim] * np.sign(vt[np.arange(dim), np.argmax(np.abs(vt[:dim]), axis=1)])[:, None]
    np.testing.assert_allclose(space.basis, expected, atol=1e-9)
    np.testing.assert_allclose(space.std, singular[:dim] / np.sqrt(k - 1), rtol=1e-10)
    ratio = np.sum(singular[:dim] ** 2) / np.sum(singular**2)
    assert space.explained_variance_ratio == pytest.approx(ratio, rel=1e-12)
