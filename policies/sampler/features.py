"""A model's input and anchor: the observation fields it reads (:class:`FeatureMap`, the
:data:`FEATURE_SETS`), the anchor its Gaussian is centred on (:func:`quadratic_anchor`), an env
seen through them (:class:`SamplerFeatures`) and a search problem's observation
(:func:`problem_observation`). See :mod:`policies.sampler`."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from fpg_gym.env_observation import CONTEXT_NAMES, LATENT_LIMIT, ObservationLayout
from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE, quadratic_minimiser
from fpg_gym.reconstruct.energy import EnergyWeights

__all__ = [
    "ANCHORS",
    "DEFAULT_FEATURES",
    "FEATURE_SETS",
    "LATENT_FEATURES",
    "MASKED_CONTEXT",
    "PAPER_WEIGHTS",
    "FeatureMap",
    "SamplerFeatures",
    "problem_observation",
    "quadratic_anchor",
]

#: ``context`` entries a SearchProblem cannot give: zeroed in every model input.
MASKED_CONTEXT: tuple[str, ...] = ("no_body", "progress")
#: Observation fields a model reads by default: all of them.
DEFAULT_FEATURES: tuple[str, ...] = (
    "kinect",
    "reliability",
    "reliability_terms",
    "prediction",
    "previous",
    "bone_lengths",
    "latent_mean",
    "latent_basis",
    "latent_std",
    "latent_mask",
    "x0",
    "z_kinect",
    "z_prediction",
    "z_candidates",
    "candidate_scores",
    "candidate_mask",
    "context",
)

#: A smaller feature set: everything in latent (action) coordinates, the reliabilities and the
#: context, without the poses and the basis (1,044 of the 2,304 values at the defaults).
LATENT_FEATURES: tuple[str, ...] = (
    "reliability",
    "reliability_terms",
    "latent_std",
    "latent_mask",
    "x0",
    "z_kinect",
    "z_prediction",
    "z_candidates",
    "candidate_scores",
    "candidate_mask",
    "context",
)
#: Named feature sets (``fpg-gym train-sampler --features``).
FEATURE_SETS: dict[str, tuple[str, ...]] = {"all": DEFAULT_FEATURES, "latent": LATENT_FEATURES}


#: Anchors a sampler's Gaussian may be centred on (see :class:`FeatureMap`).
ANCHORS: tuple[str, ...] = ("none", "quadratic")
#: The papers' energy weights (Shum Eq. 10): control, style, kinematic, motion.
PAPER_WEIGHTS: tuple[float, float, float, float] = EnergyWeights().paper_terms()


def quadratic_anchor(
    parts: Mapping[str, np.ndarray],
    *,
    action_scale: float,
    delta: bool,
    energy_weights: Sequence[float] = PAPER_WEIGHTS,
    style: float = DEFAULT_STYLE,
) -> np.ndarray:
    """:func:`fpg_gym.reconstruct.closed_form.quadratic_minimiser` from observation parts, as
    actions: the closed-form minimiser of the energy's quadratic terms (``Ec``, ``Em``, a ridge
    standing in for ``Es``) in each frame's latent space, one batched ``(L, L)`` solve.

    Parameters
    ----------
    parts : mapping
        :meth:`ObservationLayout.split` of observations ``(n, N)``.
    action_scale : float
    delta : bool
        Actions relative to ``x0`` (``"delta"``) or absolute.
    energy_weights : 4 floats
        ``w_c, w_s, w_k, w_m`` (the env's).
    style : float
        Ridge weight as a multiple of ``w_s / J`` (2).

    Returns
    -------
    ndarray, shape (n, L), float64
        The actions that select the minimiser (zero on unused axes), clipped to the
        observation's latent bounds.
    """

    n = parts["kinect"].shape[0]
    mask = parts["latent_mask"] > 0.5
    z = quadratic_minimiser(
        parts["kinect"].reshape(n, -1),
        parts["reliability"],
        parts["latent_mean"].reshape(n, -1),
        parts["latent_basis"],
        parts["latent_std"],
        prediction=parts["prediction"].reshape(n, -1),
        has_prediction=parts["context"][:, CONTEXT_NAMES.index("has_prediction")] > 0.5,
        mask=mask,
        weights=energy_weights,
        style=style,
    )
    action = z / float(action_scale)
    if delta:
        action = action - parts["x0"].astype(np.float64)
    return np.where(mask, np.clip(action, -LATENT_LIMIT, LATENT_LIMIT), 0.0)


class FeatureMap:
    """The model input of an observation, and the anchor its Gaussian is centred on.

    Features: the chosen fields of the observation, with :data:`MASKED_CONTEXT` zeroed, then
    (with an anchor) the anchor's ``L`` action coordinates. The anchor (``"quadratic"``:
    :func:`quadratic_anchor`; ``"none"``: zero) is computed from the observation alone, so it
    is the same in the env loop and in the optimiser adapter; a model outputs its Gaussian's
    mean *relative to the anchor*.

    Parameters
    ----------
    layout : ObservationLayout
        The env's observation layout.
    fields : sequence of str
        Field names of ``layout`` (in this order), default :data:`DEFAULT_FEATURES`.
    anchor : {"none", "quadratic"}
    action_scale : float
    delta : bool
        The env's action mode is ``"delta"``.
    energy_weights : 4 floats
        The env's energy weights (for the anchor).
    anchor_style : float
        ``style`` of :func:`quadratic_anchor`.

    Attributes
    ----------
    indices : ndarray of int
        Positions of the field features in the observation vector.
    size : int
        Number of features.
    low, high : ndarray, shape (size,)
        Bounds of the features.
    """

    def __init__(
        self,
        layout: ObservationLayout,
        fields: Sequence[str] = DEFAULT_FEATURES,
        *,
        anchor: str = "none",
        action_scale: float = 3.0,
        delta: bool = True,
        energy_weights: Sequence[float] = PAPER_WEIGHTS,
        anchor_style: float = DEFAULT_STYLE,
    ) -> None:

        unknown = [f for f in fields if f not in layout.slices]
        if unknown or not fields:
            raise ValueError(
                f"features: unknown observation field(s) {unknown}; expected some of "
                f"{', '.join(layout.slices)}"
            )
        if anchor not in ANCHORS:
            raise ValueError(f"anchor: expected one of {ANCHORS}, got {anchor!r}")
        self.layout = layout
        self.fields = tuple(fields)
        self.anchor_kind = anchor
        self.action_scale = float(action_scale)
        self.delta = bool(delta)
        self.energy_weights = tuple(float(w) for w in energy_weights)
        self.anchor_style = float(anchor_style)
        parts = [np.arange(layout.slices[f].start, layout.slices[f].stop) for f in self.fields]
        self.indices = np.concatenate(parts)
        context = layout.slices["context"]
        masked = [context.start + CONTEXT_NAMES.index(name) for name in MASKED_CONTEXT]
        self._masked = np.flatnonzero(np.isin(self.indices, masked))
        extra = layout.latent_dim if anchor != "none" else 0
        self.size = len(self.indices) + extra
        limit = np.full(extra, LATENT_LIMIT, np.float32)
        self.low = np.concatenate([layout.low[self.indices], -limit])
        self.high = np.concatenate([layout.high[self.indices], limit])
        self.low[self._masked] = 0.0
        self.high[self._masked] = 0.0

    def _check(self, observation: np.ndarray) -> np.ndarray:
        obs = np.asarray(observation, dtype=np.float32)
        if obs.ndim == 0 or obs.shape[-1] != self.layout.size:
            raise ValueError(
                f"observation: expected shape (..., {self.layout.size}) (the layout this model "
                f"was trained on: latent_dim={self.layout.latent_dim}, "
                f"k={self.layout.candidates}), got {np.shape(observation)}"
            )
        return obs

    def transform(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Features ``(..., size)`` float32 and anchor actions ``(..., L)`` float64 of
        observations ``(..., layout.size)``.

        Raises
        ------
        ValueError
            If the observation's last axis is not the layout's size (a model trained on
            another observation layout).
        """
        obs = self._check(observation)
        batch = obs.shape[:-1]
        flat = obs.reshape(-1, obs.shape[-1])
        fields = flat[:, self.indices]
        fields[:, self._masked] = 0.0
        if self.anchor_kind == "none":
            anchor = np.zeros((len(flat), self.layout.latent_dim))
            features = fields
        else:
            anchor = quadratic_anchor(
                self.layout.split(flat),
                action_scale=self.action_scale,
                delta=self.delta,
                energy_weights=self.energy_weights,
                style=self.anchor_style,
            )
            features = np.concatenate([fields, anchor.astype(np.float32)], axis=1)
        return (
            features.reshape(*batch, self.size),
            anchor.reshape(*batch, self.layout.latent_dim),
        )

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Features ``(..., size)`` float32 of observations ``(..., layout.size)``."""
        return self.transform(observation)[0]

    def split(self, features: np.ndarray) -> dict[str, np.ndarray]:
        """The named parts ``(n, size_of_field)`` float64 of feature rows ``(n, size)``, the
        inverse of :meth:`transform`'s concatenation: each field flat, and the anchor actions
        ``(n, L)`` under ``"anchor"`` (zero without an anchor)."""
        rows = np.asarray(features, dtype=np.float64)
        parts: dict[str, np.ndarray] = {}
        start = 0
        for name in self.fields:
            size = self.layout.slices[name].stop - self.layout.slices[name].start
            parts[name] = rows[:, start : start + size]
            start += size
        dim = self.layout.latent_dim
        parts["anchor"] = (
            rows[:, start : start + dim] if start < rows.shape[1] else (np.zeros((len(rows), dim)))
        )
        return parts

    def wrap(self, env: Any) -> SamplerFeatures:
        """``env`` seen through this map (a Gymnasium wrapper): observations become features
        and an action ``a`` becomes ``anchor + a`` (the env should not clip actions then)."""
        return SamplerFeatures(env, self)


class SamplerFeatures(gym.Wrapper):
    """An env seen through a :class:`FeatureMap`: observations replaced by the sampler's
    features, actions taken relative to its anchor (:meth:`FeatureMap.wrap`)."""

    def __init__(self, env: Any, feature_map: FeatureMap) -> None:
        super().__init__(env)
        self.feature_map = feature_map
        self.observation_space = gym.spaces.Box(feature_map.low, feature_map.high, dtype=np.float32)
        self._anchor = np.zeros(feature_map.layout.latent_dim)

    def _features(self, observation: Any) -> np.ndarray:
        features, self._anchor = self.feature_map.transform(observation)
        return np.asarray(features, dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset the env; the first observation as features."""
        observation, info = self.env.reset(**kwargs)
        return self._features(observation), info

    def step(self, action: Any) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        """Step with ``anchor + action``; the next observation as features."""
        full = self._anchor + np.asarray(action, dtype=np.float64)
        observation, reward, terminated, truncated, info = self.env.step(full)
        return self._features(observation), reward, terminated, truncated, info


def problem_observation(
    problem: Any,
    layout: ObservationLayout,
    *,
    action_scale: float,
    delta: bool = True,
    frame_dt: float = 1.0 / 30.0,
) -> np.ndarray:
    """The env observation of a :class:`~fpg_gym.reconstruct.SearchProblem` ``(layout.size,)``.

    The env's own builder (:meth:`ObservationLayout.build`) with the two context entries a
    problem cannot give (:data:`MASKED_CONTEXT`) left at zero; :class:`FeatureMap` zeroes them
    in the env's observations too.
    """
    return layout.build(
        problem,
        action_scale=action_scale,
        delta=delta,
        no_body=False,
        progress=0.0,
        frame_dt=frame_dt,
    )
