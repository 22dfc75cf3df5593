"""The paper's local search compiled (numba) as one kernel; imported only when ``fpg-gym[fast]``
is installed (:mod:`fpg_gym.reconstruct.search` falls back to the ask/tell loop without it).

:func:`local_search` is :class:`optimizers.local_search.LocalSearch` run by
:func:`optimizers.run_optimizer` on a frame's fused energy (:mod:`fpg_gym.reconstruct.kernels`),
step for step: the same draws from the same generator (the table's uniforms drawn before the
call, the normal draws in numba, which runs numpy's algorithms on the generator's own bit
generator; the generator ends in the same state), the same rows of the
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
from numba import types
from numba.extending import overload

from fpg_gym.core.compiled import JIT_OPTIONS
from fpg_gym.reconstruct.compiled_kernels import energy_rows

__all__ = ["local_search"]

#: :func:`local_search`'s status: the search ended normally.
STATUS_OK = 0
#: :func:`local_search`'s status: a proposed point was not finite (the search stopped there).
STATUS_NON_FINITE = 1


def _uniforms(draws, batch, count):
    """Batch ``batch``'s ``count`` uniform draws: from the generator now, or row ``batch`` of
    the draws drawn before."""
    return draws[batch] if isinstance(draws, np.ndarray) else draws.random(count)


@overload(_uniforms)
def _uniforms_overload(draws, batch, count):
    if isinstance(draws, types.Array):
        return lambda draws, batch, count: draws[batch]
    return lambda draws, batch, count: draws.random(count)


def _normals(draws, batch, samples, d):
    """Batch ``batch``'s ``(samples, d)`` standard normal draws: from the generator now, or
    row ``batch`` of the draws drawn before."""
    if isinstance(draws, np.ndarray):
        return draws[batch].reshape((samples, d))
    return draws.standard_normal((samples, d))


@overload(_normals)
def _normals_overload(draws, batch, samples, d):
    if isinstance(draws, types.Array):
        return lambda draws, batch, samples, d: draws[batch].reshape((samples, d))
    return lambda draws, batch, samples, d: draws.standard_normal((samples, d))


@numba.njit(**JIT_OPTIONS)
def _proposals(draws, batch, table, step, samples, signed):
    """Where batch ``batch``'s ``samples`` points ``center + step * N(0, I)`` come from: rows
    ``start, ...`` of the returned array scaled per axis by ``signed`` (``d``, filled here);
    fresh normal draws scaled by ``step``, or a block of ``table``'s rows at a uniform offset
    with a random sign per axis (``LocalSearch._from_table``)."""
    d = signed.shape[0]
    if table.shape[0] == 0:
        for j in range(d):
            signed[j] = step
        return _normals(draws, batch, samples, d), 0
    uniform = _uniforms(draws, batch, d + 1)  # the offset and a sign per axis
    for j in range(d):
        signed[j] = np.copysign(step, uniform[1 + j] - 0.5)
    return table, int(uniform[0] * (table.shape[0] - samples + 1))


@numba.njit(**JIT_OPTIONS)
def _coordinate(rows, start, signed, center, first, i, j):
    """Coordinate ``j`` of the batch's point ``i`` (float64): ``rows[start + i, j] *
    signed[j] + center[j]`` (``LocalSearch.ask``'s rounding), the centre itself for the
    first batch's first point (the start is scored)."""
    if first and i == 0:
        return center[j]
    return rows[start + i, j] * signed[j] + center[j]


@numba.njit(**JIT_OPTIONS)
def local_search(
    draws,
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
    draws : numpy.random.Generator or ndarray
        The optimiser's generator (advanced as the ask/tell loop advances it), or the draws of
        the batches drawn from it before, a row per batch: ``(batches, d + 1)`` uniforms with
        the table (``Generator.random``), ``(batches, samples * d)`` standard normals without.
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
    d = x0.shape[0]
    signed = np.empty(d)  # the batch's scale per axis
    points = np.empty((samples, d), dtype=matrix.dtype)  # the batch in the tables' dtype
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
        first = iteration == 0
        iteration += 1
        # the batch's index as iteration - 1: a variable that starts at 0 would also compile
        # _proposals for the literal 0
        rows, start = _proposals(draws, iteration - 1, table, current_step, samples, signed)
        admitted = samples if left < 0 else min(samples, left)
        # the points in the tables' dtype at once (the float64 point rounded, as astype)
        for i in range(admitted):
            for j in range(d):
                points[i, j] = rows[start + i, j] * signed[j] + center[j]
        if first:  # the start is scored
            for j in range(d):
                points[0, j] = center[j]
        # numba's ``points @ matrix`` is this gemm into a new array
        np.dot(points[:admitted], matrix, product[:admitted])
        rows_p = product[:admitted]  # only the first lowest row counts (the argmins below)
        energy_rows(
            rows_p,
            points[:admitted],
            c0,
            ycst,
            b0,
            lengths,
            wk,
            energies[:admitted],
            np.bool_(True),
        )
        finite = True
        for i in range(admitted):
            values[i] = energies[i]
            finite = finite and np.isfinite(values[i])
        if not finite:  # element loops: np.all(np.isfinite(...)) compiles numba's reductions
            for i in range(admitted):
                for j in range(d):
                    if not np.isfinite(_coordinate(rows, start, signed, center, first, i, j)):
                        return best_x, best, evaluations, asks, STATUS_NON_FINITE
        evaluations += admitted
        # numba's np.argmin is numpy's: the first NaN, else the first minimum. The run's best
        # point; also the optimiser's tell (whose clipped rows count as +inf: the same row).
        row = np.argmin(values[:admitted])
        if values[row] < best:
            best = values[row]
            for j in range(d):
                best_x[j] = _coordinate(rows, start, signed, center, first, row, j)
        if values[row] < centre_energy:
            centre_energy = values[row]
            for j in range(d):  # each coordinate from its own old value
                center[j] = _coordinate(rows, start, signed, center, first, row, j)
        elif shrink <= 0.0:
            done = True
        else:
            current_step *= shrink
            done = current_step < min_step
    return best_x, best, evaluations, asks, STATUS_OK
