"""The natural posture space: a whitened local PCA of the K candidate poses (Shum §VI-C).

Each pose is a 60-vector (20 joints x 3). With ``mean`` the candidates' mean, ``basis`` the first
``d`` principal directions (rows, orthonormal) and ``std`` the spread of the candidates along
each of them, a whitened latent point ``z`` decodes to

``x = mean + (z * std) @ basis``

and a pose encodes to ``z = ((x - mean) @ basis.T) / std``. Every axis has unit variance over the
candidates, so every optimiser sees the same scale whatever the motion.

``d = min(max_dim, K - 1)`` (20 by default) so that the dimension depends only on K. Degenerate
axes (candidates that do not spread along them, e.g. duplicate poses) keep their place but get
the spread ``min_std`` (1 micrometre): moving along them changes the pose by a negligible amount
instead of dividing by zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.poses import as_poses
from fpg_gym.reconstruct.kernels import resolve_kernel
from fpg_gym.runtime.threads import one_blas_thread

POSE_SIZE = skeleton.NUM_JOINTS * 3

#: Largest ratio of the first to the d-th singular value for which :func:`principal_axes` takes
#: the axes from the Gram matrix (its directions then lose at most about 1e-8 to rounding).
GRAM_MAX_CONDITION = 1e4


def gram_eigenpairs(centred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.eigh`` of the Gram matrix ``C C^T`` of centred poses ``(K, 60)`` (eigenvalues
    ascending), on one BLAS thread (:func:`fpg_gym.runtime.threads.one_blas_thread`).

    LAPACK's ``dsyevd`` on the lower triangle, as ``np.linalg.eigh`` calls it, through scipy's
    wrapper (the same values and vectors to the bit, about 4 µs less of the 60 µs at K = 30);
    the vectors C-ordered, as numpy returns them."""
    with one_blas_thread():
        values, vectors, info = lapack.dsyevd(centred @ centred.T, compute_v=1, lower=1)
    if info != 0:  # numpy's error
        raise np.linalg.LinAlgError("Eigenvalues did not converge")
    return values, np.ascontiguousarray(vectors)


def principal_axes(
    centred: np.ndarray, dim: int, eigenpairs: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (descending) and the first ``dim`` right singular vectors of ``centred``.

    Parameters
    ----------
    centred : ndarray, shape (K, 60)
        Centred poses, float64.
    dim : int
        Axes wanted, ``1 <= dim <= min(K, 60)``.
    eigenpairs : tuple of ndarray, optional
        :func:`gram_eigenpairs` of ``centred`` when the caller has them already.

    Returns
    -------
    singular : ndarray, shape (min(K, 60),)
    basis : ndarray, shape (dim, 60)
        Orthonormal rows, signs as they come (the caller fixes them).

    Notes
    -----
    With no more poses than coordinates (K = 30 candidates by default), the eigenvectors
    ``u_i`` of the ``K x K`` Gram matrix ``C C^T`` give the axes ``C^T u_i / s_i`` for about
    60 % of the SVD's time (105 against 165-200 µs here for K = 30). Their rounding grows as
    ``(s_1 / s_d)^2``, so they are used only while ``s_1 / s_d <=``
    :data:`GRAM_MAX_CONDITION`; duplicate candidates or a flat spread take the SVD. On candidate
    sets of the Bandai graph the two agree to 2.3e-13 (basis) and 2e-15 (relative spread).
    """
    count = len(centred)
    if count <= centred.shape[1]:
        values, vectors = gram_eigenpairs(centred) if eigenpairs is None else eigenpairs
        singular = np.sqrt(np.maximum(values[::-1], 0.0))
        if singular[dim - 1] > 0.0 and singular[0] <= GRAM_MAX_CONDITION * singular[dim - 1]:
            basis = (vectors[:, ::-1][:, :dim].T @ centred) / singular[:dim, None]
            return singular, basis
    with one_blas_thread():
        _, singular, vt = np.linalg.svd(centred, full_matrices=False)
    return singular, vt[:dim].copy()


@dataclass(frozen=True)
class LatentSpace:
    """A whitened PCA space fitted to a few poses.

    Attributes
    ----------
    mean : ndarray, shape (60,)
        Mean of the fitted poses.
    basis : ndarray, shape (d, 60)
        Orthonormal principal directions, strongest first.
    std : ndarray, shape (d,)
        Spread (sample standard deviation) of the fitted poses along each direction, floored at
        ``min_std``.
    degenerate : ndarray, shape (d,), bool
        Axes whose spread was below ``min_std``.
    explained_variance_ratio : float
        Share of the fitted poses' variance the ``d`` axes keep.
    """

    mean: np.ndarray
    basis: np.ndarray
    std: np.ndarray
    degenerate: np.ndarray
    explained_variance_ratio: float

    @property
    def dim(self) -> int:
        """Latent dimension ``d``."""
        return int(self.basis.shape[0])

    @property
    def components(self) -> np.ndarray:
        """``(d, 60)``: ``basis`` scaled by ``std`` (decode is ``mean + z @ components``)."""
        return self.basis * self.std[:, None]

    @classmethod
    def fit(
        cls, poses: np.ndarray, max_dim: int = 20, min_std: float = 1e-6, kernel: str = "auto"
    ) -> LatentSpace:
        """PCA of ``poses`` ``(K, 20, 3)`` with ``d = min(max_dim, K - 1)`` whitened axes.

        The sign of each direction is fixed (its largest-magnitude entry is positive) so that the
        same poses always give the same space. ``kernel`` (``"auto"``, ``"numba"``,
        ``"numpy"``): ``"numba"`` takes the axes from the Gram matrix's eigenpairs in one compiled
        call (:func:`fpg_gym.reconstruct.compiled_frame.whitened_axes`; the same result to
        rounding), ``"auto"`` when numba is installed.

        Raises
        ------
        ValueError
            If ``poses`` is not ``(K, 20, 3)`` with K >= 1, or ``max_dim`` < 0.
        """
        if max_dim < 0:
            raise ValueError(f"max_dim: expected >= 0, got {max_dim}")
        if min_std <= 0:
            raise ValueError(f"min_std: expected > 0, got {min_std}")
        array = np.asarray(poses, dtype=np.float32)
        count = len(array) if array.ndim else 0
        dim = min(max_dim, count - 1, POSE_SIZE)
        compiled = (
            compiled_module("fpg_gym.reconstruct.compiled_frame")
            if 0 < dim and count <= POSE_SIZE and resolve_kernel(kernel) == "numba"
            else None
        )
        centred = None
        if compiled is not None and array.shape[1:] == (skeleton.NUM_JOINTS, 3):
            # the checks, the mean and the centring in one call (numpy's to the bit)
            mean, centred, finite = compiled.centre_poses(np.ascontiguousarray(array))
            if not finite:
                centred = None  # as_poses below names the value
        if centred is None:
            data = as_poses(array, "poses", ndim=3).reshape(-1, POSE_SIZE).astype(np.float64)
            if len(data) == 0:
                raise ValueError("poses: expected at least one pose, got 0")
            mean = data.mean(axis=0)
            centred = data - mean
        eigenpairs = None
        if compiled is not None:
            eigenpairs = gram_eigenpairs(centred)
            basis, std, degenerate, ratio, usable = compiled.whitened_axes(
                centred, *eigenpairs, dim, min_std, GRAM_MAX_CONDITION
            )
            if usable:  # else principal_axes takes the SVD, from the same eigenpairs
                return cls(mean, basis, std, degenerate, float(ratio))
        if dim == 0:
            return cls(mean, np.zeros((0, POSE_SIZE)), np.zeros(0), np.zeros(0, bool), 1.0)
        singular, basis = principal_axes(centred, dim, eigenpairs)
        signs = np.sign(basis[np.arange(dim), np.argmax(np.abs(basis), axis=1)])
        basis *= np.where(signs == 0, 1.0, signs)[:, None]
        spread = np.zeros(dim)
        kept = min(dim, len(singular))
        spread[:kept] = singular[:kept] / np.sqrt(count - 1)
        degenerate = spread < min_std
        total = float(np.sum(singular**2))
        ratio = float(np.sum(singular[:kept] ** 2) / total) if total > 0 else 1.0
        return cls(mean, basis, np.maximum(spread, min_std), degenerate, ratio)

    def encode(self, poses: np.ndarray) -> np.ndarray:
        """Whitened coordinates of poses ``(..., 20, 3) -> (..., d)``."""
        x = np.asarray(poses, dtype=np.float64).reshape(*np.shape(poses)[:-2], POSE_SIZE)
        return ((x - self.mean) @ self.basis.T) / self.std

    def decode(self, z: np.ndarray) -> np.ndarray:
        """Poses of whitened coordinates ``(..., d) -> (..., 20, 3)`` float64."""
        z = np.asarray(z, dtype=np.float64)
        if z.shape[-1:] != (self.dim,):
            raise ValueError(f"z: expected shape (..., {self.dim}), got {z.shape}")
        x = self.mean + (z * self.std) @ self.basis
        return x.reshape(*z.shape[:-1], skeleton.NUM_JOINTS, 3)

    def project(self, poses: np.ndarray) -> np.ndarray:
        """The closest poses in the space (encode then decode)."""
        return self.decode(self.encode(poses))
