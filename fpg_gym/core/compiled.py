"""The compiled (numba) kernels' modules, and the one loader that imports them.

Each module of :data:`COMPILED_MODULES` imports numba at its top and exists for the optional
extra ``fpg-gym[fast]``; the code that uses it asks :func:`compiled_module` for it and runs its
numpy path when it gets None. The kernels compile on first use and are cached on disk
(``cache=True``), so a new process loads them instead of compiling them again.

With the environment variable ``FPG_GYM_NO_NUMBA=1`` (:data:`NO_NUMBA_VARIABLE`) the process
runs as without numba: :func:`compiled_module` gives None and :func:`numba_available` False, so
every kernel runs its numpy twin (CI runs the equation tests this way too).
"""

from __future__ import annotations

import functools
import importlib
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import Any

__all__ = [
    "COMPILED_MODULES",
    "JIT_OPTIONS",
    "NO_NUMBA_VARIABLE",
    "compiled_module",
    "kernels_cached",
    "numba_available",
    "numpy_only",
    "only_compiled",
]

#: The modules of compiled kernels, each imported only when ``fpg-gym[fast]`` is installed.
COMPILED_MODULES: tuple[str, ...] = (
    "fpg_gym.core.compiled_poses",
    "fpg_gym.filters.compiled_filters",
    "fpg_gym.physics.compiled_ragdoll",
    "fpg_gym.reconstruct.compiled_frame",
    "fpg_gym.reconstruct.compiled_fusion",
    "fpg_gym.reconstruct.compiled_kernels",
    "fpg_gym.reconstruct.compiled_reliability",
    "fpg_gym.reconstruct.compiled_search",
    "fpg_gym.reconstruct.compiled_selection",
)
#: ``numba.njit``'s options for every kernel of :data:`COMPILED_MODULES`: compiled once per
#: installation and kept on disk (``cache``), the GIL released (``nogil``), and no C-callable
#: entry point (``no_cfunc_wrapper``: a ``cfunc`` address, which nothing here takes; making it
#: was about 2 of the 24 CPU s a fresh installation spends compiling). ``Any`` values: numba's
#: typed ``njit`` names no ``no_cfunc_wrapper``.
JIT_OPTIONS: dict[str, Any] = {"cache": True, "nogil": True, "no_cfunc_wrapper": True}

#: Environment variable: ``1`` runs every kernel's numpy twin, as without numba.
NO_NUMBA_VARIABLE = "FPG_GYM_NO_NUMBA"

_shown: frozenset[str] | None = None  # None: every module


@contextmanager
def numpy_only(*, new_processes: bool = False) -> Iterator[None]:
    """Within this block :func:`compiled_module` gives None, so that everything built in it runs
    its numpy path, as without numba (not thread-safe). With ``new_processes`` the processes
    started in the block (a compare's spawned workers) run as without numba too:
    :data:`NO_NUMBA_VARIABLE` is set in this process's environment for the block."""
    before = os.environ.get(NO_NUMBA_VARIABLE)
    if new_processes:
        os.environ[NO_NUMBA_VARIABLE] = "1"
    try:
        with only_compiled(()):
            yield
    finally:
        if new_processes:
            if before is None:
                os.environ.pop(NO_NUMBA_VARIABLE, None)
            else:
                os.environ[NO_NUMBA_VARIABLE] = before


@contextmanager
def only_compiled(names: Iterable[str]) -> Iterator[None]:
    """Within this block :func:`compiled_module` gives None for every module not in ``names``
    (and within an enclosing block's), so that only those modules' kernels run and compile
    (a warm-up shares the modules between processes this way; not thread-safe)."""
    global _shown
    previous = _shown
    _shown = frozenset(names) if previous is None else previous & frozenset(names)
    try:
        yield
    finally:
        _shown = previous


def compiled_module(name: str) -> ModuleType | None:
    """The module ``name``, one of :data:`COMPILED_MODULES`, or None when numba is not installed
    (``pip install 'fpg-gym[fast]'``) or within :func:`numpy_only`. Imported once.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`COMPILED_MODULES`.
    ImportError
        If the module fails to import for another reason than a missing numba (or llvmlite).
    """
    if name not in COMPILED_MODULES:
        raise ValueError(f"name: expected one of {', '.join(COMPILED_MODULES)}, got {name!r}")
    return None if _shown is not None and name not in _shown else _import(name)


@functools.cache
def _import(name: str) -> ModuleType | None:
    """``name`` imported, or None when numba (or its llvmlite) is missing or hidden by
    :data:`NO_NUMBA_VARIABLE`; other errors raise."""
    if os.environ.get(NO_NUMBA_VARIABLE, "") not in ("", "0"):
        return None
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as error:
        if error.name not in ("numba", "llvmlite"):
            raise
        return None


def numba_available() -> bool:
    """Whether numba can be imported (the compiled kernels can run)."""
    return _import("numba") is not None


def kernels_cached(kernels: Iterable[tuple[str, str]]) -> bool:
    """Whether numba's disk cache holds compiled code for every ``(module, function)`` of
    ``kernels`` for this version of its source (False without numba, or when numba's cache
    cannot be read)."""
    try:
        for module_name, function in kernels:
            module = compiled_module(module_name)
            if module is None:
                return False
            # numba's private cache index: {} when absent or written for another source.
            if not getattr(module, function)._cache._cache_file._load_index():
                return False
    except (AttributeError, OSError):
        return False
    return True
