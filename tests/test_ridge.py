"""The ridge regression from pooled sums (policies.ridge)."""

from __future__ import annotations

import numpy as np

from policies.ridge import fit_ridge, predict_ridge, ridge_sums


def _data(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    x = rng.normal(size=(n, 5)) * [1.0, 10.0, 0.1, 3.0, 1.0] + [0.0, 5.0, -2.0, 1.0, 0.0]
    x[:, 4] = 7.0  # a constant regressor
    y = x[:, :4] @ rng.normal(size=(4, 2)) + [3.0, -1.5] + 0.01 * rng.normal(size=(n, 2))
    return x, y


def test_without_penalty_it_is_least_squares_with_an_intercept() -> None:
    x, y = _data(np.random.default_rng(0), 200)
    model = fit_ridge([ridge_sums(x, y)], 0.0)
    design = np.column_stack([x[:, :4], np.ones(len(x))])
    expected = design @ np.linalg.lstsq(design, y, rcond=None)[0]
    np.testing.assert_allclose(predict_ridge(model, x), expected, rtol=1e-8, atol=1e-8)
    assert model["regressor_scale"][4] == 1.0


def test_pooled_sums_fit_as_the_concatenated_data() -> None:
    rng = np.random.default_rng(1)
    parts = [_data(rng, n) for n in (50, 80, 30)]
    pooled = fit_ridge([ridge_sums(x, y) for x, y in parts], 10.0)
    whole = fit_ridge(
        [ridge_sums(np.concatenate([x for x, _ in parts]), np.concatenate([y for _, y in parts]))],
        10.0,
    )
    for name in ("regressor_mean", "regressor_scale", "weights", "bias"):
        np.testing.assert_allclose(pooled[name], whole[name], rtol=1e-9, atol=1e-12)


def test_a_large_penalty_leaves_the_mean() -> None:
    x, y = _data(np.random.default_rng(2), 100)
    model = fit_ridge([ridge_sums(x, y)], 1e12)
    np.testing.assert_allclose(
        predict_ridge(model, x), np.broadcast_to(y.mean(0), y.shape), atol=1e-6
    )
