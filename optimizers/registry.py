"""The optimiser registry: names (and ``PREFIX:ARGUMENT`` names) to factories.

Built-in entries are ``"module:attr"`` strings, imported on first use, so that optimisers that
live above this layer (``closed-form`` beside the reconstruction problem it reads, ``learned:``
beside the torch policies) register without this layer importing them.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from typing import Any, TypeVar

from optimizers.base import BaseOptimizer, Optimizer, OptimizerNotFound

__all__ = ["available", "make", "prefixes", "register", "register_prefix"]

OptimizerFactory = Callable[..., Optimizer]
F = TypeVar("F", bound=Callable[..., Any])

# name -> factory, or "module:attr" naming one (imported on first use).
_REGISTRY: dict[str, OptimizerFactory | str] = {
    "local-search": "optimizers.local_search:LocalSearch",
    "random-search": "optimizers.random_search:RandomSearch",
    "cma-es": "optimizers.cma_es:CMAES",
    "none": "optimizers.none:NoSearch",
    "closed-form": "fpg_gym.reconstruct.closed_form:ClosedForm",
}
# Parametrised names "PREFIX:ARGUMENT": the factory is called with ARGUMENT first.
_PREFIX_REGISTRY: dict[str, OptimizerFactory | str] = {
    "learned": "policies.learned_optimizers:LearnedSampler",
    "learned+search": "policies.learned_optimizers:LearnedSearch",
}


def _check_factory(label: str, factory: Any) -> None:
    if isinstance(factory, str):
        module_name, colon, attr = factory.partition(":")
        if not (module_name and colon and attr):
            raise ValueError(f"factory for {label}: expected 'module:attr', got {factory!r}")
    elif not callable(factory):
        raise ValueError(
            f"factory for {label}: expected a callable or 'module:attr', got {factory!r}"
        )


def register(
    name: str, factory: OptimizerFactory | str | None = None, *, overwrite: bool = False
) -> Any:
    """Register an optimiser factory under ``name``; usable as a decorator.

    Parameters
    ----------
    name : str
    factory : callable or str, optional
        Returns an object following :class:`~optimizers.Optimizer` when called with keyword
        arguments (usually the class), or ``"module:attr"`` naming one (imported by
        :func:`make`, so registering does not import it). Omit it to use ``register`` as a
        class decorator.
    overwrite : bool
        Replace an existing registration (built-ins included) instead of raising.

    Raises
    ------
    ValueError
        If ``name`` is empty or already taken (without ``overwrite``), or ``factory`` is
        neither callable nor ``"module:attr"``.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"name: expected a non-empty string, got {name!r}")

    def decorate(f: F) -> F:
        _check_factory(repr(name), f)
        if not overwrite and name in _REGISTRY:
            raise ValueError(f"optimizer {name!r} is already registered (pass overwrite=True)")
        _REGISTRY[name] = f
        return f

    if factory is None:
        return decorate
    if isinstance(factory, str):
        _check_factory(repr(name), factory)
        if not overwrite and name in _REGISTRY:
            raise ValueError(f"optimizer {name!r} is already registered (pass overwrite=True)")
        _REGISTRY[name] = factory
        return factory
    return decorate(factory)


def register_prefix(
    prefix: str, factory: OptimizerFactory | str, *, overwrite: bool = False
) -> OptimizerFactory | str:
    """Register a factory for parametrised names ``PREFIX:ARGUMENT``.

    ``make("PREFIX:ARGUMENT", **kwargs)`` returns ``factory(ARGUMENT, **kwargs)`` (the argument
    is everything after the first colon, e.g. a file path). Plain names take precedence.
    ``factory`` may be ``"module:attr"`` as in :func:`register`.

    Raises
    ------
    ValueError
        If ``prefix`` is empty, contains ``:``, or is taken (without ``overwrite``).
    """
    if not isinstance(prefix, str) or not prefix or ":" in prefix:
        raise ValueError(f"prefix: expected a non-empty string without ':', got {prefix!r}")
    _check_factory(repr(prefix), factory)
    if not overwrite and prefix in _PREFIX_REGISTRY:
        raise ValueError(f"optimizer prefix {prefix!r} is already registered")
    _PREFIX_REGISTRY[prefix] = factory
    return factory


def prefixes() -> list[str]:
    """Prefixes of parametrised names (``learned``, ``learned+search``, ...), sorted."""
    return sorted(_PREFIX_REGISTRY)


def available() -> list[str]:
    """Names :func:`make` accepts, sorted."""
    return sorted(_REGISTRY)


def _resolve(entry: OptimizerFactory | str) -> OptimizerFactory:
    if not isinstance(entry, str):
        return entry
    module_name, _, attr = entry.partition(":")
    factory: OptimizerFactory = getattr(importlib.import_module(module_name), attr)
    return factory


def _factory(name: str) -> OptimizerFactory:
    if name in _REGISTRY:
        return _resolve(_REGISTRY[name])
    prefix, colon, argument = name.partition(":")
    if colon and prefix in _PREFIX_REGISTRY:
        return functools.partial(_resolve(_PREFIX_REGISTRY[prefix]), argument)
    parametrised = ", ".join(f"{p}:ARG" for p in prefixes())
    raise OptimizerNotFound(
        f"unknown optimizer {name!r}; available: {', '.join(available())}; parametrised: "
        f"{parametrised}"
    )


def _follows_protocol(candidate: object) -> bool:
    """Whether ``candidate`` has reset/ask/tell: a :class:`BaseOptimizer` by its class (cheap:
    Python 3.11's structural ``isinstance`` takes ~20 µs, once per frame), else structurally."""
    return isinstance(candidate, BaseOptimizer) or isinstance(candidate, Optimizer)


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
        if not _follows_protocol(name):
            raise ValueError(f"make: {name!r} does not have reset/ask/tell")
        return name
    optimizer = _factory(name)(**kwargs)
    if not _follows_protocol(optimizer):
        raise ValueError(
            f"optimizer {name!r}: factory returned {optimizer!r} without reset/ask/tell"
        )
    return optimizer
