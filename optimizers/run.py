"""Running an optimiser on a problem: the one place that owns the budget and the best point."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from optimizers.base import Optimizer, Problem
from optimizers.registry import make

__all__ = ["OptimizerRun", "SearchResult", "run_optimizer"]


@dataclass(frozen=True)
class SearchResult:
    """What :func:`run_optimizer` found.

    Attributes
    ----------
    x : ndarray, shape (dim,)
        The best point evaluated (or the one the optimiser recommends, see
        :meth:`~optimizers.BaseOptimizer.recommend`), or a copy of ``problem.x0`` when nothing
        was evaluated.
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
    run = OptimizerRun(
        problem,
        optimizer,
        rng,
        max_evaluations=max_evaluations,
        time_budget_s=time_budget_s,
        max_asks=max_asks,
    )
    while (z := run.propose()) is not None:
        run.receive(problem.evaluate(z))
    return run.result()


class OptimizerRun:
    """:func:`run_optimizer` one batch at a time, for a caller that evaluates the batches.

    The same budget rules as :func:`run_optimizer` (which loops over this class): ``propose``
    returns the admitted rows of the optimiser's next batch (clipped to the evaluations left) or
    None when the search is over; ``receive`` takes their values. A caller that runs many
    searches side by side (many streams) evaluates their batches together between the two.

    Parameters
    ----------
    problem, optimizer, rng, max_evaluations, time_budget_s, max_asks
        As :func:`run_optimizer`; ``problem`` needs ``dim`` and ``x0`` only (the caller
        evaluates).

    Attributes
    ----------
    optimizer : Optimizer
    rng : numpy.random.Generator
        The optimiser's generator.
    max_evaluations, time_budget_s, max_asks
        The budget.
    """

    def __init__(
        self,
        problem: Any,
        optimizer: Optimizer | str,
        rng: np.random.Generator | int | None = None,
        *,
        max_evaluations: int | None = None,
        time_budget_s: float | None = None,
        max_asks: int | None = 100_000,
    ) -> None:
        if max_evaluations is not None and max_evaluations < 0:
            raise ValueError(f"max_evaluations: expected >= 0 or None, got {max_evaluations}")
        if time_budget_s is not None and not time_budget_s > 0:
            raise ValueError(f"time_budget_s: expected > 0 or None, got {time_budget_s}")
        self.optimizer = make(optimizer) if isinstance(optimizer, str) else optimizer
        generator = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.dim = int(problem.dim)
        self.max_evaluations = max_evaluations
        self.time_budget_s = time_budget_s
        self.max_asks = max_asks
        self.best_x = np.array(problem.x0, dtype=np.float64)
        self.best = float("inf")
        self.evaluations = self.asks = 0
        self._started: float | None = None
        self._asked: np.ndarray | None = None  # the optimiser's whole last batch
        self._admitted = 0
        self.done = self.dim <= 0
        self.rng = generator
        self.optimizer.reset(problem, generator)

    def propose(self) -> np.ndarray | None:
        """The rows ``(m, dim)`` to evaluate next, or None when the search is over."""
        if self.done:
            return None
        if self._asked is not None:
            raise RuntimeError("propose: the last batch was not received (call receive)")
        left = None if self.max_evaluations is None else self.max_evaluations - self.evaluations
        out_of_time = (
            self._started is not None
            and self.time_budget_s is not None
            and time.perf_counter() - self._started >= self.time_budget_s
        )
        if left == 0 or out_of_time or (self.max_asks is not None and self.asks >= self.max_asks):
            self.done = True
            return None
        z = self.optimizer.ask()
        self.asks += 1
        if z is None:
            self.done = True
            return None
        z = np.asarray(z, dtype=np.float64)
        if z.ndim == 1:
            z = z[None]
        if z.ndim != 2 or z.shape[1] != self.dim:
            raise ValueError(
                f"optimizer {self.optimizer!r}: asked shape {z.shape}, expected (n, {self.dim})"
            )
        if len(z) == 0:
            self.done = True
            return None
        self._admitted = len(z) if left is None else min(len(z), left)
        if self._started is None:
            self._started = time.perf_counter()
        self._asked = z
        return z[: self._admitted]

    def receive(self, values: np.ndarray) -> None:
        """The values ``(m,)`` of the rows :meth:`propose` returned."""
        z, admitted = self._asked, self._admitted
        if z is None:
            raise RuntimeError("receive: nothing was proposed")
        self._asked = None
        values = np.asarray(values, dtype=np.float64).reshape(admitted)
        self.evaluations += admitted
        i = int(np.argmin(values))
        if values[i] < self.best:
            self.best = float(values[i])
            self.best_x = z[i].copy()
        if admitted < len(z):
            values = np.concatenate([values, np.full(len(z) - admitted, np.inf)])
        self.optimizer.tell(z, values)

    def complete(self, result: SearchResult) -> None:
        """End the run with ``result``: the same search run elsewhere (a compiled twin of the
        optimiser on the same generator), before this run proposed anything.

        Raises
        ------
        RuntimeError
            If this run has already proposed a batch.
        """
        if self.asks or self._asked is not None:
            raise RuntimeError("complete: the run has already proposed (a search runs once)")
        self.best_x = np.array(result.x, dtype=np.float64)
        self.best = float(result.energy)
        self.evaluations, self.asks = int(result.evaluations), int(result.asks)
        self.done = True

    def result(self) -> SearchResult:
        """The best point found so far (the optimiser's recommendation when it makes one:
        :meth:`BaseOptimizer.recommend`) and the evaluations and asks spent."""
        recommend = getattr(self.optimizer, "recommend", None)
        choice = recommend() if callable(recommend) and self.asks else None
        x, energy = (self.best_x, self.best) if choice is None else choice
        return SearchResult(
            x=np.asarray(x, dtype=np.float64),
            energy=float(energy),
            evaluations=self.evaluations,
            asks=self.asks,
        )
