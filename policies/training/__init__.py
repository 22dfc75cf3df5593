"""Training learned samplers (``fpg-gym train-sampler``).

* :mod:`policies.training.config`: :class:`TrainConfig`, a run's settings.
* :mod:`policies.training.data`: :func:`training_clips` / :func:`split_clips`, the clips a
  sampler learns from and the held-out ones it is validated on (by whole clips, seeded; by
  default the embedded clips of the default graph, never the evaluation clips);
  :func:`simulate_episodes`, Kinect streams simulated from clips x scenarios x seeds; a run's
  paired recordings.
* :mod:`policies.training.pairs`: the imitation pairs of the supervised and linear samplers
  (:func:`collect_imitation_data`, rolled through the
  :class:`~fpg_gym.reconstruct.Reconstructor`), saved and read back from checkpoints.
* :mod:`policies.training.linear`, :mod:`policies.training.supervised`: each kind's training
  step (the RL one is :func:`policies.rl.train_rl`).
* :mod:`policies.training.evaluation`: :func:`evaluate_agents`, mean energy, mean error,
  Err0.2, evaluations and ms per frame of optimisers on episodes.
* :mod:`policies.training.driver`: :func:`train_sampler`, the whole run
  (:class:`TrainConfig` -> :class:`TrainResult`).
"""

from __future__ import annotations

from policies.imitation import (
    FOLLOW,
    TARGETS,
    ImitationData,
    collect_imitation_data,
    truth_latent,
)
from policies.training.config import TrainConfig, config_dict
from policies.training.data import (
    default_training_clip_names,
    mirror_clip,
    simulate_episodes,
    split_clips,
    training_clips,
)
from policies.training.driver import TrainResult, train_sampler
from policies.training.evaluation import evaluate_agents, format_evaluation

__all__ = [
    "FOLLOW",
    "TARGETS",
    "ImitationData",
    "TrainConfig",
    "TrainResult",
    "collect_imitation_data",
    "config_dict",
    "default_training_clip_names",
    "evaluate_agents",
    "format_evaluation",
    "mirror_clip",
    "simulate_episodes",
    "split_clips",
    "train_sampler",
    "training_clips",
    "truth_latent",
]
