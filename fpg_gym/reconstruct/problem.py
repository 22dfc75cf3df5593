"""The per-frame search problem every optimiser and policy works on.

A :class:`SearchProblem` is what :meth:`fpg_gym.reconstruct.Reconstructor.prepare` returns: the
frame's sensor data, reliability, candidates and latent space as public attributes, and the
energy as a vectorised function of whitened latent points.

Budget
------
``evaluate`` and ``evaluate_terms`` count one evaluation per row. With ``max_evaluations`` set,
a batch larger than what is left is **clipped**: its first ``remaining`` rows are evaluated and
the others get ``+inf`` (so no optimiser can pick them). A call made when nothing is left — the
evaluation budget is spent or ``time_budget_s`` has elapsed since the first evaluation — raises
:class:`BudgetExhausted`. :func:`optimizers.run_optimizer` stops on it cleanly.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np

from fpg_gym.errors import FpgGymError
from fpg_gym.reconstruct.energy import EnergyModel, EnergyWeights
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.reliability import ReliabilityTerms
from fpg_gym.reconstruct.selection import Selection


class BudgetExhausted(FpgGymError, RuntimeError):
    """Raised by :meth:`SearchProblem.evaluate` when the evaluation or time budget is spent."""


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
    max_evaluations : int or None
        Evaluation budget (None: unlimited).
    time_budget_s : float or None
        Seconds allowed from the first evaluation (None: unlimited).

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
    best_z : ndarray, shape (d,)
        Best point evaluated so far (``x0`` before any evaluation).
    best_energy : float
        Its energy (``inf`` before any evaluation).
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
        max_evaluations: int | None = 2000,
        time_budget_s: float | None = None,
    ) -> None:
        if max_evaluations is not None and max_evaluations < 0:
            raise ValueError(f"max_evaluations: expected >= 0 or None, got {max_evaluations}")
        if time_budget_s is not None and time_budget_s <= 0:
            raise ValueError(f"time_budget_s: expected > 0 or None, got {time_budget_s}")
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
        self.z_kinect = self.latent.encode(self.kinect_pose)
        self.z_prediction = None if prediction is None else self.latent.encode(prediction)
        x0 = np.asarray(x0, dtype=np.float64)
        if x0.shape != (self.dim,):
            raise ValueError(f"x0: expected shape ({self.dim},), got {x0.shape}")
        self.x0 = x0
        self.max_evaluations = max_evaluations
        self.time_budget_s = time_budget_s
        self.evaluations = 0
        self._started: float | None = None
        self.best_z = x0.copy()
        self.best_energy = float("inf")

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

    # ------------------------------------------------------------------ budget

    @property
    def elapsed_s(self) -> float:
        """Seconds since the first counted evaluation (0 before it)."""
        return 0.0 if self._started is None else time.perf_counter() - self._started

    @property
    def remaining(self) -> int | None:
        """Evaluations left (None when unlimited); 0 once the time budget has elapsed."""
        if self.time_budget_s is not None and self.elapsed_s >= self.time_budget_s:
            return 0
        if self.max_evaluations is None:
            return None
        return max(self.max_evaluations - self.evaluations, 0)

    @property
    def exhausted(self) -> bool:
        """Whether the next evaluation would raise :class:`BudgetExhausted`."""
        return self.remaining == 0

    def _check(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        if z.ndim == 1 and z.shape == (self.dim,):
            z = z[None]
        if z.ndim != 2 or z.shape[1] != self.dim:
            raise ValueError(f"Z: expected shape (n, {self.dim}), got {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ValueError("Z: non-finite latent coordinates")
        return z

    def _admit(self, n: int) -> int:
        """How many of ``n`` rows may be evaluated; raises when none may."""
        remaining = self.remaining
        if remaining == 0:
            spent = (
                f"time budget {self.time_budget_s} s"
                if self.max_evaluations is None or self.evaluations < self.max_evaluations
                else f"evaluation budget {self.max_evaluations}"
            )
            raise BudgetExhausted(f"search problem: {spent} spent ({self.evaluations} evaluations)")
        if self._started is None:
            self._started = time.perf_counter()
        return n if remaining is None else min(n, remaining)

    # ------------------------------------------------------------------ energy

    def evaluate_terms(self, z: np.ndarray, *, count: bool = True) -> dict[str, np.ndarray]:
        """``Ec``, ``Es``, ``Ek``, ``Em`` and the total ``E`` for latent points ``(n, d)``.

        Counts against the budget like :meth:`evaluate` unless ``count=False``; rows beyond the
        budget get ``inf`` in every entry.
        """
        z = self._check(z)
        n = len(z)
        admitted = self._admit(n) if count else n
        terms = self.energy.terms(z[:admitted])
        terms["E"] = self.energy.total(terms)
        if admitted < n:
            terms = {
                k: np.concatenate([v, np.full(n - admitted, np.inf)]) for k, v in terms.items()
            }
        if count:
            self._record(z, terms["E"], admitted)
        return terms

    def evaluate(self, z: np.ndarray) -> np.ndarray:
        """Energy ``E`` (Shum Eq. 10, lower is better) of latent points ``(n, d) -> (n,)``.

        Raises
        ------
        BudgetExhausted
            If the budget was already spent (a partly over-budget batch is clipped instead).
        """
        return self.evaluate_terms(z)["E"]

    def _record(self, z: np.ndarray, energies: np.ndarray, admitted: int) -> None:
        self.evaluations += admitted
        if admitted:
            i = int(np.argmin(energies[:admitted]))
            if energies[i] < self.best_energy:
                self.best_energy = float(energies[i])
                self.best_z = z[i].copy()

    def solution(self) -> np.ndarray:
        """The point to reconstruct from: ``best_z`` after evaluations, else ``x0``."""
        return self.best_z.copy() if self.evaluations else self.x0.copy()

    def __repr__(self) -> str:
        return (
            f"SearchProblem(frame={self.context.index}, dim={self.dim}, K={len(self.nodes)}, "
            f"evaluations={self.evaluations}/{self.max_evaluations}, "
            f"best_energy={self.best_energy:.6g})"
        )


__all__ = ["BudgetExhausted", "FrameContext", "SearchProblem"]
