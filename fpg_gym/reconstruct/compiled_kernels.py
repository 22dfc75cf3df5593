"""The fused energy's compiled (numba) kernels; imported only when ``fpg-gym[fast]`` is installed.

Module-level functions so that numba's disk cache (``cache=True``) finds them again in a new
process (functions defined inside a function, calling one another, are recompiled every time).
Both kernels run the same row loop, :func:`energy_rows`, on ``P = z @ matrix``, so one frame's
energies and S stacked frames' are equal to the last bit. The maths is documented in
:mod:`fpg_gym.reconstruct.kernels`.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import JIT_OPTIONS

__all__ = ["energy_rows", "fused_kernel", "stacked_fused_kernel"]


#: The skeleton's bones, a compile-time constant: the bone loop of :func:`energy_rows`
#: vectorises with a constant trip count.
_NUM_BONES = skeleton.NUM_BONES


@numba.njit(**JIT_OPTIONS, inline="always")
def _bone_errors(bones, row, b0, lengths, diff):
    """Ek's (Eq. 13) ``|P[bone b] + b0_b| - lengths_b`` of one row's bone columns ``row``."""
    for b in range(bones):
        x = row[3 * b] + b0[3 * b]
        y = row[3 * b + 1] + b0[3 * b + 1]
        w = row[3 * b + 2] + b0[3 * b + 2]
        diff[b] = np.sqrt(x * x + y * y + w * w) - lengths[b]


@numba.njit(**JIT_OPTIONS, inline="always")
def _lower(value, lowest):
    """``value`` if it is below ``lowest`` (a NaN is not), else ``lowest``."""
    return value if value < lowest else lowest


@numba.njit(**JIT_OPTIONS)
def _partial_rows(p, z, c0, ycst, partial):
    """Each row's energy before ``Ek``: ``z_i . P[i, :d] + P[i, d] + c0 + min_k (P[i, d+1+k] +
    ycst[k])`` into ``partial`` (float64, as :func:`energy_rows` sums it). Four rows side by
    side (the last block repeats the last row): each row's sums keep their order, so the
    values are those of one row at a time to the bit, and the four chains of additions
    overlap instead of each waiting for its last one."""
    n, d = z.shape
    k = ycst.shape[0]
    for i in range(0, n, 4):
        i1, i2, i3 = min(i + 1, n - 1), min(i + 2, n - 1), min(i + 3, n - 1)
        e0, e1, e2, e3 = c0 + p[i, d], c0 + p[i1, d], c0 + p[i2, d], c0 + p[i3, d]
        for j in range(d):
            e0 += p[i, j] * z[i, j]
            e1 += p[i1, j] * z[i1, j]
            e2 += p[i2, j] * z[i2, j]
            e3 += p[i3, j] * z[i3, j]
        best0 = best1 = best2 = best3 = np.inf
        for m in range(k):  # Es, Eq. 12
            column = d + 1 + m
            best0 = _lower(p[i, column] + ycst[m], best0)
            best1 = _lower(p[i1, column] + ycst[m], best1)
            best2 = _lower(p[i2, column] + ycst[m], best2)
            best3 = _lower(p[i3, column] + ycst[m], best3)
        partial[i3] = e3 + best3
        partial[i2] = e2 + best2
        partial[i1] = e1 + best1
        partial[i] = e0 + best0


@numba.njit(**JIT_OPTIONS)
def energy_rows(p, z, c0, ycst, b0, lengths, wk, out, lowest_only=False):
    """``out[i] = z_i . P[i, :d] + P[i, d] + c0 + min_k (P[i, d+1+k] + ycst[k]) + wk * sum_b
    (|P[i, bone b] + b0_b| - lengths_b)^2`` (Shum Eq. 10 as in the tables; ``p``, ``b0`` and
    ``lengths`` in one dtype, as the tables hold them).

    With ``lowest_only`` (a search that keeps only the first lowest row), a row whose sum
    before ``Ek`` is finite and above an earlier row's energy gets that sum instead: ``Ek``
    (``wk * sum_b ... >= 0``) cannot lower it, so the first lowest row, its energy and whether
    the energies are finite stay those of the full rows (unless the bone columns of ``P``
    overflow), and the row skips ``Ek``'s square roots."""
    n, d = z.shape
    k = ycst.shape[0]
    bones = lengths.shape[0]
    base = d + 1 + k
    diff = np.empty(bones, dtype=p.dtype)
    partial = np.empty(n)
    _partial_rows(p, z, c0, ycst, partial)
    lowest = np.inf
    skip = lowest_only and wk > 0.0
    for i in range(n):
        if skip and lowest < partial[i] < np.inf:
            out[i] = partial[i]
            continue
        # Ek, Eq. 13: the row's bone errors first (one vectorised loop for the skeleton's
        # bones), then their squares summed in order (the same result to the bit)
        row = p[i, base : base + 3 * bones]
        if bones == _NUM_BONES:
            _bone_errors(_NUM_BONES, row, b0, lengths, diff)
        else:
            _bone_errors(bones, row, b0, lengths, diff)
        s = 0.0
        for b in range(bones):
            s += diff[b] * diff[b]
        out[i] = partial[i] + wk * s
        if out[i] < lowest:
            lowest = out[i]


@numba.njit(**JIT_OPTIONS)
def fused_kernel(z, matrix, c0, ycst, b0, lengths, wk):
    """One frame: points ``(n, d)`` -> ``(n,)``."""
    out = np.empty(z.shape[0], dtype=z.dtype)
    energy_rows(z @ matrix, z, c0, ycst, b0, lengths, wk, out, np.bool_(False))
    return out


@numba.njit(**JIT_OPTIONS)
def stacked_fused_kernel(z, matrix, c0, ycst, b0, lengths, wk):
    """S stacked frames: points ``(S, n, d)`` -> ``(S, n)``."""
    out = np.empty(z.shape[:2], dtype=z.dtype)
    for f in range(z.shape[0]):
        energy_rows(
            z[f] @ matrix[f], z[f], c0[f], ycst[f], b0[f], lengths[f], wk, out[f], np.bool_(False)
        )
    return out
