"""The observation of :class:`fpg_gym.env.KinectPoseEnv`: a fixed-size float32 vector.

One observation describes the frame waiting to be reconstructed: the sensor pose and its
reliability, the continuity prediction and the previous reconstruction, and the frame's natural
posture space (the whitened local PCA of the K selected graph nodes) with the sensor pose, the
prediction, ``x0`` and the candidates placed in it. It is everything a policy needs to pick the
frame's latent point without reading the env's internals.

Layout (``L`` = the env's ``latent_dim``, ``K`` = candidates per frame; ``344 + 65 L + K L + 2 K``
values, 2,304 at the defaults L = 20, K = 30):

======================  ========  ==========  ==================================================
field                   shape     bounds      content
======================  ========  ==========  ==================================================
``kinect``              (20, 3)   ±4 m        sensor pose, normalised (root at 0, facing +Z)
``reliability``         (20,)     [0, 1]      per-joint reliability R (Shum §IV, FPG §5)
``reliability_terms``   (3, 20)   [0, 1]      its terms: behaviour Rb, kinematic Rk, tracking Rt
``prediction``          (20, 3)   ±4 m        continuity prediction p_l + v_l dt (FPG Eq. 6)
``previous``            (20, 3)   ±4 m        previous reconstruction in this frame
``bone_lengths``        (19,)     [0, 2] m    the user's reference bone lengths
``latent_mean``         (20, 3)   ±4 m        mean of the K candidates
``latent_basis``        (L, 60)   [-1, 1]     orthonormal principal directions (rows); 0 rows unused
``latent_std``          (L,)      [0, 4] m    spread of the candidates along each direction
``latent_mask``         (L,)      {0, 1}      1 for the axes this frame has (d <= L)
``x0``                  (L,)      ±10         x0 (previous reconstruction projected) / action_scale
``z_kinect``            (L,)      ±10         the action that selects the sensor pose's projection
``z_prediction``        (L,)      ±10         the action that selects the prediction's projection
``z_candidates``        (K, L)    ±10         the actions that select each candidate's projection
``candidate_scores``    (K,)      [0, 4] m    selection scores (lower is better), best first
``candidate_mask``      (K,)      {0, 1}      1 for the candidates this frame has
``context``             (5,)      [0, 30]     first frame, no body, has prediction, dt in
                                              frames, episode progress t / T
======================  ========  ==========  ==================================================

Poses are in metres in the frame's normalised space (the space the candidates and the energy
live in). Latent coordinates are *action coordinates*: the action that makes the env
reconstruct from that latent point, i.e. ``(z - x0) / action_scale`` in ``"delta"`` action mode
and ``z / action_scale`` in ``"absolute"`` mode (``x0`` itself is always ``x0 / action_scale``).
Every value is finite and clipped to its bounds (NaN becomes 0): the whitened coordinates of a
sensor pose far from the candidates can be far out (a few hundred), the exact values are on
``env.unwrapped.problem``. Missing parts (no prediction on a stream's first frame, fewer than L
axes or K candidates) are zeros, marked by ``context``, ``latent_mask`` and ``candidate_mask``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fpg_gym.core import skeleton

if TYPE_CHECKING:
    from fpg_gym.reconstruct.problem import SearchProblem

__all__ = [
    "CONTEXT_NAMES",
    "LATENT_LIMIT",
    "POSE_LIMIT_M",
    "ObservationField",
    "ObservationLayout",
]

#: Bound of pose coordinates (metres) in the observation.
POSE_LIMIT_M = 4.0
#: Bound of latent (action) coordinates in the observation.
LATENT_LIMIT = 10.0
#: Entries of the ``context`` field, in order.
CONTEXT_NAMES: tuple[str, ...] = ("first", "no_body", "has_prediction", "dt_frames", "progress")
_MAX_DT_FRAMES = 30.0
_J = skeleton.NUM_JOINTS


@dataclass(frozen=True)
class ObservationField:
    """One named part of the observation vector.

    Attributes
    ----------
    name : str
    shape : tuple of int
        Natural shape of the part (the vector holds it flattened, C order).
    low, high : float
        Bounds of every value.
    description : str
    """

    name: str
    shape: tuple[int, ...]
    low: float
    high: float
    description: str

    @property
    def size(self) -> int:
        """Number of values."""
        return math.prod(self.shape)


class ObservationLayout:
    """Where each part of the observation vector lies, and how to build it from a problem.

    Parameters
    ----------
    latent_dim : int
        ``L``: latent axes the observation (and the action) has room for.
    candidates : int
        ``K``: candidates the observation has room for.

    Attributes
    ----------
    fields : tuple of ObservationField
    slices : dict of str to slice
        Field name -> its slice of the vector.
    size : int
        Length of the vector.
    low, high : ndarray, shape (size,), float32
        Bounds of the vector.
    """

    def __init__(self, latent_dim: int, candidates: int) -> None:
        if latent_dim < 1:
            raise ValueError(f"latent_dim: expected >= 1, got {latent_dim}")
        if candidates < 1:
            raise ValueError(f"candidates: expected >= 1, got {candidates}")
        self.latent_dim = int(latent_dim)
        self.candidates = int(candidates)
        big_l, big_k, p = self.latent_dim, self.candidates, POSE_LIMIT_M
        self.fields: tuple[ObservationField, ...] = (
            ObservationField("kinect", (_J, 3), -p, p, "normalised sensor pose (m)"),
            ObservationField("reliability", (_J,), 0.0, 1.0, "per-joint reliability R"),
            ObservationField(
                "reliability_terms", (3, _J), 0.0, 1.0, "behaviour, kinematic, tracking terms"
            ),
            ObservationField("prediction", (_J, 3), -p, p, "continuity prediction (m)"),
            ObservationField("previous", (_J, 3), -p, p, "previous reconstruction (m)"),
            ObservationField(
                "bone_lengths", (skeleton.NUM_BONES,), 0.0, 2.0, "reference bone lengths (m)"
            ),
            ObservationField("latent_mean", (_J, 3), -p, p, "mean of the candidates (m)"),
            ObservationField("latent_basis", (big_l, 3 * _J), -1.0, 1.0, "principal directions"),
            ObservationField("latent_std", (big_l,), 0.0, p, "spread along each direction (m)"),
            ObservationField("latent_mask", (big_l,), 0.0, 1.0, "1 for the axes in use"),
            ObservationField("x0", (big_l,), -LATENT_LIMIT, LATENT_LIMIT, "x0 / action_scale"),
            ObservationField(
                "z_kinect", (big_l,), -LATENT_LIMIT, LATENT_LIMIT, "action of the sensor pose"
            ),
            ObservationField(
                "z_prediction", (big_l,), -LATENT_LIMIT, LATENT_LIMIT, "action of the prediction"
            ),
            ObservationField(
                "z_candidates",
                (big_k, big_l),
                -LATENT_LIMIT,
                LATENT_LIMIT,
                "actions of the candidates",
            ),
            ObservationField("candidate_scores", (big_k,), 0.0, p, "selection scores (m)"),
            ObservationField("candidate_mask", (big_k,), 0.0, 1.0, "1 for the candidates in use"),
            ObservationField(
                "context", (len(CONTEXT_NAMES),), 0.0, _MAX_DT_FRAMES, ", ".join(CONTEXT_NAMES)
            ),
        )
        self.slices: dict[str, slice] = {}
        start = 0
        for f in self.fields:
            self.slices[f.name] = slice(start, start + f.size)
            start += f.size
        self.size = start
        self._starts = {name: sl.start for name, sl in self.slices.items()}
        self.shapes: dict[str, tuple[int, ...]] = {f.name: f.shape for f in self.fields}
        self.low = np.concatenate([np.full(f.size, f.low, np.float32) for f in self.fields])
        self.high = np.concatenate([np.full(f.size, f.high, np.float32) for f in self.fields])
        context = self.slices["context"]
        self.high[context.start : context.start + 3] = 1.0  # the flags
        self.high[context.start + 4] = 1.0  # progress
        self.low.flags.writeable = False
        self.high.flags.writeable = False

    @staticmethod
    @functools.lru_cache(maxsize=32)
    def of(latent_dim: int, candidates: int) -> ObservationLayout:
        """The layout of ``latent_dim`` and ``candidates``, built once (layouts are read-only;
        a learned sampler asks for its own on every frame)."""
        return ObservationLayout(latent_dim, candidates)

    # ------------------------------------------------------------------ reading

    def split(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        """Named parts of observation vectors ``(..., size)``, each ``(..., *shape)`` (views).

        Raises
        ------
        ValueError
            If the last axis is not ``size`` long.
        """
        obs = np.asarray(observation)
        if obs.ndim == 0 or obs.shape[-1] != self.size:
            raise ValueError(
                f"observation: expected shape (..., {self.size}), got {np.shape(observation)}"
            )
        batch = obs.shape[:-1]
        return {
            name: obs[..., sl].reshape(*batch, *self.shapes[name])
            for name, sl in self.slices.items()
        }

    def to_dict(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        """The ``observation_mode="dict"`` form: each part flat ``(field size,)``, a copy."""
        return {name: observation[sl].copy() for name, sl in self.slices.items()}

    def table(self) -> list[dict[str, object]]:
        """One row per field: name, shape, start, stop, low, high, description."""
        return [
            {
                "name": f.name,
                "shape": f.shape,
                "start": self.slices[f.name].start,
                "stop": self.slices[f.name].stop,
                "low": f.low,
                "high": f.high,
                "description": f.description,
            }
            for f in self.fields
        ]

    # ------------------------------------------------------------------ building

    def build(
        self,
        problem: SearchProblem,
        *,
        action_scale: float,
        delta: bool,
        no_body: bool = False,
        progress: float = 0.0,
        frame_dt: float = 1.0 / 30.0,
    ) -> np.ndarray:
        """The observation vector of a :class:`~fpg_gym.reconstruct.SearchProblem`.

        Parameters
        ----------
        problem : SearchProblem
        action_scale : float
            Whitened units per action unit.
        delta : bool
            Whether actions are relative to ``x0`` (``"delta"`` mode).
        no_body : bool
            Whether the sensor saw no joint in this frame.
        progress : float
            ``t / T`` of the frame in its episode.
        frame_dt : float
            Nominal frame interval (s), the unit of ``dt_frames``.

        Returns
        -------
        ndarray, shape (size,), float32
            A new array, finite and within ``[low, high]``.
        """
        p = problem
        out = np.zeros(self.size, dtype=np.float32)
        at = self._starts
        # Flat slices written in place; the 2-D parts through one view each.
        out[self.slices["kinect"]] = p.kinect_pose.reshape(-1)
        out[self.slices["reliability"]] = p.reliability
        terms = at["reliability_terms"]
        out[terms : terms + _J] = p.behaviour
        out[terms + _J : terms + 2 * _J] = p.kinematic
        out[terms + 2 * _J : terms + 3 * _J] = p.tracking
        if p.prediction is not None:
            out[self.slices["prediction"]] = p.prediction.reshape(-1)
        if p.previous is not None:
            out[self.slices["previous"]] = p.previous.reshape(-1)
        out[self.slices["bone_lengths"]] = p.lengths
        latent = p.latent
        d = min(latent.dim, self.latent_dim)
        out[self.slices["latent_mean"]] = latent.mean.reshape(-1)
        basis = at["latent_basis"]
        out[basis : basis + 3 * _J * d] = latent.basis[:d].reshape(-1)
        out[at["latent_std"] : at["latent_std"] + d] = latent.std[:d]
        out[at["latent_mask"] : at["latent_mask"] + d] = 1.0
        x0 = np.asarray(p.x0, dtype=np.float64)[:d]
        origin: np.ndarray | float = x0 if delta else 0.0
        scale = 1.0 / float(action_scale)
        out[at["x0"] : at["x0"] + d] = x0 * scale
        out[at["z_kinect"] : at["z_kinect"] + d] = (p.z_kinect[:d] - origin) * scale
        if p.z_prediction is not None:
            z_prediction = at["z_prediction"]
            out[z_prediction : z_prediction + d] = (p.z_prediction[:d] - origin) * scale
        k = min(len(p.node_poses), self.candidates)
        if k and d:
            z_nodes = latent.encode(p.node_poses[:k])[:, :d]
            candidates = out[self.slices["z_candidates"]].reshape(self.candidates, self.latent_dim)
            candidates[:k, :d] = (z_nodes - origin) * scale
        out[at["candidate_scores"] : at["candidate_scores"] + k] = p.node_scores[:k]
        out[at["candidate_mask"] : at["candidate_mask"] + k] = 1.0
        out[self.slices["context"]] = (
            float(p.context.first),
            float(no_body),
            float(p.prediction is not None),
            float(p.context.dt) / frame_dt,
            progress,
        )
        if not np.isfinite(out).all():  # NaN -> 0, +-inf -> +-max, then clipped to the bounds
            np.nan_to_num(out, copy=False)
        np.maximum(out, self.low, out=out)  # clipped to the bounds, as np.clip does
        np.minimum(out, self.high, out=out)
        return out
