"""The search's inner loop: the energy of a batch of latent points as one fused kernel.

Every term of Shum Eq. 10 is a function of the decoded pose ``x = mean + z @ C`` (``C`` the
latent ``components``, ``z`` whitened coordinates), and all but ``Ek`` are quadratic in ``z``:

* ``Ec = sum_i w_i (x_i - s_i)^2 = z^T (C W C^T) z + 2 (C W (m - s)) . z + (m - s)^T W (m - s)``
  (Eq. 11, ``W = diag(R)`` repeated per coordinate); ``Em`` (Eq. 14) the same with the motion
  target and ``W = I / 20``; ``Ep = |z|^2 / d``;
* ``Es`` (Eq. 12): ``|x - n|^2 = |u|^2 - 2 u . y_n + |y_n|^2 + |r_n|^2`` with ``u = std * z``,
  ``y_n`` the neighbour's unwhitened coordinates and ``r_n`` its residual outside the space, so
  ``min_n`` only needs the ``K`` inner products ``u . y_n``;
* ``Ek`` (Eq. 13): bone vectors are linear in ``z``: ``b = b0 + z @ C_b``.

So the total energy of ``n`` points is one matrix product ``P = z @ M`` with a fixed ``(d, d + 1
+ K + 57)`` matrix (the weighted quadratic form, its linear term, the ``Es`` inner products and
the bone vectors) followed by cheap per-row reductions. :class:`EnergyTables` holds ``M`` and the
constants of one frame; :func:`fused_energy` evaluates it, with a compiled (numba) kernel when
``fpg-gym[fast]`` is installed and a fused numpy kernel otherwise (same maths, same results to
floating-point tolerance; ``tests/reference_energy.py`` keeps the previous implementation and the
tests compare them).

The tables are plain arrays, so a batched caller (many streams) can stack them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym import skeleton

__all__ = [
    "KERNELS",
    "EnergyTables",
    "available_kernels",
    "compile_kernels",
    "fused_energy",
    "numpy_energy",
    "resolve_kernel",
]

#: Kernel names: ``"auto"`` picks ``"numba"`` when it is installed, else ``"numpy"``.
KERNELS: tuple[str, ...] = ("auto", "numba", "numpy")

_BONE_COORDS = 3 * skeleton.NUM_BONES


@dataclass(frozen=True)
class EnergyTables:
    """One frame's energy as a fixed matrix and constants (see the module docstring).

    ``E(z) = rowdot(P[:, :d], z) + P[:, d] + c0 + min_k (P[:, d+1+k] + ycst[k])
    + wk * sum_b (|P[:, bones_b] + b0_b| - lengths_b)^2`` with ``P = z @ matrix``.

    Attributes
    ----------
    matrix : ndarray, shape (d, d + 1 + K + 57), C-contiguous
        Weighted quadratic form (``d`` columns), linear term (1), ``Es`` inner products
        (``K``, scaled by ``-2 w_s / 20``), bone vectors' linear part (57).
    c0 : float
        Constant of the quadratic terms.
    ycst : ndarray, shape (K,)
        ``w_s / 20 (|y_n|^2 + |r_n|^2)``.
    b0 : ndarray, shape (57,)
        Bone vectors of the latent mean.
    lengths : ndarray, shape (19,)
        Reference bone lengths ``l_db``.
    wk : float
        ``w_k / 19`` (the mean over bones).
    """

    matrix: np.ndarray
    c0: float
    ycst: np.ndarray
    b0: np.ndarray
    lengths: np.ndarray
    wk: float

    @property
    def dim(self) -> int:
        """Latent dimension ``d``."""
        return int(self.matrix.shape[0])

    @property
    def k(self) -> int:
        """Number of candidates ``K`` of ``Es``."""
        return len(self.ycst)

    def astype(self, dtype: Any) -> EnergyTables:
        """The same tables in another floating-point precision."""
        t = np.dtype(dtype)
        return EnergyTables(
            np.ascontiguousarray(self.matrix, dtype=t),
            float(self.c0),
            self.ycst.astype(t),
            self.b0.astype(t),
            self.lengths.astype(t),
            float(self.wk),
        )


# --------------------------------------------------------------------------- numpy kernel


def numpy_energy(z: np.ndarray, tables: EnergyTables) -> np.ndarray:
    """The fused energy in numpy: points ``(n, d)`` -> ``(n,)`` in the tables' dtype."""
    d, k = tables.dim, tables.k
    p = z @ tables.matrix
    energy = np.einsum("nd,nd->n", p[:, :d], z)  # quadratic form (Ec, Em, Ep, |u|^2 of Es)
    energy += p[:, d]
    energy += tables.c0
    energy += (p[:, d + 1 : d + 1 + k] + tables.ycst).min(axis=1)  # Es, Eq. 12
    bones = p[:, d + 1 + k :]
    bones += tables.b0
    bones *= bones
    length = np.sqrt(bones.reshape(len(z), skeleton.NUM_BONES, 3).sum(axis=2))
    length -= tables.lengths
    energy += tables.wk * np.einsum("nb,nb->n", length, length)  # Ek, Eq. 13
    return energy


# --------------------------------------------------------------------------- numba kernel


@functools.lru_cache(maxsize=1)
def _numba_kernel() -> Callable[..., np.ndarray] | None:
    """The compiled kernel, or None without numba (compiled on first use, cached on disk)."""
    try:
        import numba  # optional extra fpg-gym[fast]
    except ImportError:
        return None

    @numba.njit(cache=True, nogil=True)
    def kernel(z, matrix, c0, ycst, b0, lengths, wk):
        p = z @ matrix
        n, d = z.shape
        k = ycst.shape[0]
        bones = lengths.shape[0]
        out = np.empty(n, dtype=z.dtype)
        for i in range(n):
            e = c0 + p[i, d]
            for j in range(d):
                e += p[i, j] * z[i, j]
            best = np.inf
            for m in range(k):
                v = p[i, d + 1 + m] + ycst[m]
                if v < best:
                    best = v
            s = 0.0
            base = d + 1 + k
            for b in range(bones):
                c = base + 3 * b
                x = p[i, c] + b0[3 * b]
                y = p[i, c + 1] + b0[3 * b + 1]
                w = p[i, c + 2] + b0[3 * b + 2]
                diff = np.sqrt(x * x + y * y + w * w) - lengths[b]
                s += diff * diff
            out[i] = e + best + wk * s
        return out

    return kernel


def available_kernels() -> tuple[str, ...]:
    """The kernels this installation can run (``"numpy"`` always)."""
    return ("numba", "numpy") if _numba_kernel() is not None else ("numpy",)


def compile_kernels() -> tuple[str, ...]:
    """Compile (or load from the disk cache) the available kernels now rather than on the first
    frame; returns their names."""
    tables = EnergyTables(
        np.zeros((1, 2 + 1 + _BONE_COORDS)),
        0.0,
        np.zeros(1),
        np.zeros(_BONE_COORDS),
        np.zeros(skeleton.NUM_BONES),
        0.0,
    )
    for name in available_kernels():
        fused_energy(np.zeros((1, 1)), tables, name)
    return available_kernels()


def resolve_kernel(name: str) -> str:
    """``"auto"`` -> the fastest available kernel; checks the name.

    Raises
    ------
    ValueError
        On an unknown name, or ``"numba"`` without numba installed.
    """
    if name not in KERNELS:
        raise ValueError(f"kernel: expected one of {', '.join(KERNELS)}, got {name!r}")
    if name == "auto":
        return available_kernels()[0]
    if name == "numba" and _numba_kernel() is None:
        raise ValueError("kernel: 'numba' needs numba (pip install 'fpg-gym[fast]')")
    return name


def fused_energy(z: np.ndarray, tables: EnergyTables, kernel: str = "auto") -> np.ndarray:
    """Total energy (Shum Eq. 10) of latent points ``(n, d)`` -> ``(n,)``.

    Parameters
    ----------
    z : ndarray, shape (n, d)
        Whitened latent points in the tables' dtype (float64 or float32), C-contiguous.
    tables : EnergyTables
    kernel : {"auto", "numba", "numpy"}

    Returns
    -------
    ndarray, shape (n,)
        In the tables' dtype.
    """
    compiled = _numba_kernel() if resolve_kernel(kernel) == "numba" else None
    if compiled is None:
        return numpy_energy(z, tables)
    return compiled(
        np.ascontiguousarray(z),
        tables.matrix,
        tables.matrix.dtype.type(tables.c0),
        tables.ycst,
        tables.b0,
        tables.lengths,
        tables.matrix.dtype.type(tables.wk),
    )
