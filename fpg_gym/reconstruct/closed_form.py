"""Closed-form minimiser of the energy's quadratic terms in a frame's natural posture space.

In the latent space of a frame (unwhitened coordinates ``u``, pose ``x = mean + B^T u``), the
control term ``Ec`` (Shum Eq. 11) and the motion term ``Em`` (Eq. 14) are quadratic in ``u``;
the style term ``Es`` (Eq. 12, "stay near the candidates") is replaced by a ridge
``(w_s / J) * style * ||u||^2`` that pulls toward the candidates' mean, and the kinematic term
``Ek`` (not quadratic) is left out. The minimiser of

    w_c Ec + w_m Em + (w_s / J) style ||u||^2 + eps ||z||^2,     z = u / std,

is one ``(d, d)`` linear solve (``eps`` only keeps axes of tiny spread finite). It is a
reliability-weighted, regularised least-squares fit of the sensor pose (and the continuity
prediction) in the PCA space: beyond the papers, and on the held-out data of the README more
accurate than their stochastic search, at one energy evaluation (optimiser ``closed-form``,
registered here because it reads the per-frame problem, :class:`~fpg_gym.reconstruct.problem.
SearchProblem`; the learned samplers of :mod:`policies` centre their Gaussians on it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from fpg_gym.reconstruct.energy import EnergyWeights
from optimizers import BaseOptimizer, OptimizerError, register

__all__ = ["DEFAULT_STYLE", "ClosedForm", "quadratic_minimiser"]

#: Ridge weight as a multiple of ``w_s / J``.
DEFAULT_STYLE = 2.0
#: Weight of the faint prior in whitened units (keeps degenerate axes finite).
_WHITENED_PRIOR = 1e-5
#: What :class:`ClosedForm` reads of its problem beyond ``dim`` and ``x0``.
_READS = ("kinect_pose", "reliability", "latent", "prediction", "weights")


def quadratic_minimiser(
    sensor: np.ndarray,
    reliability: np.ndarray,
    mean: np.ndarray,
    basis: np.ndarray,
    std: np.ndarray,
    *,
    prediction: np.ndarray | None = None,
    has_prediction: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    weights: Sequence[float] = EnergyWeights().paper_terms(),
    style: float = DEFAULT_STYLE,
) -> np.ndarray:
    """Whitened latent points ``(n, L)`` minimising the quadratic energy, batched over frames.

    Parameters
    ----------
    sensor : ndarray, shape (n, 60)
        Normalised sensor poses as 60-vectors (or any pose to fit, such as the learned pose of
        :mod:`policies.pose_sampler`).
    reliability : ndarray, shape (n, 20)
    mean : ndarray, shape (n, 60)
        Latent mean of each frame.
    basis : ndarray, shape (n, L, 60)
        Orthonormal principal directions (rows).
    std : ndarray, shape (n, L)
        Spread along each direction (metres).
    prediction : ndarray, shape (n, 60), optional
        Motion target of ``Em``; used where ``has_prediction`` is True.
    has_prediction : ndarray of bool, shape (n,), optional
        Default: True wherever ``prediction`` is given.
    mask : ndarray of bool, shape (n, L), optional
        Axes the frame has (others get 0). Default: all.
    weights : 4 floats
        ``w_c, w_s, w_k, w_m`` of the energy (``w_k`` is not used); the papers' by default
        (:meth:`EnergyWeights.paper_terms`).
    style : float
        Ridge weight as a multiple of ``w_s / J``.

    Returns
    -------
    ndarray, shape (n, L), float64
    """
    sensor = np.asarray(sensor, dtype=np.float64)
    n, size = sensor.shape[0], np.asarray(basis).shape[1]
    joints = np.asarray(reliability).shape[-1]
    basis = np.asarray(basis, dtype=np.float64)
    mean = np.asarray(mean, dtype=np.float64)
    std = np.asarray(std, dtype=np.float64)
    mask = np.ones((n, size), dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    w_c, w_s, _, w_m = (float(w) for w in weights)
    if prediction is None:
        prediction = mean
        has_prediction = np.zeros(n, dtype=bool)
    elif has_prediction is None:
        has_prediction = np.ones(n, dtype=bool)
    prediction = np.asarray(prediction, dtype=np.float64)
    joint_weights = w_c * np.repeat(np.asarray(reliability, dtype=np.float64), 3, axis=1)
    motion = np.where(np.asarray(has_prediction, dtype=bool), w_m / joints, 0.0)  # (n,)
    ridge = w_s / joints * style + 1e-9
    eye = np.eye(size)
    a = np.einsum("nlk,nk,nmk->nlm", basis, joint_weights, basis)  # Ec (Eq. 11)
    a += (motion + ridge)[:, None, None] * eye  # Em (Eq. 14) and the ridge for Es (Eq. 12)
    a += _WHITENED_PRIOR * eye / np.maximum(std, 1e-6)[:, :, None] ** 2
    b = np.einsum("nlk,nk->nl", basis, joint_weights * (sensor - mean))
    b += motion[:, None] * np.einsum("nlk,nk->nl", basis, prediction - mean)
    valid = mask[:, :, None] & mask[:, None, :]
    a = np.where(valid, a, eye)
    b = np.where(mask, b, 0.0)
    u = np.linalg.solve(a, b[..., None])[..., 0]
    return np.where(mask, u / np.maximum(std, 1e-9), 0.0)


@register("closed-form")
class ClosedForm(BaseOptimizer):
    """Asks one point: the exact minimiser of ``w_c Ec + w_m Em`` plus a ridge toward the
    candidates' mean standing in for ``Es`` (above).

    Beyond the papers: a deterministic, regularised least-squares fit of the reliable sensor
    joints and the continuity prediction in the frame's natural posture space. It reads the
    problem's public attributes (sensor pose, reliability, prediction, latent space, energy
    weights) and spends one energy evaluation, so the chosen point's energy is recorded like
    any other optimiser's.

    Parameters
    ----------
    style : float
        Ridge weight as a multiple of ``w_s / J`` (2).
    """

    name = "closed-form"

    def __init__(self, style: float = DEFAULT_STYLE) -> None:
        super().__init__()
        if not (np.isfinite(style) and style >= 0):
            raise ValueError(f"style: expected a finite value >= 0, got {style}")
        self.style = float(style)
        self._asked = False

    def params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {"style": self.style}

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Start on a new frame's problem.

        Raises
        ------
        OptimizerError
            If ``problem`` is not the per-frame reconstruction problem (a plain
            :class:`optimizers.Problem` has no sensor pose or latent space to fit).
        """
        missing = [name for name in _READS if not hasattr(problem, name)]
        if missing:
            raise OptimizerError(
                "closed-form: needs the per-frame reconstruction problem "
                f"(fpg_gym.reconstruct.SearchProblem), got {type(problem).__name__} without "
                f"{', '.join(missing)}"
            )
        super().reset(problem, rng)
        self._asked = False

    def ask(self) -> np.ndarray | None:
        """The minimiser ``(1, d)`` on the first call, then None."""
        if self._asked:
            return None
        self._asked = True
        problem = self.problem
        latent = problem.latent
        prediction = problem.prediction
        return quadratic_minimiser(
            np.asarray(problem.kinect_pose, dtype=np.float64).reshape(1, -1),
            np.asarray(problem.reliability, dtype=np.float64)[None],
            np.asarray(latent.mean, dtype=np.float64).reshape(1, -1),
            np.asarray(latent.basis, dtype=np.float64)[None],
            np.asarray(latent.std, dtype=np.float64)[None],
            prediction=None if prediction is None else np.asarray(prediction).reshape(1, -1),
            weights=problem.weights.paper_terms(),
            style=self.style,
        )
