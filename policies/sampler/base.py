"""The common interface of learned candidate samplers (:class:`GaussianSampler`) and the
anchor alone as a sampler (:class:`AnchorSampler`). See :mod:`policies.sampler`."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from policies.sampler.features import problem_observation
from policies.sampler.spec import SamplerSpec

__all__ = ["AnchorSampler", "GaussianSampler"]


class GaussianSampler:
    """A learned Gaussian over the latent space, in action units (see :mod:`policies.sampler`).

    Subclasses implement :meth:`gaussian_features` (features -> mean relative to the anchor,
    std) and :meth:`save`; :meth:`gaussian` adds the anchor (:class:`FeatureMap`).

    Parameters
    ----------
    spec : SamplerSpec
    seed : int, optional
        Seed of :meth:`predict`'s own generator (``deterministic=False``).
    """

    def __init__(self, spec: SamplerSpec, seed: int | None = 0) -> None:
        self.spec = spec
        self.features = spec.feature_map()
        self.layout = self.features.layout
        self.rng = np.random.default_rng(seed)

    # ---------------------------------------------------------------- to override

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (relative to the anchor) and std ``(n, L)`` float64 of feature rows ``(n, F)``."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``MODEL.json`` and the weights; returns the JSON's path."""
        raise NotImplementedError

    # ---------------------------------------------------------------- shared

    @property
    def kind(self) -> str:
        """``"supervised"`` or ``"rl"``."""
        return self.spec.kind

    def distribution(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean, std and anchor (action units) of an observation ``(N,)`` -> ``(L,)`` each,
        or of a batch ``(n, N)`` -> ``(n, L)`` each (the anchor is zero without one).

        Raises
        ------
        ValueError
            If the observation does not have the model's size.
        """
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        features, anchor = self.features.transform(np.atleast_2d(obs))
        if features.ndim != 2:
            raise ValueError(f"observation: expected (N,) or (n, N), got shape {obs.shape}")
        offset, std = self.gaussian_features(features)
        mean = anchor + offset
        if single:
            return mean[0], std[0], anchor[0]
        return mean, std, anchor

    def gaussian(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std (action units) of an observation ``(N,)`` -> ``(L,)`` each, or of a
        batch ``(n, N)`` -> ``(n, L)`` each (see :meth:`distribution`)."""
        mean, std, _ = self.distribution(observation)
        return mean, std

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """SB3-style ``(action, None)``: the mean, or a sample from the sampler's own generator
        (``seed`` at construction).

        Not clipped: an anchored Gaussian's mean may lie beyond the action box (the point the
        anchor selects usually does), so make the env with ``clip_actions=False`` to act on it
        exactly, as the RL sampler's training env is.
        """
        mean, std = self.gaussian(observation)
        action = mean if deterministic else mean + std * self.rng.standard_normal(mean.shape)
        return np.asarray(action, dtype=np.float32), None

    def observe(self, problem: Any) -> np.ndarray:
        """The observation ``(N,)`` of a search problem (:func:`problem_observation`).

        Raises
        ------
        ValueError
            If the problem has more latent axes or candidates than the model's layout.
        """
        if problem.dim > self.spec.latent_dim or len(problem.nodes) > self.spec.candidates:
            raise ValueError(
                f"search problem with {problem.dim} latent axes and {len(problem.nodes)} "
                f"candidates does not fit this sampler's observation (latent_dim="
                f"{self.spec.latent_dim}, k={self.spec.candidates}); use the reconstructor "
                "settings the sampler was trained with"
            )
        return problem_observation(
            problem,
            self.layout,
            action_scale=self.spec.action_scale,
            delta=self.spec.action_mode == "delta",
            frame_dt=self.spec.frame_dt,
        )

    def latent_gaussian(self, problem: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The model's Gaussian in ``problem``'s whitened latent space: mean and std ``(d,)``,
        and the anchor's point ``(d,)`` (None without an anchor). Actions map to points by
        ``z = x0 + scale * a`` (delta) or ``z = scale * a`` (absolute)."""
        mean, std, anchor = self.distribution(self.observe(problem))
        d = int(problem.dim)
        scale = self.spec.action_scale
        origin = np.asarray(problem.x0, dtype=np.float64) if self.spec.action_mode == "delta" else 0
        point = None if self.spec.anchor == "none" else origin + scale * anchor[:d]
        return origin + scale * mean[:d], scale * std[:d], point

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(kind={self.kind!r}, algo={self.spec.algo!r}, "
            f"observation_size={self.spec.observation_size}, features={self.features.size})"
        )


class AnchorSampler(GaussianSampler):
    """The anchor alone: zero offset and a constant spread (a baseline, nothing learned).

    With ``spec.anchor == "quadratic"`` its mean is :func:`quadratic_anchor`'s point, the
    closed-form minimiser of the energy's quadratic terms; it shows how much of a learned
    sampler's result the anchor already gives.

    Parameters
    ----------
    spec : SamplerSpec
    std : float
        Standard deviation on every axis, in action units (0.1).
    """

    def __init__(self, spec: SamplerSpec, std: float = 0.1, seed: int | None = 0) -> None:
        super().__init__(spec, seed)
        self.std = float(std)

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Zero offset, constant std."""
        shape = (len(features), self.spec.latent_dim)
        return np.zeros(shape), np.full(shape, self.std)
