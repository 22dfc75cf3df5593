"""The per-frame linear algebra on one BLAS thread.

A frame's LAPACK calls are tiny (the candidates' ``30 x 30`` Gram matrix), and OpenBLAS's
threads cost more than they bring there: ``np.linalg.eigh`` of that matrix took 196 µs with two
threads against 87 µs with one on this project's 2-core machine, and when the other core was
busy a frame's PCA stalled for a scheduler tick (about 16 ms) instead of 0.3 ms. The command
line's worker processes already run BLAS on one thread; :func:`one_blas_thread` does the same for
the calls that need it in any process, for the duration of the call only.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["one_blas_thread"]


@functools.cache
def _blas_libraries() -> tuple[Any, ...]:
    """threadpoolctl's controllers of the BLAS libraries loaded at the first call (numpy's
    among them: it is loaded with numpy)."""
    from threadpoolctl import ThreadpoolController  # a few ms, once per process

    return tuple(ThreadpoolController().select(user_api="blas").lib_controllers)


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with the loaded BLAS libraries on one thread, then restore their thread
    counts (about 2 µs). The setting is process-wide: another Python thread's BLAS calls during
    the block also run on one thread."""
    libraries = _blas_libraries()
    previous = [library.get_num_threads() for library in libraries]
    for library, threads in zip(libraries, previous, strict=True):
        if threads != 1:
            library.set_num_threads(1)
    try:
        yield
    finally:
        for library, threads in zip(libraries, previous, strict=True):
            if threads != 1:
                library.set_num_threads(threads)
