"""What an optimiser and a problem are: the two protocols, a convenience base class, errors.

numpy only: this layer knows nothing of poses, environments or torch.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "BaseOptimizer",
    "MissingDependency",
    "Optimizer",
    "OptimizerError",
    "OptimizerNotFound",
    "Problem",
]


class OptimizerError(Exception):
    """Base class of the errors the optimiser layer raises on purpose."""


class OptimizerNotFound(OptimizerError, KeyError):
    """No optimiser is registered under the requested name."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class MissingDependency(OptimizerError, ImportError):
    """An optimiser needs an optional package that is not installed."""


@runtime_checkable
class Problem(Protocol):
    """The minimal problem an optimiser runs on: a dimension, a start and a batched objective.

    ``evaluate`` maps points ``(n, dim)`` to values ``(n,)`` (lower is better). Nothing else is
    required: :func:`optimizers.run_optimizer` owns the budget and the best point. A problem may
    offer more (:class:`fpg_gym.reconstruct.SearchProblem` does: the frame's sensor data,
    reliability, latent space); optimisers that read more say so and are registered beside that
    problem, not here.
    """

    @property
    def dim(self) -> int: ...

    @property
    def x0(self) -> np.ndarray: ...

    def evaluate(self, z: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class Optimizer(Protocol):
    """The ask/tell protocol every optimiser follows."""

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Start on a new problem (one frame); ``rng`` is the only source of randomness."""
        ...

    def ask(self) -> np.ndarray | None:
        """The next batch of points ``(n, dim)``, or None when the search is over."""
        ...

    def tell(self, z: np.ndarray, energies: np.ndarray) -> None:
        """Values ``(n,)`` of the batch last asked (``inf`` for rows over the budget)."""
        ...


class BaseOptimizer:
    """Convenience base class: stores ``problem``, ``rng`` and ``dim``; ``tell`` does nothing.

    Subclasses override :meth:`ask` (and usually :meth:`tell` and :meth:`reset`, calling
    ``super().reset(problem, rng)``).
    """

    name = "base"

    #: The generator of the current problem (set by :meth:`reset`).
    rng: np.random.Generator

    def __init__(self) -> None:
        self.problem: Any = None
        self.dim = 0

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Start on ``problem`` with the generator ``rng``."""
        self.problem = problem
        self.rng = rng
        self.dim = int(problem.dim)

    def ask(self) -> np.ndarray | None:  # pragma: no cover - abstract
        """The next batch, or None when done."""
        raise NotImplementedError

    def tell(self, z: np.ndarray, energies: np.ndarray) -> None:
        """Receive the batch's values (ignored by default)."""

    def recommend(self) -> tuple[np.ndarray, float] | None:
        """The point the search returns and its energy, when that is not the lowest-energy
        point evaluated; None (the default) returns that point.

        A sampler with a learned prior recommends the evaluated point of highest posterior
        (:class:`policies.learned_optimizers.LearnedSampler`): the energy alone is not the
        accuracy, so its lowest point need not be the best guess (the distinction between
        the best evaluated point and the recommendation is Nevergrad's).
        """
        return None

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.params().items())
        return f"{type(self).__name__}({params})"

    def params(self) -> dict[str, Any]:
        """Constructor parameters (for reports and ``repr``)."""
        return {}
