"""The reconstruction energy (Shum 2013 Eq. 10-15), minimised over the natural posture space.

``E = w_c Ec + w_s Es + w_k Ek + w_m Em`` with weights 1.0, 0.5, 1.5, 0.25 where, for a candidate
pose ``p_x`` (normalised, in the current frame):

* ``Ec = sum_j R(j) ||p_x(j) - p_k(j)||^2`` — control: follow the reliable sensor joints
  (Eq. 11, the Eq. 9 form);
* ``Es = min_n mean_j ||p_x(j) - p_n(j)||^2`` over the K candidates ``p_n`` — style: stay near a
  real pose (Eq. 12);
* ``Ek = mean_b (l_x(b) - l_db(b))^2`` — kinematics: keep the bone lengths (Eq. 13);
* ``Em = mean_j ||p_x(j) - 2 p_{x-1}(j) + p_{x-2}(j)||^2`` — motion: small acceleration (Eq. 14).
  With irregular timestamps the constant-velocity target ``p_{x-1} + (p_{x-1} - p_{x-2}) dt /
  dt_prev`` replaces ``2 p_{x-1} - p_{x-2}`` (identical at a constant frame rate), so
  ``Em = mean_j ||p_x(j) - target(j)||^2``. Without a previous frame ``Em = 0``.

Beyond the papers, an optional fifth term (weight 0 by default, which is the papers' energy):

* ``Ep = mean_i z_i^2`` over the whitened latent coordinates — prior: a Gaussian prior on the
  natural posture space, centred on the mean of the K candidates with their spread (the PCA
  pose prior of e.g. Chai & Hodgins 2005). It pulls the search toward the candidates when the
  sensor term trusts joints that are wrong. ``EnergyWeights.with_prior()`` gives the weight
  chosen on a validation split (see the README).

The functions ``control_energy`` ... ``motion_energy`` compute each term directly from poses
(the reference implementation). :class:`EnergyModel` evaluates the same terms for a batch of
latent points without building the candidates' distance tensors: poses are decoded with one
matrix product and ``Es`` uses ``||x - n||^2 = ||std*z - y_n||^2 + ||r_n||^2`` (``y_n`` the
neighbour's unwhitened coordinates, ``r_n`` its residual outside the space), which is exact.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from fpg_gym import skeleton
from fpg_gym.poses import bone_lengths
from fpg_gym.reconstruct.latent import POSE_SIZE, LatentSpace

#: The papers' terms (computable from a pose alone) and all terms, in weight order.
POSE_TERM_NAMES: tuple[str, ...] = ("Ec", "Es", "Ek", "Em")
TERM_NAMES: tuple[str, ...] = (*POSE_TERM_NAMES, "Ep")
#: Prior weight chosen on a validation split of Bandai Namco takes (README, "Beyond the papers").
TUNED_PRIOR_WEIGHT = 0.1


@dataclass(frozen=True)
class EnergyWeights:
    """Weights of the energy terms (Shum Eq. 10).

    Attributes
    ----------
    control, style, kinematic, motion : float
        Weights of ``Ec``, ``Es``, ``Ek`` and ``Em`` (1.0, 0.5, 1.5, 0.25).
    prior : float
        Weight of the latent prior ``Ep`` (beyond the papers; 0 = off, the papers' energy).
    """

    control: float = 1.0
    style: float = 0.5
    kinematic: float = 1.5
    motion: float = 0.25
    prior: float = 0.0

    @classmethod
    def with_prior(cls, prior: float = TUNED_PRIOR_WEIGHT) -> EnergyWeights:
        """The papers' weights plus the latent prior (weight chosen on a validation split)."""
        return cls(prior=prior)

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"energy weight {name}: expected a finite value >= 0, got {value}")

    def as_array(self) -> np.ndarray:
        """The weights in :data:`TERM_NAMES` order, ``(5,)``."""
        return np.array([self.control, self.style, self.kinematic, self.motion, self.prior])

    def paper_terms(self) -> tuple[float, float, float, float]:
        """The weights of the papers' four terms (:data:`POSE_TERM_NAMES` order): ``w_c, w_s,
        w_k, w_m``."""
        return (self.control, self.style, self.kinematic, self.motion)


# --------------------------------------------------------------------------- direct terms


def control_energy(poses: np.ndarray, sensor: np.ndarray, reliability: np.ndarray) -> np.ndarray:
    """``Ec`` (Eq. 11): ``sum_j R(j) ||p_x(j) - p_k(j)||^2`` for poses ``(n, 20, 3) -> (n,)``."""
    diff = np.asarray(poses, dtype=np.float64) - np.asarray(sensor, dtype=np.float64)
    return np.einsum("njc,njc->nj", diff, diff) @ np.asarray(reliability, dtype=np.float64)


def style_energy(poses: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """``Es`` (Eq. 12): ``min_n mean_j ||p_x(j) - p_n(j)||^2``, ``(n, 20, 3) -> (n,)``."""
    diff = np.asarray(poses, dtype=np.float64)[:, None] - np.asarray(neighbours, dtype=np.float64)
    return np.einsum("nkjc,nkjc->nk", diff, diff).min(axis=1) / skeleton.NUM_JOINTS


def kinematic_energy(poses: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``Ek`` (Eq. 13): ``mean_b (l_x(b) - l_db(b))^2``, ``(n, 20, 3) -> (n,)``."""
    return ((bone_lengths(poses) - np.asarray(lengths)) ** 2).mean(axis=1)


def motion_energy(poses: np.ndarray, target: np.ndarray | None) -> np.ndarray:
    """``Em`` (Eq. 14): ``mean_j ||p_x(j) - target(j)||^2``, target ``= 2 p_{x-1} - p_{x-2}``.

    Returns zeros when ``target`` is None (first frame).
    """
    poses = np.asarray(poses, dtype=np.float64)
    if target is None:
        return np.zeros(len(poses))
    diff = poses - np.asarray(target, dtype=np.float64)
    return np.einsum("njc,njc->n", diff, diff) / skeleton.NUM_JOINTS


def motion_target(
    previous: np.ndarray, before: np.ndarray | None, dt: float, dt_previous: float | None = None
) -> np.ndarray:
    """Constant-velocity prediction ``p_{x-1} + (p_{x-1} - p_{x-2}) dt / dt_prev``.

    Equals ``2 p_{x-1} - p_{x-2}`` at a constant frame rate; ``p_{x-1}`` when ``before`` is None.
    """
    previous = np.asarray(previous, dtype=np.float64)
    if before is None:
        return previous.copy()
    ratio = 1.0 if not dt_previous or dt_previous <= 0 else dt / dt_previous
    return previous + (previous - np.asarray(before, dtype=np.float64)) * ratio


def pose_energy_terms(
    poses: np.ndarray,
    *,
    sensor: np.ndarray,
    reliability: np.ndarray,
    neighbours: np.ndarray,
    lengths: np.ndarray,
    target: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """The papers' four terms (:data:`POSE_TERM_NAMES`) for poses ``(n, 20, 3)``, computed
    directly (the reference path)."""
    return {
        "Ec": control_energy(poses, sensor, reliability),
        "Es": style_energy(poses, neighbours),
        "Ek": kinematic_energy(poses, lengths),
        "Em": motion_energy(poses, target),
    }


# --------------------------------------------------------------------------- latent fast path

# Ek: bone vectors are linear in the flat pose x (60,): child minus parent coordinates.
_CHILD_COORDS = (3 * skeleton.BONES[:, 1][:, None] + np.arange(3)).reshape(-1)
_PARENT_COORDS = (3 * skeleton.BONES[:, 0][:, None] + np.arange(3)).reshape(-1)


class EnergyModel:
    """The energy of one frame as a function of whitened latent points.

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
    ) -> None:
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
