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
floating-point tolerance; ``tests/test_kernels.py`` checks both against the terms' definitions in
:mod:`fpg_gym.reconstruct.energy`, with numba and without).

The tables are plain arrays, so a batched caller (many streams) stacks them
(:func:`stack_tables`: a leading axis of S frames) and evaluates S frames' points ``(S, n, d)``
with one call of the same kernel.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module

__all__ = [
    "KERNELS",
    "EnergyTables",
    "available_kernels",
    "bind_energy",
    "compile_kernels",
    "compiled_arguments",
    "fused_energy",
    "numpy_energy",
    "resolve_kernel",
    "stack_tables",
]

#: Kernel names: ``"auto"`` picks ``"numba"`` when it is installed, else ``"numpy"``.
KERNELS: tuple[str, ...] = ("auto", "numba", "numpy")

_BONE_COORDS = 3 * skeleton.NUM_BONES


@dataclass(frozen=True)
class EnergyTables:
    """One frame's energy as a fixed matrix and constants (see the module docstring).

    ``E(z) = rowdot(P[:, :d], z) + P[:, d] + c0 + min_k (P[:, d+1+k] + ycst[k])
    + wk * sum_b (|P[:, bones_b] + b0_b| - lengths_b)^2`` with ``P = z @ matrix``.

    One frame, or S frames stacked (:func:`stack_tables`): then every array has a leading axis
    S and ``c0`` is an array ``(S,)``.

    Attributes
    ----------
    matrix : ndarray, shape (d, d + 1 + K + 57), C-contiguous
        Weighted quadratic form (``d`` columns), linear term (1), ``Es`` inner products
        (``K``, scaled by ``-2 w_s / 20``), bone vectors' linear part (57).
    c0 : float or ndarray of shape (S,)
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
    c0: float | np.ndarray
    ycst: np.ndarray
    b0: np.ndarray
    lengths: np.ndarray
    wk: float

    @property
    def dim(self) -> int:
        """Latent dimension ``d``."""
        return int(self.matrix.shape[-2])

    @property
    def k(self) -> int:
        """Number of candidates ``K`` of ``Es``."""
        return int(self.ycst.shape[-1])

    @property
    def stacked(self) -> bool:
        """Whether these are S frames' tables (:func:`stack_tables`)."""
        return self.matrix.ndim == 3

    def __len__(self) -> int:
        """Frames stacked (1 for one frame's tables)."""
        return int(self.matrix.shape[0]) if self.stacked else 1

    def select(self, frames: np.ndarray) -> EnergyTables:
        """The stacked tables of the given frames (indices into this stack)."""
        if not self.stacked:
            raise ValueError("select: expected stacked tables (stack_tables), got one frame's")
        return EnergyTables(
            self.matrix[frames],
            np.asarray(self.c0)[frames],
            self.ycst[frames],
            self.b0[frames],
            self.lengths[frames],
            self.wk,
        )

    def astype(self, dtype: Any) -> EnergyTables:
        """The same tables in another floating-point precision."""
        t = np.dtype(dtype)
        return EnergyTables(
            np.ascontiguousarray(self.matrix, dtype=t),
            np.asarray(self.c0, dtype=t) if self.stacked else float(self.c0),
            self.ycst.astype(t),
            self.b0.astype(t),
            self.lengths.astype(t),
            float(self.wk),
        )


def stack_tables(frames: Sequence[EnergyTables]) -> EnergyTables:
    """S frames' tables (equal ``d``, ``K``, dtype and ``wk``) stacked along a leading axis.

    Raises
    ------
    ValueError
        On an empty sequence, or tables whose shapes, dtype or ``wk`` differ.
    """
    if not frames:
        raise ValueError("frames: expected at least one EnergyTables, got none")
    first = frames[0]
    for i, t in enumerate(frames):
        if (
            t.stacked
            or t.matrix.shape != first.matrix.shape
            or t.matrix.dtype != first.matrix.dtype
        ):
            raise ValueError(
                f"frames[{i}]: expected one frame's tables of shape {first.matrix.shape} "
                f"({first.matrix.dtype}), got {t.matrix.shape} ({t.matrix.dtype})"
            )
        if t.wk != first.wk:
            raise ValueError(f"frames[{i}]: expected wk {first.wk} (the same weights), got {t.wk}")
    dtype = first.matrix.dtype
    return EnergyTables(
        np.stack([t.matrix for t in frames]),
        np.array([t.c0 for t in frames], dtype=dtype),
        np.stack([t.ycst for t in frames]),
        np.stack([t.b0 for t in frames]),
        np.stack([t.lengths for t in frames]),
        first.wk,
    )


# --------------------------------------------------------------------------- numpy kernel


def numpy_energy(z: np.ndarray, tables: EnergyTables) -> np.ndarray:
    """The fused energy in numpy: points ``(n, d)`` -> ``(n,)`` in the tables' dtype, or
    ``(S, n, d)`` -> ``(S, n)`` with stacked tables."""
    d, k = tables.dim, tables.k

    def per_frame(a: Any) -> Any:  # a frame's constant, broadcast over its points
        return np.asarray(a)[:, None] if tables.stacked else a

    p = z @ tables.matrix
    energy = np.einsum("...nd,...nd->...n", p[..., :d], z)  # quadratic form (Ec, Em, Ep, |u|^2)
    energy += p[..., d]
    energy += per_frame(tables.c0)
    energy += (p[..., d + 1 : d + 1 + k] + per_frame(tables.ycst)).min(axis=-1)  # Es, Eq. 12
    bones = p[..., d + 1 + k :]
    bones += per_frame(tables.b0)
    bones *= bones
    length = np.sqrt(bones.reshape(*z.shape[:-1], skeleton.NUM_BONES, 3).sum(axis=-1))
    length -= per_frame(tables.lengths)
    energy += tables.wk * np.einsum("...b,...b->...", length, length)  # Ek, Eq. 13
    return energy


# --------------------------------------------------------------------------- numba kernel


def _numba_kernels() -> tuple[Callable[..., np.ndarray], Callable[..., np.ndarray]] | None:
    """The compiled energy kernels (one frame, S stacked frames;
    :mod:`fpg_gym.reconstruct.compiled_kernels`), or None without numba."""
    compiled = compiled_module("fpg_gym.reconstruct.compiled_kernels")
    return None if compiled is None else (compiled.fused_kernel, compiled.stacked_fused_kernel)


def available_kernels() -> tuple[str, ...]:
    """The kernels this installation can run (``"numpy"`` always)."""
    return ("numba", "numpy") if _numba_kernels() is not None else ("numpy",)


def compile_kernels() -> tuple[str, ...]:
    """Compile (or load from the disk cache) the available kernels, for one frame and for
    stacked frames in float64, now rather than on the first frame; returns their names."""
    tables = EnergyTables(
        np.zeros((1, 2 + 1 + _BONE_COORDS)),
        0.0,
        np.zeros(1),
        np.zeros(_BONE_COORDS),
        np.zeros(skeleton.NUM_BONES),
        0.0,
    )
    stacked = stack_tables([tables])
    for name in available_kernels():
        fused_energy(np.zeros((1, 1)), tables, name)
        fused_energy(np.zeros((1, 1, 1)), stacked, name)
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
    if name == "numba" and _numba_kernels() is None:
        raise ValueError("kernel: 'numba' needs numba (pip install 'fpg-gym[fast]')")
    return name


def bind_energy(tables: EnergyTables, kernel: str = "auto") -> Callable[[np.ndarray], np.ndarray]:
    """:func:`fused_energy` of ``tables`` as a function of the points alone, with the kernel
    resolved and its arguments converted once (the search calls it every iteration).

    Parameters
    ----------
    tables : EnergyTables
        One frame's, or S frames' stacked.
    kernel : {"auto", "numba", "numpy"}

    Returns
    -------
    callable
        ``energy(z)``: points ``(n, d)`` -> ``(n,)``, or ``(S, n, d)`` -> ``(S, n)`` with
        stacked tables, in the tables' dtype.
    """
    compiled = _numba_kernels() if resolve_kernel(kernel) == "numba" else None
    if compiled is None:
        return functools.partial(_numpy_energy_of, tables)
    function = compiled[1] if tables.stacked else compiled[0]
    arguments = compiled_arguments(tables)

    def energy(z: np.ndarray) -> np.ndarray:
        return function(np.ascontiguousarray(z), *arguments)

    return energy


def compiled_arguments(tables: EnergyTables) -> tuple[Any, ...]:
    """``(matrix, c0, ycst, b0, lengths, wk)`` as the compiled kernels take them: the scalars
    in the tables' dtype (``c0`` an array for stacked tables)."""
    dtype = tables.matrix.dtype.type
    c0 = np.asarray(tables.c0) if tables.stacked else dtype(tables.c0)
    return (tables.matrix, c0, tables.ycst, tables.b0, tables.lengths, dtype(tables.wk))


def _numpy_energy_of(tables: EnergyTables, z: np.ndarray) -> np.ndarray:
    """:func:`numpy_energy` with the tables first (for :func:`functools.partial`)."""
    return numpy_energy(z, tables)


def fused_energy(z: np.ndarray, tables: EnergyTables, kernel: str = "auto") -> np.ndarray:
    """Total energy (Shum Eq. 10) of latent points ``(n, d)`` -> ``(n,)``, or of S frames'
    points ``(S, n, d)`` -> ``(S, n)`` with stacked tables (:func:`stack_tables`).

    Parameters
    ----------
    z : ndarray, shape (n, d) or (S, n, d)
        Whitened latent points in the tables' dtype (float64 or float32), C-contiguous.
    tables : EnergyTables
    kernel : {"auto", "numba", "numpy"}

    Returns
    -------
    ndarray, shape (n,) or (S, n)
        In the tables' dtype.
    """
    return bind_energy(tables, kernel)(z)
