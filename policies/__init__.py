"""Learned candidate samplers (numpy, torch, stable-baselines3): a Gaussian over the latent space.

A sampler maps the observation of a frame of ``fpg_gym/KinectPose-v0`` to a mean and a standard
deviation per latent axis, in the env's action units (:mod:`policies.sampler`), centred on an
*anchor* computed from the observation (by default the closed-form minimiser of the energy's
quadratic terms, :func:`quadratic_anchor`):

* :class:`~policies.pose_sampler.LinearPoseSampler`: a ridge model of the ground truth's offset
  from the anchor in the frame's pose, numpy only (:mod:`policies.pose_sampler`);
* :class:`~policies.supervised.SupervisedSampler`: a torch MLP imitating the local-search
  optimum (or the ground truth) with a Gaussian likelihood (:mod:`policies.supervised`);
* :class:`~policies.rl.RLSampler`: a stable-baselines3 PPO or SAC policy trained on the env's
  energy reward (:mod:`policies.rl`).

Train with ``fpg-gym train-sampler`` (:func:`policies.training.train_sampler`), load with
:func:`load_sampler`, act in the env with ``sampler.predict(obs)`` (so
:func:`fpg_gym.episodes.run_episode` runs it), or search with the optimisers
``learned:PATH`` / ``learned+search:PATH`` (:mod:`policies.learned_optimizers`).

torch and stable-baselines3 are the optional extra ``pip install 'fpg-gym[learn]'``: importing
this package and the linear sampler need neither; using another sampler without them raises
:class:`optimizers.MissingDependency` naming the extra.
"""

from __future__ import annotations

from policies.loading import load_sampler
from policies.sampler import (
    DEFAULT_FEATURES,
    FEATURE_SETS,
    INSTALL_HINT,
    LATENT_FEATURES,
    MASKED_CONTEXT,
    AnchorSampler,
    FeatureMap,
    GaussianSampler,
    SamplerSpec,
    import_learn,
    problem_observation,
    quadratic_anchor,
)

__all__ = [
    "DEFAULT_FEATURES",
    "FEATURE_SETS",
    "INSTALL_HINT",
    "LATENT_FEATURES",
    "MASKED_CONTEXT",
    "AnchorSampler",
    "FeatureMap",
    "GaussianSampler",
    "SamplerSpec",
    "import_learn",
    "load_sampler",
    "problem_observation",
    "quadratic_anchor",
]
