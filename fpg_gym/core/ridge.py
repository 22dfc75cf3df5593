"""Ridge regression from pooled sums: fit once per data set, pool any groups for
cross-validation.

A data set ``(x, y)`` is reduced to its sums (:func:`ridge_sums`); a fit (:func:`fit_ridge`)
pools any list of them, so leaving one group out of a cross-validation costs one small solve,
not a pass over the data. The regressors are standardised by the pooled mean and spread, the
intercept is not penalised. Used by the linear pose-space sampler
(:mod:`policies.pose_sampler`), its output correction and the sensor's bone model
(:mod:`fpg_gym.reconstruct.bone_model`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["fit_ridge", "predict_ridge", "ridge_sums"]


def ridge_sums(x: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    """The sums a ridge fit needs of regressors ``x`` ``(n, R)`` and targets ``y`` ``(n, K)``:
    ``n``, ``sx``, ``sy``, ``xx`` (``x.T @ x``) and ``xy`` (``x.T @ y``)."""
    return {"n": len(x), "sx": x.sum(0), "sy": y.sum(0), "xx": x.T @ x, "xy": x.T @ y}


def fit_ridge(sums: Sequence[dict[str, Any]], penalty: float) -> dict[str, np.ndarray]:
    """The ridge fit of the pooled ``sums`` (:func:`ridge_sums`).

    Parameters
    ----------
    sums : sequence of dict
        One or more data sets' sums, pooled.
    penalty : float
        The ridge penalty on the standardised regressors' weights.

    Returns
    -------
    dict
        ``regressor_mean``, ``regressor_scale`` ``(R,)``, ``weights`` ``(R, K)`` and the
        unpenalised ``bias`` ``(K,)`` (:func:`predict_ridge`). A constant regressor gets
        scale 1 and weight 0.
    """
    n = sum(s["n"] for s in sums)
    mean = sum(s["sx"] for s in sums) / n
    bias = sum(s["sy"] for s in sums) / n
    moments = sum(s["xx"] for s in sums)
    xx = moments - n * np.outer(mean, mean)
    xy = sum(s["xy"] for s in sums) - n * np.outer(mean, bias)
    # A regressor whose spread is within the rounding of its centring is a constant: weight 0.
    spread = np.maximum(np.diag(xx) / n, 0.0)
    varying = spread > 1e-12 * np.diag(moments) / n
    scale = np.where(varying, np.sqrt(spread), 1.0)
    xx = np.where(varying[:, None] & varying[None, :], xx, 0.0)
    xy = np.where(varying[:, None], xy, 0.0)
    gram = xx / np.outer(scale, scale) + np.diag(np.where(varying, penalty, 1.0))
    weights = np.linalg.solve(gram, xy / scale[:, None])
    return {"regressor_mean": mean, "regressor_scale": scale, "weights": weights, "bias": bias}


def predict_ridge(model: dict[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """Predictions ``(n, K)`` of a :func:`fit_ridge` model for regressors ``x`` ``(n, R)``."""
    scaled = (x - model["regressor_mean"]) / model["regressor_scale"]
    return scaled @ model["weights"] + model["bias"]
