"""Energy terms (Shum Eq. 10-15): the latent fast path against direct per-sample computation."""

from __future__ import annotations

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.reconstruct.energy import (
    POSE_TERM_NAMES,
    TERM_NAMES,
    EnergyModel,
    EnergyWeights,
    motion_target,
    pose_energy_terms,
)
from fpg_gym.reconstruct.latent import LatentSpace


def setup(rng: np.random.Generator, k: int = 30, max_dim: int = 20):
    base = poses.rest_pose().astype(np.float64)
    neighbours = base[None] + rng.normal(0.0, 0.05, (k, skeleton.NUM_JOINTS, 3))
    sensor = base + rng.normal(0.0, 0.05, (skeleton.NUM_JOINTS, 3))
    reliability = rng.uniform(0, 1, skeleton.NUM_JOINTS)
    lengths = poses.DEFAULT_BONE_LENGTHS * 1.05
    target = base + rng.normal(0.0, 0.02, (skeleton.NUM_JOINTS, 3))
    latent = LatentSpace.fit(neighbours, max_dim=max_dim)
    return latent, sensor, reliability, neighbours, lengths, target


def per_sample(pose, sensor, reliability, neighbours, lengths, target):
    """Each term for one pose, written out joint by joint (the equations as printed)."""
    j_count = skeleton.NUM_JOINTS
    ec = sum(reliability[j] * np.sum((pose[j] - sensor[j]) ** 2) for j in range(j_count))
    es = min(np.mean([np.sum((pose[j] - n[j]) ** 2) for j in range(j_count)]) for n in neighbours)
    ek = np.mean(
        [
            (np.linalg.norm(pose[c] - pose[p]) - lengths[b]) ** 2
            for b, (p, c) in enumerate(skeleton.BONES)
        ]
    )
    em = (
        0.0
        if target is None
        else np.mean([np.sum((pose[j] - target[j]) ** 2) for j in range(j_count)])
    )
    return {"Ec": ec, "Es": es, "Ek": ek, "Em": em}


@pytest.mark.parametrize("max_dim", [20, 8])  # 8: neighbours have residuals outside the space
def test_latent_terms_equal_direct_per_sample_terms(rng: np.random.Generator, max_dim: int) -> None:
    latent, sensor, r, neighbours, lengths, target = setup(rng, max_dim=max_dim)
    model = EnergyModel(latent, sensor, r, neighbours, lengths, target)
    z = rng.normal(0, 1.5, (25, latent.dim))
    z[0] = latent.encode(neighbours[3])  # exactly a neighbour (Es = its residual only)
    fast = model.terms(z)
    decoded = latent.decode(z)
    direct = pose_energy_terms(
        decoded, sensor=sensor, reliability=r, neighbours=neighbours, lengths=lengths, target=target
    )
    for i in range(len(z)):
        naive = per_sample(decoded[i], sensor, r, neighbours, lengths, target)
        for name in POSE_TERM_NAMES:
            assert fast[name][i] == pytest.approx(naive[name], rel=1e-7, abs=1e-10), name
            assert direct[name][i] == pytest.approx(naive[name], rel=1e-7, abs=1e-10), name
    w = EnergyWeights()
    total = (
        w.control * fast["Ec"]
        + w.style * fast["Es"]
        + w.kinematic * fast["Ek"]
        + w.motion * fast["Em"]
    )
    assert np.allclose(model(z), total)


def test_default_weights_and_no_motion_term_without_history(rng: np.random.Generator) -> None:
    assert EnergyWeights().as_array().tolist() == [1.0, 0.5, 1.5, 0.25, 0.0]
    latent, sensor, r, neighbours, lengths, _ = setup(rng)
    model = EnergyModel(latent, sensor, r, neighbours, lengths, None, EnergyWeights(style=2.0))
    z = rng.normal(size=(4, latent.dim))
    terms = model.terms(z)
    assert np.all(terms["Em"] == 0.0)
    assert np.allclose(model(z), terms["Ec"] + 2.0 * terms["Es"] + 1.5 * terms["Ek"])
    with pytest.raises(ValueError, match="style"):
        EnergyWeights(style=-1.0)


def test_motion_target_is_the_second_difference_at_a_constant_rate(
    rng: np.random.Generator,
) -> None:
    p1, p0 = rng.normal(size=(2, 20, 3))
    assert np.allclose(motion_target(p1, p0, 1 / 30, 1 / 30), 2 * p1 - p0)
    assert np.allclose(motion_target(p1, p0, 2 / 30, 1 / 30), p1 + 2 * (p1 - p0))
    assert np.allclose(motion_target(p1, None, 1 / 30), p1)


def test_float32_arithmetic_agrees_with_float64(rng: np.random.Generator) -> None:
    latent, sensor, r, neighbours, lengths, target = setup(rng)
    exact = EnergyModel(latent, sensor, r, neighbours, lengths, target)
    fast = EnergyModel(latent, sensor, r, neighbours, lengths, target, dtype=np.float32)
    z = rng.normal(0, 1.0, (50, latent.dim))
    a, b = exact.terms(z), fast.terms(z)
    for name in TERM_NAMES:
        assert b[name].dtype == np.float64
        assert np.allclose(a[name], b[name], rtol=2e-3, atol=1e-6), name
    assert np.array_equal(np.argsort(exact(z))[:5], np.argsort(fast(z))[:5])
    with pytest.raises(ValueError, match="dtype"):
        EnergyModel(latent, sensor, r, neighbours, lengths, target, dtype=np.int32)


def test_latent_prior_term(rng: np.random.Generator) -> None:
    """Ep = mean of the squared whitened coordinates; weight 0 (the papers) leaves E unchanged."""
    latent, sensor, r, neighbours, lengths, target = setup(rng)
    z = rng.normal(0, 1.0, (6, latent.dim))
    plain = EnergyModel(latent, sensor, r, neighbours, lengths, target)
    terms = plain.terms(z)
    np.testing.assert_allclose(terms["Ep"], (z**2).mean(axis=1))
    weights = EnergyWeights.with_prior(0.2)
    assert weights.prior == 0.2 and weights.control == EnergyWeights().control
    with_prior = EnergyModel(latent, sensor, r, neighbours, lengths, target, weights)
    np.testing.assert_allclose(with_prior(z), plain(z) + 0.2 * terms["Ep"])
    with pytest.raises(ValueError, match="prior"):
        EnergyWeights(prior=-0.1)


def test_paper_terms_are_the_papers_weights() -> None:
    assert EnergyWeights().paper_terms() == (1.0, 0.5, 1.5, 0.25)
    assert EnergyWeights.with_prior().paper_terms() == (1.0, 0.5, 1.5, 0.25)
    assert EnergyWeights(style=2.0).paper_terms() == (1.0, 2.0, 1.5, 0.25)
