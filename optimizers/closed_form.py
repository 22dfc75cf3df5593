"""The closed-form minimiser of the energy's quadratic terms: one evaluation per frame."""

from __future__ import annotations

from typing import Any

import numpy as np

from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE, quadratic_minimiser
from optimizers import BaseOptimizer


class ClosedForm(BaseOptimizer):
    """Asks one point: the exact minimiser of ``w_c Ec + w_m Em`` plus a ridge toward the
    candidates' mean standing in for ``Es`` (see :mod:`fpg_gym.reconstruct.closed_form`).

    Beyond the papers: a deterministic, regularised least-squares fit of the reliable sensor
    joints and the continuity prediction in the frame's natural posture space. It reads the
    problem's public attributes (sensor pose, reliability, prediction, latent space, energy
    weights) and spends one energy evaluation, so the chosen point's energy is recorded like
    any other optimiser's.

    Parameters
    ----------
    style : float
        Ridge weight as a multiple of ``w_s / J`` (2).
    """

    name = "closed-form"

    def __init__(self, style: float = DEFAULT_STYLE) -> None:
        super().__init__()
        if not (np.isfinite(style) and style >= 0):
            raise ValueError(f"style: expected a finite value >= 0, got {style}")
        self.style = float(style)
        self._asked = False

    def params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {"style": self.style}

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Start on a new frame's problem."""
        super().reset(problem, rng)
        self._asked = False

    def ask(self) -> np.ndarray | None:
        """The minimiser ``(1, d)`` on the first call, then None."""
        if self._asked:
            return None
        self._asked = True
        problem = self.problem
        latent = problem.latent
        prediction = problem.prediction
        return quadratic_minimiser(
            np.asarray(problem.kinect_pose, dtype=np.float64).reshape(1, -1),
            np.asarray(problem.reliability, dtype=np.float64)[None],
            np.asarray(latent.mean, dtype=np.float64).reshape(1, -1),
            np.asarray(latent.basis, dtype=np.float64)[None],
            np.asarray(latent.std, dtype=np.float64)[None],
            prediction=None if prediction is None else np.asarray(prediction).reshape(1, -1),
            weights=problem.weights.paper_terms(),
            style=self.style,
        )
