"""Random search from the latent prior: the floor any optimiser must beat."""

from __future__ import annotations

from typing import Any

import numpy as np

from optimizers import BaseOptimizer


class RandomSearch(BaseOptimizer):
    """Independent samples from the whitened latent prior ``N(0, scale^2 I)``.

    The prior is the Gaussian the K candidates span (mean = candidates' mean, unit variance per
    whitened axis). It ignores ``x0`` and the sensor: what any informed method must beat at the
    same budget.

    Parameters
    ----------
    samples : int
        Points per batch (100).
    iterations : int
        Batches (20, so 2,000 evaluations like local search).
    scale : float
        Standard deviation in whitened units (1).
    """

    name = "random-search"

    def __init__(self, samples: int = 100, iterations: int = 20, scale: float = 1.0) -> None:
        super().__init__()
        if samples < 1 or iterations < 1:
            raise ValueError(f"samples, iterations: expected >= 1, got {samples}, {iterations}")
        if not scale > 0:
            raise ValueError(f"scale: expected > 0, got {scale}")
        self.samples = samples
        self.iterations = iterations
        self.scale = scale

    def params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {"samples": self.samples, "iterations": self.iterations, "scale": self.scale}

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Start a new frame."""
        super().reset(problem, rng)
        self.iteration = 0

    def ask(self) -> np.ndarray | None:
        """``samples`` prior samples, until ``iterations`` batches were asked."""
        if self.iteration >= self.iterations:
            return None
        self.iteration += 1
        return self.scale * self.rng.standard_normal((self.samples, self.dim))
