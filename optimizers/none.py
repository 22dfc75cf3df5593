"""The ablation: no search at all."""

from __future__ import annotations

import numpy as np

from optimizers import BaseOptimizer


class NoSearch(BaseOptimizer):
    """Asks nothing: the frame is reconstructed from ``problem.x0``.

    ``x0`` is the previous reconstruction projected into the new latent space, or the best
    candidate's projection on a first frame.
    """

    name = "none"

    def ask(self) -> np.ndarray | None:
        """Always None: the search is over before it starts."""
        return None
