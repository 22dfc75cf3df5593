"""Optimiser plug-ins for the per-frame search problem: an ask/tell protocol and a registry.

An optimiser is a small object with three methods (the :class:`Optimizer` protocol)::

    reset(problem, rng)   # a new frame: read problem.dim, problem.x0, ... ; keep rng
    ask() -> Z | None     # next batch of latent points (n, d), or None when done
    tell(Z, energies)     # the energies (n,) of that batch (lower is better)

It never calls ``problem.evaluate`` itself: :func:`run_optimizer` does, so budgets are enforced
in one place. The problem only needs ``dim``, ``x0``, ``evaluate``, ``exhausted`` and
``solution()`` (duck typed; :class:`fpg_gym.reconstruct.SearchProblem` is the real one).

Built-in optimisers (``make(name, **kwargs)``):

=================  =====================================================================
``local-search``   Shum §VI-E: start at x0, 100 Gaussian samples per iteration around the
                   best point, move on improvement, stop at a local optimum or on budget
``random-search``  samples from the whitened latent prior N(0, I): the floor to beat
``cma-es``         CMA-ES warm-started at x0 (needs ``pip install 'fpg-gym[cma]'``)
``none``           no search: x0 (the previous reconstruction projected, or the best candidate)
``closed-form``    beyond the papers: one point, the exact minimiser of the energy's quadratic
                   terms (Ec, Em, a ridge for Es) in the latent space (1 evaluation)
=================  =====================================================================

Parametrised names ``PREFIX:ARGUMENT`` call a prefix factory with the argument (see
:func:`register_prefix`): ``learned:PATH`` and ``learned+search:PATH`` draw candidates from a
learned sampler saved at ``PATH`` (:mod:`optimizers.learned`, needs ``fpg-gym[learn]``).

Third-party optimisers register a factory (usually the class) under a name::

    import optimizers

    @optimizers.register("my-search")
    class MySearch(optimizers.BaseOptimizer):
        def ask(self): ...

    opt = optimizers.make("my-search", samples=50)

The registry is a module-level mapping (like Gymnasium's env registry): registering is the only
way it changes.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from fpg_gym.errors import FpgGymError

__all__ = [
    "BaseOptimizer",
    "MissingDependency",
    "Optimizer",
    "OptimizerNotFound",
    "ProblemLike",
    "available",
    "make",
    "prefixes",
    "register",
    "register_prefix",
    "run_optimizer",
]


class OptimizerNotFound(FpgGymError, KeyError):
    """No optimiser is registered under the requested name."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class MissingDependency(FpgGymError, ImportError):
    """An optimiser needs an optional package that is not installed."""


@runtime_checkable
class ProblemLike(Protocol):
    """What an optimiser may read from a problem (see ``SearchProblem`` for the full API)."""

    @property
    def dim(self) -> int: ...

    x0: np.ndarray


@runtime_checkable
class Optimizer(Protocol):
    """The ask/tell protocol every optimiser follows."""

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Start on a new problem (one frame); ``rng`` is the only source of randomness."""
        ...

    def ask(self) -> np.ndarray | None:
        """The next batch of latent points ``(n, dim)``, or None when the search is over."""
        ...

    def tell(self, z: np.ndarray, energies: np.ndarray) -> None:
        """Energies ``(n,)`` of the batch last asked (``inf`` for rows over the budget)."""
        ...


class BaseOptimizer:
    """Convenience base class: stores ``problem``, ``rng`` and ``dim``; ``tell`` does nothing.

    Subclasses override :meth:`ask` (and usually :meth:`tell` and :meth:`reset`, calling
    ``super().reset(problem, rng)``).
    """

    name = "base"

    def __init__(self) -> None:
        self.problem: Any = None
        self.rng: np.random.Generator = np.random.default_rng(0)
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
        """Receive the batch's energies (ignored by default)."""

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.params().items())
        return f"{type(self).__name__}({params})"

    def params(self) -> dict[str, Any]:
        """Constructor parameters (for reports and ``repr``)."""
        return {}


OptimizerFactory = Callable[..., Optimizer]
F = TypeVar("F", bound=Callable[..., Any])

_BUILTINS: dict[str, str] = {
    "local-search": "optimizers.local_search:LocalSearch",
    "random-search": "optimizers.random_search:RandomSearch",
    "cma-es": "optimizers.cma_es:CMAES",
    "none": "optimizers.none:NoSearch",
    "closed-form": "optimizers.closed_form:ClosedForm",
}
_REGISTRY: dict[str, OptimizerFactory] = {}
# Parametrised names "PREFIX:ARGUMENT": the factory is called with ARGUMENT first.
_BUILTIN_PREFIXES: dict[str, str] = {
    "learned": "optimizers.learned:LearnedSampler",
    "learned+search": "optimizers.learned:LearnedSearch",
}
_PREFIX_REGISTRY: dict[str, OptimizerFactory] = {}


def register(name: str, factory: OptimizerFactory | None = None, *, overwrite: bool = False) -> Any:
    """Register an optimiser factory under ``name``; usable as a decorator.

    Parameters
    ----------
    name : str
    factory : callable, optional
        Returns an object following :class:`Optimizer` when called with keyword arguments
        (usually the class). Omit it to use ``register`` as a class decorator.
    overwrite : bool
        Replace an existing registration (built-ins included) instead of raising.

    Raises
    ------
    ValueError
        If ``name`` is empty or already taken (without ``overwrite``).
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name: expected a non-empty string, got {name!r}")

    def decorate(f: F) -> F:
        if not callable(f):
            raise ValueError(f"factory for {name!r}: expected a callable, got {f!r}")
        if not overwrite and (name in _REGISTRY or name in _BUILTINS):
            raise ValueError(f"optimizer {name!r} is already registered (pass overwrite=True)")
        _REGISTRY[name] = f
        return f

    if factory is None:
        return decorate
    return decorate(factory)


def register_prefix(
    prefix: str, factory: OptimizerFactory, *, overwrite: bool = False
) -> OptimizerFactory:
    """Register a factory for parametrised names ``PREFIX:ARGUMENT``.

    ``make("PREFIX:ARGUMENT", **kwargs)`` returns ``factory(ARGUMENT, **kwargs)`` (the argument
    is everything after the first colon, e.g. a file path). Plain names take precedence.

    Raises
    ------
    ValueError
        If ``prefix`` is empty, contains ``:``, or is taken (without ``overwrite``).
    """
    if not isinstance(prefix, str) or not prefix or ":" in prefix:
        raise ValueError(f"prefix: expected a non-empty string without ':', got {prefix!r}")
    if not callable(factory):
        raise ValueError(f"factory for {prefix!r}: expected a callable, got {factory!r}")
    if not overwrite and (prefix in _PREFIX_REGISTRY or prefix in _BUILTIN_PREFIXES):
        raise ValueError(f"optimizer prefix {prefix!r} is already registered")
    _PREFIX_REGISTRY[prefix] = factory
    return factory


def prefixes() -> list[str]:
    """Prefixes of parametrised names (``learned``, ``learned+search``, ...), sorted."""
    return sorted(set(_BUILTIN_PREFIXES) | set(_PREFIX_REGISTRY))


def available() -> list[str]:
    """Names :func:`make` accepts, sorted."""
    return sorted(set(_BUILTINS) | set(_REGISTRY))


def _factory(name: str) -> OptimizerFactory:
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in _BUILTINS:
        module_name, attr = _BUILTINS[name].split(":")
        factory: OptimizerFactory = getattr(importlib.import_module(module_name), attr)
        return factory
    prefix, colon, argument = name.partition(":")
    if colon and prefix in _PREFIX_REGISTRY:
        return functools.partial(_PREFIX_REGISTRY[prefix], argument)
    if colon and prefix in _BUILTIN_PREFIXES:
        module_name, attr = _BUILTIN_PREFIXES[prefix].split(":")
        return functools.partial(getattr(importlib.import_module(module_name), attr), argument)
    parametrised = ", ".join(f"{p}:ARG" for p in prefixes())
    raise OptimizerNotFound(
        f"unknown optimizer {name!r}; available: {', '.join(available())}; parametrised: "
        f"{parametrised}"
    )


def make(name: str | Optimizer, **kwargs: Any) -> Optimizer:
    """Create the optimiser registered as ``name`` with keyword arguments ``kwargs``.

    An object that already follows the protocol is returned as is (``kwargs`` must be empty).

    Raises
    ------
    OptimizerNotFound
        Unknown name (the message lists the available ones).
    MissingDependency
        The optimiser needs an optional package (e.g. ``cma-es`` needs ``fpg-gym[cma]``).
    """
    if not isinstance(name, str):
        if kwargs:
            raise ValueError("make: keyword arguments given with an optimizer instance")
        if not isinstance(name, Optimizer):
            raise ValueError(f"make: {name!r} does not have reset/ask/tell")
        return name
    optimizer = _factory(name)(**kwargs)
    if not isinstance(optimizer, Optimizer):
        raise ValueError(
            f"optimizer {name!r}: factory returned {optimizer!r} without reset/ask/tell"
        )
    return optimizer


def run_optimizer(
    problem: Any,
    optimizer: Optimizer | str,
    rng: np.random.Generator | int | None = None,
    *,
    max_asks: int | None = 100_000,
) -> np.ndarray:
    """Run ``optimizer`` on ``problem`` until it stops or the budget is spent.

    Parameters
    ----------
    problem : SearchProblem-like
    optimizer : Optimizer or str
        An optimiser object or a registered name.
    rng : numpy.random.Generator or int, optional
        The optimiser's randomness (an int seeds a new generator; None: unseeded).
    max_asks : int, optional
        Safety stop for an optimiser that never returns None on an unlimited budget.

    Returns
    -------
    ndarray, shape (dim,)
        ``problem.solution()``: the best point evaluated, or ``x0`` without evaluations.
    """
    from fpg_gym.reconstruct.problem import BudgetExhausted

    opt = make(optimizer) if isinstance(optimizer, str) else optimizer
    generator = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    opt.reset(problem, generator)
    asks = 0
    while problem.dim > 0 and not problem.exhausted:
        if max_asks is not None and asks >= max_asks:
            break
        z = opt.ask()
        asks += 1
        if z is None:
            break
        z = np.asarray(z, dtype=np.float64)
        if z.ndim == 1:
            z = z[None]
        if len(z) == 0:
            break
        try:
            energies = problem.evaluate(z)
        except BudgetExhausted:
            break
        opt.tell(z, energies)
    solution: np.ndarray = problem.solution()
    return solution
