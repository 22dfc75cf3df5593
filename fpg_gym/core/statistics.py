"""Statistics of results over episodes or sessions (not of one skeleton stream).

* :func:`bootstrap_mean_ci` — a 95 % bootstrap interval of a mean over episodes (or of its
  change against a baseline on the same episodes).
* :func:`robust_z_scores` — modified z-scores (median and MAD), the outlier rule of the UI-PRMD
  import's sessions.

Both are documented as :mod:`fpg_gym.core.metrics` names and importable from there too.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fpg_gym.core.seeding import as_generator

__all__ = ["bootstrap_mean_ci", "robust_z_scores"]


def bootstrap_mean_ci(
    values: npt.ArrayLike,
    *,
    weights: npt.ArrayLike | None = None,
    base: npt.ArrayLike | None = None,
    draws: int = 2000,
    rng: np.random.Generator | int = 0,
) -> tuple[float, float]:
    """95 % percentile bootstrap interval of a mean over episodes, resampling the episodes.

    Parameters
    ----------
    values : array_like, shape (E,)
        One value per episode (e.g. its mean error).
    weights : array_like, shape (E,), optional
        Each episode's weight (e.g. its frame count): the mean is then ``sum(w v) / sum(w)``,
        the pooled mean over frames.
    base : array_like, shape (E,), optional
        The same episodes' values under a baseline: the interval is then that of the relative
        change ``mean(values) / mean(base) - 1`` (paired).
    draws : int
        Bootstrap resamples.
    rng : numpy.random.Generator or int
        The resampling's generator, or its seed.

    Returns
    -------
    tuple of float
        The 2.5th and 97.5th percentiles.

    Raises
    ------
    ValueError
        If ``values`` is empty or the arrays differ in length.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(v) == 0:
        raise ValueError("values: expected at least one episode, got 0")
    w = np.ones_like(v) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    b = None if base is None else np.asarray(base, dtype=np.float64).reshape(-1)
    if len(w) != len(v) or (b is not None and len(b) != len(v)):
        raise ValueError(f"weights, base: expected {len(v)} values (one per episode)")
    generator = as_generator(rng)
    idx = generator.integers(0, len(v), size=(draws, len(v)))
    total = w[idx].sum(axis=1)
    means = (w * v)[idx].sum(axis=1) / total
    if b is not None:
        means = means / ((w * b)[idx].sum(axis=1) / total) - 1.0
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def robust_z_scores(values: npt.ArrayLike) -> np.ndarray:
    """Modified z-scores ``0.6745 (x - median) / MAD`` (Iglewicz & Hoaglin 1993): how far each
    value lies from the others' median, in robust standard deviations; above 3.5 is their
    outlier rule. With a MAD of 0 the mean absolute deviation (times 1.2533) stands in; all
    values equal give zeros.

    Parameters
    ----------
    values : array_like, shape (N,)
        Finite numbers.

    Returns
    -------
    ndarray, shape (N,), float64
    """
    x = np.asarray(values, dtype=np.float64)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise ValueError(f"values: expected a 1-D array of finite numbers, got shape {x.shape}")
    if len(x) == 0:
        return x.copy()
    deviation = x - np.median(x)
    mad = float(np.median(np.abs(deviation)))
    if mad > 0:
        return 0.6745 * deviation / mad
    mean_ad = float(np.mean(np.abs(deviation)))
    return deviation / (1.2533 * mean_ad) if mean_ad > 0 else np.zeros_like(x)
