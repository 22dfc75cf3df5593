"""The paper's local search compiled (numba) as one kernel; imported only when ``fpg-gym[fast]``
is installed (:mod:`fpg_gym.reconstruct.search` falls back to the ask/tell loop without it).

:func:`local_search` is :class:`optimizers.local_search.LocalSearch` run by
:func:`optimizers.run_optimizer` on a frame's fused energy (:mod:`fpg_gym.reconstruct.kernels`),
step for step: the same draws from the same generator (numba runs numpy's algorithms on the
generator's own bit generator, so the generator ends in the same state), the same rows of the
proposal table, the same budget rule (a batch larger than the evaluations left is clipped, its
other rows count as ``+inf``), the same energies (:func:`energy_rows` on ``z @ matrix``, as
:func:`fpg_gym.reconstruct.compiled_kernels.fused_kernel`, except that a row that cannot be the
lowest skips ``Ek``: ``lowest_only``) and the same ``argmin`` (the first NaN, else the first
minimum). Its best point equals the ask/tell loop's to the last bit; the
tests check it. What it saves is the interpreter: about 40 numpy calls per batch of 100 points.

Module-level functions so that numba's disk cache (``cache=True``) finds them in a new process.
"""

from __future__ import annotations

import numba
import numpy as np
from numba.extending import overload

from fpg_gym.core.compiled import JIT_OPTIONS
from fpg_gym.reconstruct.compiled_kernels import energy_rows

__all__ = ["local_search"]

#: :func:`local_search`'s status: the search ended normally.
STATUS_OK = 0
#: :func:`local_search`'s status: a proposed point was not finite (the search stopped there).
STATUS_NON_FINITE = 1


def _as_dtype_of(points, matrix):
    """``points`` in ``matrix``'s dtype: themselves when they are in it already, else a copy."""
    return points.astype(matrix.dtype)


@overload(_as_dtype_of)
def _as_dtype_of_overload(points, matrix):
    if points.dtype == matrix.dtype:
        return lambda points, matrix: points
    return lambda points, matrix: points.astype(matrix.dtype)


@numba.njit(**JIT_OPTIONS)
def _proposals(generator, table, center, step, samples):
    """``samples`` points ``center + step * N(0, I)``: drawn now, or a block of ``table``'s
    rows at a uniform offset with a random sign per axis (``LocalSearch._from_table``)."""
    d = center.shape[0]
    if table.shape[0] == 0:
        z = generator.standard_normal((samples, d))
        for i in range(samples):
            for j in range(d):
                z[i, j] *= step
    else:
        uniform = generator.random(d + 1)  # the offset and a sign per axis
        start = int(uniform[0] * (table.shape[0] - samples + 1))
        signed = np.empty(d)
        for j in range(d):
            signed[j] = np.copysign(step, uniform[1 + j] - 0.5)
        z = np.empty((samples, d))
        for i in range(samples):
            row = table[start + i]
            for j in range(d):
                z[i, j] = row[j] * signed[j] + center[j]
        return z
    # Element loops here and below: array-wide assignments compile numba's shape-error
    # messages (seconds of compilation on a fresh install).
    for i in range(samples):
        for j in range(d):
            z[i, j] += center[j]
    return z


@numba.njit(**JIT_OPTIONS)
def local_search(
    generator,
    table,
    x0,
    matrix,
    c0,
    ycst,
    b0,
    lengths,
    wk,
    samples,
    iterations,
    step,
    shrink,
    min_step,
    max_evaluations,
    max_asks,
):
    """Local search (Shum §VI-E) on one frame's fused energy (Eq. 10).

    Parameters
    ----------
    generator : numpy.random.Generator
        The optimiser's generator (advanced as the ask/tell loop advances it).
    table : ndarray, shape (rows, d) or (0, d)
        The proposal table, or no rows for fresh normal draws.
    x0 : ndarray, shape (d,), float64
    matrix, c0, ycst, b0, lengths, wk
        The frame's :class:`~fpg_gym.reconstruct.kernels.EnergyTables` (float64 or float32).
    samples, iterations, step, shrink, min_step
        :class:`~optimizers.local_search.LocalSearch`'s parameters; ``shrink <= 0`` is None
        (stop at the first batch without improvement).
    max_evaluations, max_asks : int
        The budget; negative is unlimited.

    Returns
    -------
    best_x : ndarray, shape (d,)
    best : float
        Its energy (``inf`` when nothing was evaluated).
    evaluations, asks : int
        As :class:`optimizers.SearchResult` counts them.
    status : int
        :data:`STATUS_OK` or :data:`STATUS_NON_FINITE`.
    """
    center = x0.copy()
    best_x = x0.copy()
    best = np.inf
    centre_energy = np.inf
    current_step = step
    evaluations = asks = iteration = 0
    done = False  # the optimiser's own stop (it answers None to the next ask)
    energies = np.empty(samples, dtype=matrix.dtype)
    product = np.empty((samples, matrix.shape[1]), dtype=matrix.dtype)  # z @ matrix
    values = np.empty(samples)
    while True:
        left = max_evaluations - evaluations if max_evaluations >= 0 else -1
        if left == 0 or (max_asks >= 0 and asks >= max_asks):
            break
        asks += 1
        if done or iteration >= iterations:  # the optimiser's None
            break
        z = _proposals(generator, table, center, current_step, samples)
        if iteration == 0:
            for j in range(center.shape[0]):  # the start is scored
                z[0, j] = center[j]
        iteration += 1
        admitted = samples if left < 0 else min(samples, left)
        points = _as_dtype_of(z[:admitted], matrix)
        # numba's ``points @ matrix`` is this gemm into a new array
        np.dot(points, matrix, product[:admitted])
        rows = product[:admitted]  # only the first lowest row counts (the argmins below)
        energy_rows(rows, points, c0, ycst, b0, lengths, wk, energies[:admitted], np.bool_(True))
        finite = True
        for i in range(admitted):
            values[i] = energies[i]
            finite = finite and np.isfinite(values[i])
        if not finite:  # element loops: np.all(np.isfinite(...)) compiles numba's reductions
            for i in range(admitted):
                for j in range(z.shape[1]):
                    if not np.isfinite(z[i, j]):
                        return best_x, best, evaluations, asks, STATUS_NON_FINITE
        for i in range(admitted, samples):
            values[i] = np.inf
        evaluations += admitted
        # numba's np.argmin is numpy's: the first NaN, else the first minimum
        row = np.argmin(values[:admitted])  # the run's best point
        if values[row] < best:
            best = values[row]
            for j in range(best_x.shape[0]):
                best_x[j] = z[row, j]
        row = np.argmin(values)  # the optimiser's tell
        if values[row] < centre_energy:
            centre_energy = values[row]
            for j in range(center.shape[0]):
                center[j] = z[row, j]
        elif shrink <= 0.0:
            done = True
        else:
            current_step *= shrink
            done = current_step < min_step
    return best_x, best, evaluations, asks, STATUS_OK
