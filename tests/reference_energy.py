"""The previous latent energy (``EnergyModel`` before issue 18), kept as the tests' reference.

The package computes the same terms with :mod:`fpg_gym.reconstruct.kernels`; tests assert that
both agree to floating-point tolerance on random problems, and the bench script can time both.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.reconstruct.energy import EnergyWeights
from fpg_gym.reconstruct.latent import POSE_SIZE, LatentSpace

# --------------------------------------------------------------------------- latent fast path

# Ek: bone vectors are linear in the flat pose x (60,): child minus parent coordinates.
_CHILD_COORDS = (3 * skeleton.BONES[:, 1][:, None] + np.arange(3)).reshape(-1)
_PARENT_COORDS = (3 * skeleton.BONES[:, 0][:, None] + np.arange(3)).reshape(-1)


class ReferenceEnergyModel:
    """The energy of one frame as a function of whitened latent points (previous implementation).

    Parameters
    ----------
    latent : LatentSpace
    sensor : ndarray, shape (20, 3)
        Normalised sensor pose ``p_k``.
    reliability : ndarray, shape (20,)
    neighbours : ndarray, shape (K, 20, 3)
        The selected candidates (what ``Es`` compares with).
    lengths : ndarray, shape (19,)
        Reference bone lengths ``l_db``.
    target : ndarray, shape (20, 3) or None
        Motion target for ``Em`` (see :func:`motion_target`); None gives ``Em = 0``.
    weights : EnergyWeights, optional
    dtype : numpy dtype
        Arithmetic precision (float64). ``float32`` is about 4x faster for batches of a few
        thousand points and ~20 % faster at 100; the terms are returned as float64 either way.
    """

    def __init__(
        self,
        latent: LatentSpace,
        sensor: np.ndarray,
        reliability: np.ndarray,
        neighbours: np.ndarray,
        lengths: np.ndarray,
        target: np.ndarray | None,
        weights: EnergyWeights | None = None,
        dtype: npt.DTypeLike = np.float64,
        kernel: str = "auto",  # accepted as the Reconstructor passes it; one path here
    ) -> None:
        del kernel
        self.dtype = np.dtype(dtype)
        if self.dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ValueError(f"dtype: expected float32 or float64, got {self.dtype}")
        self.latent = latent
        self.weights = weights or EnergyWeights()
        self._w = self.weights.as_array()
        self.sensor = np.asarray(sensor, dtype=np.float64).reshape(POSE_SIZE)
        self.reliability = np.asarray(reliability, dtype=np.float64)
        self.lengths = np.asarray(lengths, dtype=np.float64)
        self.target = None if target is None else np.asarray(target, dtype=np.float64).reshape(-1)
        self._joint_weights = np.repeat(self.reliability, 3)  # (60,) for Ec
        # Es: neighbours' unwhitened coordinates y_n (K, d) and squared residuals |r_n|^2 (K,).
        flat = np.asarray(neighbours, dtype=np.float64).reshape(len(neighbours), POSE_SIZE)
        centred = flat - latent.mean
        self._y = centred @ latent.basis.T
        self._y_sq = np.einsum("kd,kd->k", self._y, self._y)
        residual = centred - self._y @ latent.basis
        self._r_sq = np.einsum("kd,kd->k", residual, residual)
        self._std = latent.std
        # Working copies in the arithmetic precision.
        t = self.dtype
        self._w_sensor = self.sensor.astype(t)
        self._w_target = None if self.target is None else self.target.astype(t)
        self._w_lengths = self.lengths.astype(t)
        self._mean = latent.mean.astype(t)
        self._components = latent.components.astype(t)  # (d, 60)
        self._joint_weights = self._joint_weights.astype(t)
        self._y, self._y_sq, self._r_sq = (
            self._y.astype(t),
            self._y_sq.astype(t),
            self._r_sq.astype(t),
        )
        self._std = self._std.astype(t)

    def decode_flat(self, z: np.ndarray) -> np.ndarray:
        """Poses as 60-vectors ``(n, 60)`` for latent points ``(n, d)`` (in ``dtype``)."""
        return self._mean + np.asarray(z, dtype=self.dtype) @ self._components

    def terms(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """``Ec``, ``Es``, ``Ek``, ``Em``, ``Ep`` for latent points ``(n, d)``, each ``(n,)``
        float64."""
        z = np.asarray(z, dtype=self.dtype)
        x = self.decode_flat(z)
        joints = skeleton.NUM_JOINTS
        diff = x - self._w_sensor
        ec = (diff * diff) @ self._joint_weights  # Eq. 11
        u = z * self._std  # unwhitened coordinates
        dist = (
            np.einsum("nd,nd->n", u, u)[:, None] - 2.0 * (u @ self._y.T) + self._y_sq + self._r_sq
        )
        es = np.maximum(dist.min(axis=1), 0.0) / joints  # Eq. 12
        bones = (x[:, _CHILD_COORDS] - x[:, _PARENT_COORDS]).reshape(len(x), skeleton.NUM_BONES, 3)
        length = np.sqrt(np.einsum("nbc,nbc->nb", bones, bones))
        ek = ((length - self._w_lengths) ** 2).mean(axis=1)  # Eq. 13
        if self._w_target is None:
            em = np.zeros(len(x))
        else:
            diff = x - self._w_target
            em = np.einsum("nd,nd->n", diff, diff) / joints  # Eq. 14
        ep = np.einsum("nd,nd->n", z, z) / max(z.shape[1], 1)  # latent prior (beyond the papers)
        out = {"Ec": ec, "Es": es, "Ek": ek, "Em": em, "Ep": ep}
        if self.dtype != np.float64:
            out = {k: v.astype(np.float64) for k, v in out.items()}
        return out

    def total(self, terms: dict[str, np.ndarray]) -> np.ndarray:
        """Weighted sum of terms (Eq. 10, plus the prior when its weight is not 0)."""
        w = self._w
        total = w[0] * terms["Ec"] + w[1] * terms["Es"] + w[2] * terms["Ek"] + w[3] * terms["Em"]
        return total + w[4] * terms["Ep"] if w[4] else total

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """``E`` for latent points ``(n, d) -> (n,)``."""
        return self.total(self.terms(z))
