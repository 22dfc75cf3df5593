"""CMA-ES through the ``cmaes`` package (optional extra ``fpg-gym[cma]``), warm-started at x0."""

from __future__ import annotations

from typing import Any

import numpy as np

from optimizers import BaseOptimizer, MissingDependency


def _cma_class() -> Any:
    try:
        from cmaes import CMA
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise MissingDependency(
            "optimizer 'cma-es' needs the cmaes package: pip install 'fpg-gym[cma]'"
        ) from error
    return CMA


class CMAES(BaseOptimizer):
    """CMA-ES (Hansen) in the whitened latent space, started at ``problem.x0``.

    Each :meth:`ask` returns one generation (``population_size`` points); the first one also
    contains ``x0`` (scored, not told to CMA-ES). The search ends after ``max_generations``, when
    CMA-ES reports convergence, or when the problem's budget is spent (2,000 evaluations).
    The ``cmaes`` generator is seeded from the ``rng`` given to :meth:`reset`.

    Parameters
    ----------
    sigma : float
        Initial step size in whitened units (0.3).
    population_size : int, optional
        Points per generation; CMA-ES's default ``4 + floor(3 ln d)`` when omitted.
    max_generations : int, optional
        Stop after this many generations (None: budget only).

    Raises
    ------
    MissingDependency
        When ``cmaes`` is not installed (``pip install 'fpg-gym[cma]'``).
    """

    name = "cma-es"

    def __init__(
        self,
        sigma: float = 0.3,
        population_size: int | None = None,
        max_generations: int | None = None,
    ) -> None:
        super().__init__()
        self._cma = _cma_class()
        if not sigma > 0:
            raise ValueError(f"sigma: expected > 0, got {sigma}")
        if population_size is not None and population_size < 2:
            raise ValueError(f"population_size: expected >= 2, got {population_size}")
        self.sigma = sigma
        self.population_size = population_size
        self.max_generations = max_generations

    def params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {
            "sigma": self.sigma,
            "population_size": self.population_size,
            "max_generations": self.max_generations,
        }

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """A fresh CMA-ES at ``x0`` for this frame."""
        super().reset(problem, rng)
        self.x0 = np.asarray(problem.x0, dtype=np.float64)
        self.generation = 0
        self.done = self.dim == 0
        self.es: Any = None
        if self.dim > 0:
            self.es = self._cma(
                mean=self.x0.copy(),
                sigma=self.sigma,
                seed=int(rng.integers(2**31 - 1)),
                population_size=self.population_size,
            )

    def ask(self) -> np.ndarray | None:
        """One generation (plus x0 in the first)."""
        if self.done or self.es is None:
            return None
        if self.max_generations is not None and self.generation >= self.max_generations:
            return None
        batch = np.stack([self.es.ask() for _ in range(self.es.population_size)])
        if self.generation == 0:
            batch = np.vstack([batch, self.x0[None]])
        return batch

    def tell(self, z: np.ndarray, energies: np.ndarray) -> None:
        """Update CMA-ES with the generation's energies (a clipped batch ends the search)."""
        popsize = self.es.population_size
        if len(z) < popsize or not np.all(np.isfinite(energies[:popsize])):
            self.done = True
            return
        self.es.tell([(z[i], float(energies[i])) for i in range(popsize)])
        self.generation += 1
        self.done = bool(self.es.should_stop())
