"""The per-frame search problem every optimiser and policy works on.

A :class:`SearchProblem` is what :meth:`fpg_gym.reconstruct.Reconstructor.prepare` returns: the
frame's sensor data, reliability, candidates and latent space as public attributes, and the
energy as a vectorised function of whitened latent points.

It follows :class:`optimizers.Problem` (``dim``, ``x0``, ``evaluate``): the budget and the best
point belong to :func:`optimizers.run_optimizer`, which the reconstructor calls with its
configured budget (:meth:`fpg_gym.reconstruct.Reconstructor.search`). ``evaluate`` counts the
rows it scores in ``evaluations`` (a tally for reports, not a limit).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from fpg_gym.reconstruct.energy import EnergyModel, EnergyWeights
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.reliability import ReliabilityTerms
from fpg_gym.reconstruct.selection import Selection


@dataclass(frozen=True)
class FrameContext:
    """Where and when a frame is: what :class:`SearchProblem` reports besides the energy.

    Attributes
    ----------
    index : int
        0-based frame index in the stream.
    timestamp : float
        Seconds.
    dt : float
        Seconds since the previous reconstructed frame (1/30 on the first frame).
    first : bool
        Whether this frame starts a stream (no previous reconstruction to continue from).
    """

    index: int
    timestamp: float
    dt: float
    first: bool


class SearchProblem:
    """One frame's energy minimisation over the natural posture space.

    Parameters
    ----------
    energy : EnergyModel
    kinect_pose : ndarray, shape (20, 3)
        Normalised sensor pose ``p_k``.
    reliability : ReliabilityTerms
    selection : Selection
    prediction : ndarray, shape (20, 3) or None
        Continuity prediction ``p_l + v_l dt`` in the current frame (None on a first frame).
    previous : ndarray, shape (20, 3) or None
        Previous reconstruction ``p_l`` in the current frame (None on a first frame).
    x0 : ndarray, shape (d,)
        Starting point: the previous reconstruction projected into the space, or the best
        candidate's projection on a first frame.
    context : FrameContext

    Attributes
    ----------
    kinect_pose, prediction, previous : ndarray or None
        As above (float64).
    reliability, behaviour, kinematic, tracking : ndarray, shape (20,)
        ``R`` and its terms.
    nodes : ndarray, shape (K,)
        Selected graph node ids, best first.
    node_poses : ndarray, shape (K, 20, 3)
        Their (normalised, retargeted) poses.
    node_scores : ndarray, shape (K,)
    latent : LatentSpace
        ``mean`` (60,), ``basis`` (d, 60) and ``std`` (d,) are also attributes of the problem.
    z_kinect : ndarray, shape (d,)
        The sensor pose projected into the space.
    z_prediction, z_previous : ndarray, shape (d,) or None
        The prediction and the previous reconstruction projected into the space.
    lengths : ndarray, shape (19,)
        The user's reference bone lengths.
    weights : EnergyWeights
    dim : int
    x0 : ndarray, shape (d,)
    evaluations : int
        Rows evaluated so far (counted calls only).
    """

    def __init__(
        self,
        *,
        energy: EnergyModel,
        kinect_pose: np.ndarray,
        reliability: ReliabilityTerms,
        selection: Selection,
        prediction: np.ndarray | None,
        previous: np.ndarray | None,
        x0: np.ndarray,
        context: FrameContext,
    ) -> None:
        self.energy = energy
        self.latent: LatentSpace = energy.latent
        self.kinect_pose = np.asarray(kinect_pose, dtype=np.float64)
        self.reliability_terms = reliability
        self.reliability = reliability.reliability
        self.behaviour = reliability.behaviour
        self.kinematic = reliability.kinematic
        self.tracking = reliability.tracking
        self.selection = selection
        self.nodes = selection.nodes
        self.node_poses = selection.poses
        self.node_scores = selection.scores
        self.prediction = prediction
        self.previous = previous
        self.lengths = energy.lengths
        self.weights: EnergyWeights = energy.weights
        self.context = context
        self.dt = context.dt
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != (self.dim,):
            raise ValueError(f"x0: expected shape ({self.dim},), got {x0.shape}")
        self.x0 = x0
        self.evaluations = 0

    # ------------------------------------------------------------------ space

    @property
    def dim(self) -> int:
        """Latent dimension ``d``."""
        return self.latent.dim

    @property
    def mean(self) -> np.ndarray:
        """Latent mean ``(60,)``."""
        return self.latent.mean

    @property
    def basis(self) -> np.ndarray:
        """Latent basis ``(d, 60)``."""
        return self.latent.basis

    @property
    def std(self) -> np.ndarray:
        """Per-axis spread ``(d,)`` of the candidates (the whitening scale)."""
        return self.latent.std

    @functools.cached_property
    def z_kinect(self) -> np.ndarray:
        """The sensor pose projected into the space (computed on first use)."""
        return self.latent.encode(self.kinect_pose)

    @functools.cached_property
    def z_prediction(self) -> np.ndarray | None:
        """The prediction projected into the space (None on a first frame; computed on first
        use)."""
        return None if self.prediction is None else self.latent.encode(self.prediction)

    @functools.cached_property
    def z_previous(self) -> np.ndarray | None:
        """The previous reconstruction projected into the space (None on a first frame;
        computed on first use)."""
        return None if self.previous is None else self.latent.encode(self.previous)

    def decode(self, z: np.ndarray) -> np.ndarray:
        """Normalised poses ``(n, 20, 3)`` of latent points ``(n, d)`` (no budget)."""
        return self.latent.decode(z)

    def encode(self, poses: np.ndarray) -> np.ndarray:
        """Whitened coordinates ``(..., d)`` of normalised poses ``(..., 20, 3)``."""
        return self.latent.encode(poses)

    # ------------------------------------------------------------------ energy

    def _check(self, z: np.ndarray, finite: bool = True) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        if z.ndim == 1 and z.shape == (self.dim,):
            z = z[None]
        if z.ndim != 2 or z.shape[1] != self.dim:
            raise ValueError(f"Z: expected shape (n, {self.dim}), got {z.shape}")
        if finite and not np.isfinite(z).all():
            raise ValueError("Z: non-finite latent coordinates")
        return z

    def evaluate_terms(self, z: np.ndarray, *, count: bool = True) -> dict[str, np.ndarray]:
        """``Ec``, ``Es``, ``Ek``, ``Em`` and the total ``E`` for latent points ``(n, d)``.

        Adds the rows to ``evaluations`` unless ``count=False``.
        """
        z = self._check(z)
        terms = self.energy.terms_and_total(z)
        if count:
            self.evaluations += len(z)
        return terms

    def evaluate(self, z: np.ndarray) -> np.ndarray:
        """Energy ``E`` (Shum Eq. 10, lower is better) of latent points ``(n, d) -> (n,)``.

        The search's inner loop: the total only, by the fused kernel
        (:mod:`fpg_gym.reconstruct.kernels`); :meth:`evaluate_terms` gives each term.
        """
        z = self._check(z, finite=False)
        energy = self.energy(z)
        if not np.isfinite(energy).all():  # n values to check rather than n x d
            self._check(z)
        self.evaluations += len(z)
        return energy

    def __repr__(self) -> str:
        return (
            f"SearchProblem(frame={self.context.index}, dim={self.dim}, K={len(self.nodes)}, "
            f"evaluations={self.evaluations})"
        )


__all__ = ["FrameContext", "SearchProblem"]
