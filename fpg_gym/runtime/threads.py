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
from contextlib import AbstractContextManager
from typing import Any

__all__ = ["one_blas_thread"]


@functools.cache
def _blas_libraries() -> tuple[Any, ...]:
    """threadpoolctl's controllers of the BLAS libraries loaded at the first call (numpy's
    among them: it is loaded with numpy)."""
    from threadpoolctl import ThreadpoolController  # a few ms, once per process

    return tuple(ThreadpoolController().select(user_api="blas").lib_controllers)


class _OneBlasThread:
    """:func:`one_blas_thread`'s context manager (a class: an empty block costs 3.9 µs of CPU
    against 5.8 µs for a generator's ``contextmanager``, numpy's and scipy's OpenBLAS loaded)."""

    __slots__ = ("_restore",)

    def __enter__(self) -> None:
        restore = []
        for library in _blas_libraries():
            threads = library.get_num_threads()
            if threads != 1:
                library.set_num_threads(1)
                restore.append((library, threads))
        self._restore = restore

    def __exit__(self, *error: object) -> None:
        for library, threads in self._restore:
            library.set_num_threads(threads)


def one_blas_thread() -> AbstractContextManager[None]:
    """Run the block with the loaded BLAS libraries on one thread, then restore their thread
    counts. The setting is process-wide: another Python thread's BLAS calls during the block
    also run on one thread."""
    return _OneBlasThread()
