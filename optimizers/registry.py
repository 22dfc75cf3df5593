"""The optimiser registry: names (and ``PREFIX:ARGUMENT`` names) to factories.

This layer registers its own optimisers (as ``"module:attr"`` strings, imported on first use).
Optimisers that live above it register themselves in the modules that define them
(``closed-form`` beside the per-frame problem it reads, the ``learned:`` samplers beside their
models); this layer names none of them. Importing such a module registers its optimisers; a
program that has not imported it still finds them by name, because the modules are declared as
plug-ins (the ``optimizers.plugins`` entry-point group of the distribution's metadata,
:data:`PLUGIN_GROUP`), which :func:`make`, :func:`available` and :func:`prefixes` import the
first time a name is not registered or the whole list is asked for.
"""

from __future__ import annotations

import functools
import importlib
import warnings
from collections.abc import Callable
from importlib import metadata
from typing import Any, TypeVar

from optimizers.base import BaseOptimizer, Optimizer, OptimizerNotFound

__all__ = ["PLUGIN_GROUP", "available", "make", "prefixes", "register", "register_prefix"]

OptimizerFactory = Callable[..., Optimizer]
F = TypeVar("F", bound=Callable[..., Any])

# name -> factory, or "module:attr" naming one (imported on first use).
_REGISTRY: dict[str, OptimizerFactory | str] = {
    "local-search": "optimizers.local_search:LocalSearch",
    "random-search": "optimizers.random_search:RandomSearch",
    "cma-es": "optimizers.cma_es:CMAES",
    "none": "optimizers.none:NoSearch",
}
# Parametrised names "PREFIX:ARGUMENT": the factory is called with ARGUMENT first.
_PREFIX_REGISTRY: dict[str, OptimizerFactory | str] = {}

#: Entry-point group of the modules that register optimisers when imported (plug-ins).
PLUGIN_GROUP = "optimizers.plugins"
_plugins_loaded = False


def _load_plugins() -> None:
    """Import the modules of :data:`PLUGIN_GROUP` once (they register their optimisers).

    A plug-in that fails to import is reported by a warning naming it, and skipped.
    """
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for entry in metadata.entry_points(group=PLUGIN_GROUP):
        try:
            entry.load()
        except Exception as error:  # a broken plug-in must not break the registry
            warnings.warn(
                f"optimizer plug-in {entry.name!r} ({entry.value}) failed to load: {error}",
                RuntimeWarning,
                stacklevel=3,
            )


def _store(
    table: dict[str, OptimizerFactory | str],
    key: str,
    factory: OptimizerFactory | str,
    overwrite: bool,
    what: str,
) -> None:
    if not overwrite and key in table:
        raise ValueError(f"{what} {key!r} is already registered (pass overwrite=True)")
    table[key] = factory


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
        _store(_REGISTRY, name, f, overwrite, "optimizer")
        return f

    if factory is None:
        return decorate
    if isinstance(factory, str):
        _check_factory(repr(name), factory)
        _store(_REGISTRY, name, factory, overwrite, "optimizer")
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
    _store(_PREFIX_REGISTRY, prefix, factory, overwrite, "optimizer prefix")
    return factory


def prefixes() -> list[str]:
    """Prefixes of parametrised names (``learned``, ``learned+search``, ...), sorted; plug-ins
    included."""
    _load_plugins()
    return sorted(_PREFIX_REGISTRY)


def available() -> list[str]:
    """Names :func:`make` accepts, sorted; plug-ins included. Some need more than a plain
    :class:`~optimizers.Problem` and say so when reset on one (``closed-form`` reads the
    per-frame reconstruction problem)."""
    _load_plugins()
    return sorted(_REGISTRY)


def _resolve(entry: OptimizerFactory | str) -> OptimizerFactory:
    if not isinstance(entry, str):
        return entry
    module_name, _, attr = entry.partition(":")
    factory: OptimizerFactory = getattr(importlib.import_module(module_name), attr)
    return factory


def _lookup(name: str) -> OptimizerFactory | None:
    if name in _REGISTRY:
        return _resolve(_REGISTRY[name])
    prefix, colon, argument = name.partition(":")
    if colon and prefix in _PREFIX_REGISTRY:
        return functools.partial(_resolve(_PREFIX_REGISTRY[prefix]), argument)
    return None


def _factory(name: str) -> OptimizerFactory:
    found = _lookup(name)
    if found is None and not _plugins_loaded:
        _load_plugins()
        found = _lookup(name)
    if found is not None:
        return found
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
