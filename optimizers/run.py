"""Running an optimiser on a problem: the one place that owns the budget and the best point."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from optimizers.base import Optimizer, Problem
from optimizers.registry import make

__all__ = ["SearchResult", "run_optimizer"]


@dataclass(frozen=True)
class SearchResult:
    """What :func:`run_optimizer` found.

    Attributes
    ----------
    x : ndarray, shape (dim,)
        The best point evaluated, or a copy of ``problem.x0`` when nothing was evaluated.
    energy : float
        Its value (``inf`` when nothing was evaluated).
    evaluations : int
        Points evaluated (rows passed to ``problem.evaluate``).
    asks : int
        Batches asked (including the final ``None``, if any).
    """

    x: np.ndarray
    energy: float
    evaluations: int
    asks: int


def run_optimizer(
    problem: Problem,
    optimizer: Optimizer | str,
    rng: np.random.Generator | int | None = None,
    *,
    max_evaluations: int | None = None,
    time_budget_s: float | None = None,
    max_asks: int | None = 100_000,
) -> SearchResult:
    """Run ``optimizer`` on ``problem`` until it stops or the budget is spent.

    Each batch the optimiser asks is evaluated by ``problem.evaluate``; a batch larger than the
    evaluations left is clipped (its first rows are evaluated, the others get ``+inf`` so that
    no optimiser can pick them), and the search ends once nothing is left.

    Parameters
    ----------
    problem : Problem
        Anything with ``dim``, ``x0`` and ``evaluate(Z) -> values`` (lower is better).
    optimizer : Optimizer or str
        An optimiser object or a registered name.
    rng : numpy.random.Generator or int, optional
        The optimiser's randomness (an int seeds a new generator; None: unseeded).
    max_evaluations : int, optional
        Most points evaluated (None: unlimited).
    time_budget_s : float, optional
        Seconds allowed from the first evaluation (None: unlimited); checked between batches.
    max_asks : int, optional
        Safety stop for an optimiser that never returns None on an unlimited budget.

    Returns
    -------
    SearchResult
        The best point and its value, the evaluations and asks spent.

    Examples
    --------
    A custom problem needs only ``dim``, ``x0`` and ``evaluate``:

    >>> import numpy as np
    >>> class Sphere:
    ...     dim = 3
    ...     x0 = np.ones(3)
    ...     def evaluate(self, z):
    ...         return (z**2).sum(axis=1)
    >>> result = run_optimizer(Sphere(), "local-search", rng=0, max_evaluations=500)
    >>> bool(result.energy < 3.0), result.evaluations <= 500
    (True, True)
    """
    if max_evaluations is not None and max_evaluations < 0:
        raise ValueError(f"max_evaluations: expected >= 0 or None, got {max_evaluations}")
    if time_budget_s is not None and not time_budget_s > 0:
        raise ValueError(f"time_budget_s: expected > 0 or None, got {time_budget_s}")
    opt = make(optimizer) if isinstance(optimizer, str) else optimizer
    generator = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    dim = int(problem.dim)
    best_x = np.array(problem.x0, dtype=np.float64)
    best = float("inf")
    evaluations = asks = 0
    started: float | None = None
    opt.reset(problem, generator)
    while dim > 0:
        left = None if max_evaluations is None else max_evaluations - evaluations
        out_of_time = (
            started is not None
            and time_budget_s is not None
            and time.perf_counter() - started >= time_budget_s
        )
        if left == 0 or out_of_time or (max_asks is not None and asks >= max_asks):
            break
        z = opt.ask()
        asks += 1
        if z is None:
            break
        z = np.asarray(z, dtype=np.float64)
        if z.ndim == 1:
            z = z[None]
        if z.ndim != 2 or z.shape[1] != dim:
            raise ValueError(f"optimizer {opt!r}: asked shape {z.shape}, expected (n, {dim})")
        if len(z) == 0:
            break
        admitted = len(z) if left is None else min(len(z), left)
        if started is None:
            started = time.perf_counter()
        values = np.asarray(problem.evaluate(z[:admitted]), dtype=np.float64).reshape(admitted)
        evaluations += admitted
        i = int(np.argmin(values))
        if values[i] < best:
            best = float(values[i])
            best_x = z[i].copy()
        if admitted < len(z):
            values = np.concatenate([values, np.full(len(z) - admitted, np.inf)])
        opt.tell(z, values)
    return SearchResult(x=best_x, energy=best, evaluations=evaluations, asks=asks)
