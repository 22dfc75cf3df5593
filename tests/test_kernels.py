"""The energy's kernels (fused, compiled and numpy; the compiled terms) against its one definition:
the terms of :mod:`fpg_gym.reconstruct.energy` (Shum Eq. 11-14) on the decoded poses. CI runs
these tests with numba and again without it (``FPG_GYM_NO_NUMBA=1``)."""

from __future__ import annotations

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.core.compiled import COMPILED_MODULES, compiled_module, numba_available
from fpg_gym.reconstruct.energy import (
    TERM_NAMES,
    EnergyModel,
    EnergyWeights,
    pose_energy_terms,
)
from fpg_gym.reconstruct.kernels import (
    available_kernels,
    fused_energy,
    numpy_energy,
    resolve_kernel,
)
from fpg_gym.reconstruct.latent import LatentSpace

KERNELS = available_kernels()


def random_frame(rng: np.random.Generator, k: int, max_dim: int, motion: bool, spread: float):
    """A random frame: K noisy candidates around a random pose, a noisy sensor and target."""
    base = poses.rest_pose().astype(np.float64) + rng.normal(0.0, 0.1, (skeleton.NUM_JOINTS, 3))
    neighbours = base[None] + rng.normal(0.0, spread, (k, skeleton.NUM_JOINTS, 3))
    sensor = base + rng.normal(0.0, 0.08, (skeleton.NUM_JOINTS, 3))
    reliability = rng.uniform(0, 1, skeleton.NUM_JOINTS)
    reliability[rng.uniform(size=skeleton.NUM_JOINTS) < 0.2] = 0.0
    lengths = poses.DEFAULT_BONE_LENGTHS * rng.uniform(0.9, 1.1)
    target = base + rng.normal(0.0, 0.02, (skeleton.NUM_JOINTS, 3)) if motion else None
    latent = LatentSpace.fit(neighbours, max_dim=max_dim)
    return latent, sensor, reliability, neighbours, lengths, target


def definition(frame, weights: EnergyWeights, z: np.ndarray) -> dict[str, np.ndarray]:
    """The terms by their definitions on the decoded poses, the prior and the total ``E``."""
    latent, sensor, reliability, neighbours, lengths, target = frame
    terms = pose_energy_terms(
        latent.decode(z),
        sensor=sensor,
        reliability=reliability,
        neighbours=neighbours,
        lengths=lengths,
        target=target,
    )
    terms["Ep"] = np.einsum("nd,nd->n", z, z) / z.shape[1]
    w = weights.as_array()
    terms["E"] = sum(w[i] * terms[name] for i, name in enumerate(TERM_NAMES))
    return terms


CASES = [
    # (K, max_dim, motion, spread, weights)
    (30, 20, True, 0.05, EnergyWeights()),
    (30, 20, False, 0.05, EnergyWeights()),
    (30, 8, True, 0.05, EnergyWeights()),  # candidates have residuals outside the space
    (5, 20, True, 0.2, EnergyWeights.with_prior(0.3)),  # d = K - 1, prior on
    (30, 20, True, 0.05, EnergyWeights(style=0.0, kinematic=3.0)),
]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("case", range(len(CASES)))
def test_fused_energy_and_terms_equal_the_definition_on_random_problems(
    kernel: str, case: int
) -> None:
    k, max_dim, motion, spread, weights = CASES[case]
    for seed in range(4):
        rng = np.random.default_rng(1000 * case + seed)
        frame = random_frame(rng, k, max_dim, motion, spread)
        model = EnergyModel(*frame, weights, kernel=kernel)
        z = rng.normal(0.0, rng.uniform(0.2, 2.0), (100, frame[0].dim))
        z[0] = frame[0].encode(frame[3][1])  # exactly a candidate: Es = its residual only
        expected = definition(frame, weights, z)
        got = model(z)
        assert got.dtype == np.float64 and got.shape == (100,)
        np.testing.assert_allclose(got, expected["E"], rtol=1e-10, atol=1e-12)
        assert int(np.argmin(got)) == int(np.argmin(expected["E"]))
        terms = model.terms(z)
        for name in TERM_NAMES:
            np.testing.assert_allclose(
                terms[name], expected[name], rtol=1e-9, atol=1e-12, err_msg=name
            )
        np.testing.assert_allclose(model.total(terms), got, rtol=1e-10, atol=1e-12)
        both = model.terms_and_total(z)  # the compiled total: total()'s sums, to the bit
        assert np.array_equal(both.pop("E"), model.total(terms))
        assert all(np.array_equal(both[name], terms[name]) for name in TERM_NAMES)


def test_kernels_agree_and_float32_is_close(rng: np.random.Generator) -> None:
    frame = random_frame(rng, 30, 20, True, 0.05)
    model = EnergyModel(*frame)
    z = rng.normal(0.0, 1.0, (257, frame[0].dim))
    results = [fused_energy(z, model.tables, kernel) for kernel in KERNELS]
    for other in results[1:]:
        np.testing.assert_allclose(other, results[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(numpy_energy(z, model.tables), results[0], rtol=1e-12)
    low = EnergyModel(*frame, dtype=np.float32)
    assert low.tables.matrix.dtype == np.float32
    np.testing.assert_allclose(low(z), model(z), rtol=2e-3, atol=1e-5)


def test_direct_kernel_is_the_definition_on_decoded_poses(rng: np.random.Generator) -> None:
    frame = random_frame(rng, 30, 20, True, 0.05)
    weights = EnergyWeights.with_prior(0.2)
    z = rng.normal(0.0, 1.0, (40, frame[0].dim))
    direct = EnergyModel(*frame, weights, kernel="direct")(z)
    np.testing.assert_allclose(direct, EnergyModel(*frame, weights)(z), rtol=1e-9, atol=1e-12)


def test_kernel_names_are_checked() -> None:
    assert resolve_kernel("numpy") == "numpy"
    assert resolve_kernel("auto") == KERNELS[0]
    with pytest.raises(ValueError, match="kernel: expected one of auto, numba, numpy"):
        resolve_kernel("fortran")


def test_tables_are_c_contiguous_and_sized(rng: np.random.Generator) -> None:
    latent, *rest = random_frame(rng, 12, 20, True, 0.05)
    tables = EnergyModel(latent, *rest).tables
    d = latent.dim
    assert tables.matrix.flags.c_contiguous
    assert tables.matrix.shape == (d, d + 1 + 12 + 3 * skeleton.NUM_BONES)
    assert tables.dim == d and tables.k == 12


def test_compiled_module_names_its_modules_and_refuses_others() -> None:
    with pytest.raises(ValueError, match="compiled_search"):
        compiled_module("os")
    loaded = [compiled_module(name) for name in COMPILED_MODULES]
    assert numba_available() == ("numba" in available_kernels())
    if numba_available():
        assert [m.__name__ for m in loaded if m is not None] == list(COMPILED_MODULES)
    else:
        assert loaded == [None] * len(COMPILED_MODULES)


@pytest.mark.skipif(not numba_available(), reason="the compiled rows need numba (fpg-gym[fast])")
@pytest.mark.parametrize("bones", [skeleton.NUM_BONES, 5])
def test_compiled_energy_rows_equal_their_source_to_the_bit(bones: int) -> None:
    """The compiled row loop (the skeleton's bone count vectorised, any other count not) gives
    what its source gives run by the interpreter, NaN and infinities included."""
    compiled = compiled_module("fpg_gym.reconstruct.compiled_kernels")
    assert compiled is not None
    rng = np.random.default_rng(7)
    d, k = 6, 4
    p = rng.normal(0.0, 1.0, (12, d + 1 + k + 3 * bones))
    p[3, -2], p[5, d + 2], p[7, -1] = np.nan, np.inf, -np.inf
    z, ycst = rng.normal(0.0, 1.0, (12, d)), rng.uniform(0.0, 1.0, k)
    b0, lengths = rng.normal(0.0, 0.3, 3 * bones), rng.uniform(0.1, 0.5, bones)
    out, expected = np.empty(12), np.empty(12)
    compiled.energy_rows(p, z, 0.25, ycst, b0, lengths, 0.1, out)
    compiled.energy_rows.py_func(p, z, 0.25, ycst, b0, lengths, 0.1, expected)
    np.testing.assert_array_equal(out, expected)


@pytest.mark.skipif(not numba_available(), reason="the compiled rows need numba (fpg-gym[fast])")
@pytest.mark.parametrize("seed", range(5))
def test_energy_rows_lowest_only_keep_the_first_lowest_row(seed: int) -> None:
    """``lowest_only`` (the compiled local search's rows) skips Ek where it cannot make the
    lowest row: the first lowest row and its energy stay the full rows' to the bit, the other
    rows never drop below an earlier full energy, and some rows are skipped."""
    compiled = compiled_module("fpg_gym.reconstruct.compiled_kernels")
    assert compiled is not None
    rng = np.random.default_rng(seed)
    n, d, k = 100, 6, 4
    p = rng.normal(0.0, 1.0, (n, d + 1 + k + 3 * skeleton.NUM_BONES))
    if seed == 0:
        p[40, 2] = np.nan  # a NaN row stays NaN (np.argmin's first NaN)
    z, ycst = rng.normal(0.0, 1.0, (n, d)), rng.uniform(0.0, 1.0, k)
    b0, lengths = rng.normal(0.0, 0.3, 3 * skeleton.NUM_BONES), rng.uniform(0.1, 0.5, 19)
    full, lowest = np.empty(n), np.empty(n)
    compiled.energy_rows(p, z, 0.25, ycst, b0, lengths, 0.1, full, False)
    compiled.energy_rows(p, z, 0.25, ycst, b0, lengths, 0.1, lowest, True)
    row = int(np.argmin(full))
    assert int(np.argmin(lowest)) == row
    assert np.array_equal(lowest[row], full[row], equal_nan=True)
    assert np.array_equal(np.isnan(lowest), np.isnan(full))
    skipped = np.flatnonzero(~np.isnan(full) & (lowest != full))
    assert 0 < len(skipped) < n
    assert np.all(lowest[skipped] <= full[skipped])
    assert np.all(lowest[skipped] > np.fmin.accumulate(full)[skipped - 1])
    finite_row = int(np.nanargmin(full))  # the lowest row besides NaN rows too
    assert int(np.nanargmin(lowest)) == finite_row and lowest[finite_row] == full[finite_row]
