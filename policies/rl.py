"""RL sampler: a stable-baselines3 PPO or SAC policy trained on ``fpg_gym/KinectPose-v0``.

The policy acts on the env with the ``energy`` reward (``-E``, Shum Eq. 10: no ground truth
needed). A Gymnasium wrapper (:meth:`policies.sampler.FeatureMap.wrap`) shows it the sampler's
features instead of the raw observation vector and adds its action to the sampler's anchor
(the closed-form minimiser of the energy's quadratic terms, by default), so the policy learns
an offset from the anchor and its spread; the env does not clip the sum. Its Gaussian:

* PPO: SB3's diagonal Gaussian, a state-dependent mean and a learned, state-independent
  standard deviation (``log_std_init`` -1 by default: std 0.37 action units, about one whitened
  unit at ``action_scale`` 3);
* SAC: a squashed Gaussian ``tanh(N(mu, sigma))``; the sampler reports ``tanh(mu)`` and the
  linearised spread ``sigma (1 - tanh(mu)^2)``.

The discount is 0.5: a frame's action matters mostly for its own energy (later frames feel it
only through the continuity terms), and a short horizon keeps the value estimates less noisy.

Saved as ``MODEL.pt``, the policy network's ``state_dict`` (tensors only, ``torch.save``), plus
``MODEL.json`` (:class:`~policies.sampler.SamplerSpec`: the algorithm, ``net_arch`` and
``log_std_init`` among its hyper-parameters). Loading rebuilds the SB3 policy network from the
JSON and reads the tensors with ``torch.load(..., weights_only=True)``: a model file is data and
never runs code. SB3's own ``.zip`` format (whose entries are unpickled on load) is refused
(:func:`policies.sampler.load_weights_file`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import atomic_path
from fpg_gym.env import REWARD_MODES, KinectPoseEnv
from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE
from policies.rl_callback import training_callback
from policies.sampler import (
    DEFAULT_FEATURES,
    GaussianSampler,
    SamplerSpec,
    check_layer_widths,
    import_learn,
    load_weights_into,
    model_paths,
)

__all__ = [
    "ALGOS",
    "RL_DEFAULTS",
    "RL_REWARDS",
    "UNTRAINED_CHECKPOINT",
    "RLSampler",
    "make_training_env",
    "train_rl",
    "zero_action",
]

#: Supported algorithms.
ALGOS: tuple[str, ...] = ("ppo", "sac")

#: Algorithm settings (``SamplerSpec.hyperparameters`` overrides them); ``net_arch`` and
#: ``log_std_init`` go to the policy.
RL_DEFAULTS: dict[str, dict[str, Any]] = {
    "ppo": {
        "learning_rate": 3e-4,
        "n_steps": 1024,
        "batch_size": 128,
        "n_epochs": 5,
        "gamma": 0.5,
        "gae_lambda": 0.9,
        "clip_range": 0.2,
        "ent_coef": 0.0,
        "net_arch": [256, 256],
        "log_std_init": -1.0,
    },
    "sac": {
        "learning_rate": 3e-4,
        "buffer_size": 100_000,
        "batch_size": 256,
        "learning_starts": 1_000,
        "gamma": 0.5,
        "train_freq": 1,
        "gradient_steps": 1,
        "net_arch": [256, 256],
        "log_std_init": -1.0,
    },
}
_POLICY_KEYS = ("net_arch", "log_std_init")
#: The rewards an RL sampler trains on: the env's (:data:`fpg_gym.env.REWARD_MODES`) and
#: ``"energy-gain"`` (:class:`EnergyGain`).
RL_REWARDS: tuple[str, ...] = (*REWARD_MODES, "energy-gain")
#: The checkpoint of the untrained policy among :func:`train_rl`'s (``checkpoints/NAME``).
UNTRAINED_CHECKPOINT = "step-00000000"


def _algo_class(algo: str) -> Any:
    sb3 = import_learn("stable_baselines3")
    if algo not in ALGOS:
        raise ValueError(f"algo: expected one of {ALGOS}, got {algo!r}")
    return sb3.PPO if algo == "ppo" else sb3.SAC


class RLSampler(GaussianSampler):
    """A :class:`~policies.sampler.GaussianSampler` backed by an SB3 PPO or SAC policy network.

    Parameters
    ----------
    spec : SamplerSpec
    policy : stable_baselines3.common.policies.BasePolicy
        The policy network (``model.policy`` of a PPO or SAC model, or one rebuilt by
        :meth:`load_weights`).
    seed : int, optional

    Attributes
    ----------
    policy : stable_baselines3 ActorCriticPolicy (PPO) or SACPolicy (SAC)
    """

    def __init__(self, spec: SamplerSpec, policy: Any, seed: int | None = 0) -> None:
        super().__init__(spec, seed)
        if spec.kind != "rl" or spec.algo not in ALGOS:
            raise ValueError(f"RLSampler: expected an rl spec with algo in {ALGOS}, got {spec}")
        self.policy = policy

    @classmethod
    def build_policy(cls, spec: SamplerSpec, source: str | os.PathLike[str] = "") -> Any:
        """A fresh (untrained) SB3 policy network of the shape ``spec`` describes.

        Raises
        ------
        DataFormatError
            If ``net_arch`` or ``log_std_init`` in the JSON are not sensible.
        """
        import_learn("stable_baselines3")
        if spec.algo not in ALGOS:
            raise DataFormatError(
                source, f"expected algo one of {ALGOS}, got {spec.algo!r}", field="algo"
            )
        hyper = {**RL_DEFAULTS[spec.algo], **spec.hyperparameters}
        net_arch = check_layer_widths(hyper["net_arch"], "hyperparameters.net_arch", source)
        log_std_init = hyper["log_std_init"]
        if not isinstance(log_std_init, int | float) or not -20.0 <= float(log_std_init) <= 5.0:
            raise DataFormatError(
                source,
                f"expected a number in [-20, 5], got {log_std_init!r}",
                field="hyperparameters.log_std_init",
            )
        feature_map = spec.feature_map()
        observation_space = gym.spaces.Box(feature_map.low, feature_map.high, dtype=np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (spec.latent_dim,), dtype=np.float32)
        kwargs: dict[str, Any] = {"net_arch": net_arch, "log_std_init": float(log_std_init)}
        policy: Any
        if spec.algo == "ppo":
            from stable_baselines3.common.policies import ActorCriticPolicy

            policy = ActorCriticPolicy(observation_space, action_space, _Constant(0.0), **kwargs)
        else:
            from stable_baselines3.sac.policies import SACPolicy

            policy = SACPolicy(observation_space, action_space, _Constant(0.0), **kwargs)
        policy.set_training_mode(False)
        return policy

    @classmethod
    def load_weights(
        cls, spec: SamplerSpec, weights: str | os.PathLike[str], *, seed: int | None = 0
    ) -> RLSampler:
        """A sampler from ``spec`` and its ``MODEL.pt`` (tensors, ``weights_only=True``).

        Raises
        ------
        DataFormatError
            If the file is not a tensor file (an SB3 ``.zip`` included) or its tensors do not
            fit the network the JSON describes.
        """
        policy = cls.build_policy(spec, weights)
        load_weights_into(policy, weights)
        policy.set_training_mode(False)
        return cls(spec, policy, seed)

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std ``(n, L)`` (action units) of feature rows ``(n, F)``."""
        torch = import_learn("torch")
        obs = torch.as_tensor(np.asarray(features, dtype=np.float32))
        policy = self.policy
        with torch.no_grad():
            if self.spec.algo == "ppo":
                distribution = policy.get_distribution(obs).distribution
                mean, std = distribution.mean, distribution.stddev
            else:
                mu, log_std, _ = policy.actor.get_action_dist_params(obs)
                mean = torch.tanh(mu)
                std = log_std.exp() * (1.0 - mean * mean)
        mean_np = mean.double().numpy().reshape(len(features), -1)
        std_np = np.broadcast_to(std.double().numpy(), mean_np.shape).copy()
        return mean_np, np.maximum(std_np, 1e-6)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``MODEL.pt`` (the policy's ``state_dict``: tensors only) and ``MODEL.json``;
        returns the JSON's path."""
        torch = import_learn("torch")
        json_path, stem = model_paths(path)
        weights = stem.with_name(stem.name + ".pt")
        state = {k: v.detach().clone().cpu() for k, v in self.policy.state_dict().items()}
        with atomic_path(weights) as temporary:
            torch.save(state, temporary)
        self.spec.weights = weights.name
        return self.spec.save(json_path)


def zero_action(sampler: RLSampler) -> RLSampler:
    """A copy of ``sampler`` whose mean action is zero in every state (the Gaussian centred on
    its anchor, or on ``x0`` without one) with the same spread: the reference a trained
    policy's proposals must beat."""
    torch = import_learn("torch")
    policy = RLSampler.build_policy(sampler.spec)
    policy.load_state_dict(sampler.policy.state_dict())
    head = policy.action_net if sampler.spec.algo == "ppo" else policy.actor.mu
    with torch.no_grad():
        head.weight.zero_()
        head.bias.zero_()
    return RLSampler(sampler.spec, policy)


class _Constant:
    """A constant schedule (the policy's learning rate, unused when sampling)."""

    def __init__(self, value: float) -> None:
        self.value = float(value)

    def __call__(self, _progress: float) -> float:
        return self.value


class EnergyGain(gym.Wrapper):
    """The ``"energy-gain"`` reward: ``log(E(x0) / E(z))``, how many times the chosen point
    lowers the energy (Shum Eq. 10) of the search's start ``x0`` (the previous reconstruction
    projected), instead of ``-E(z)``. The same best point in every frame, but a reward on one
    scale whatever the frame's energy (which spans orders of magnitude between frames), so the
    policy gradient is not dominated by the frames that are hard for every action."""

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """Step; the reward is the log energy ratio."""
        observation, _, terminated, truncated, info = self.env.step(action)
        gain = np.log(max(info["energy_x0"], 1e-12) / max(info["energy"], 1e-12))
        return observation, float(gain), terminated, truncated, info


def make_training_env(
    graph: Any,
    clips: Sequence[Any],
    scenarios: Sequence[str],
    *,
    k: int = 30,
    latent_dim: int = 20,
    action_scale: float = 3.0,
    action_mode: str = "delta",
    max_frames: int | None = None,
    reward_mode: str = "energy",
    error_weight: float = 1.0,
    smooth_weight: float = 0.002,
) -> Any:
    """The training env: ``KinectPoseEnv`` with the ``reward_mode`` reward (the energy by
    default, or its gain over ``x0``, :class:`EnergyGain`; ``"error"``, ``"combined"`` with
    ``error_weight`` or ``"smooth"`` with ``smooth_weight`` learn the simulated ground truth),
    no ragdoll (the compared methods run without one), episodes from ``clips`` x
    ``scenarios``, unclipped actions (the policy's action is added to the sampler's anchor,
    :meth:`FeatureMap.wrap`)."""

    if reward_mode not in RL_REWARDS:
        raise ValueError(f"reward_mode: expected one of {RL_REWARDS}, got {reward_mode!r}")
    env = KinectPoseEnv(
        graph,
        clips=list(clips),
        scenarios=list(scenarios),
        k=k,
        latent_dim=latent_dim,
        action_scale=action_scale,
        action_mode=action_mode,
        reward_mode="energy" if reward_mode == "energy-gain" else reward_mode,
        error_weight=error_weight,
        smooth_weight=smooth_weight,
        clip_actions=False,
        ragdoll=False,
        max_episode_steps=max_frames,
    )
    return EnergyGain(env) if reward_mode == "energy-gain" else env


def train_rl(
    *,
    graph: Any,
    clips: Sequence[Any],
    scenarios: Sequence[str],
    algo: str = "ppo",
    timesteps: int = 100_000,
    seed: int = 0,
    k: int = 30,
    latent_dim: int = 20,
    action_scale: float = 3.0,
    action_mode: str = "delta",
    max_frames: int | None = None,
    features: Sequence[str] = DEFAULT_FEATURES,
    anchor: str = "quadratic",
    anchor_style: float = DEFAULT_STYLE,
    hyperparameters: dict[str, Any] | None = None,
    reward_mode: str = "energy",
    error_weight: float = 1.0,
    smooth_weight: float = 0.002,
    evaluate: Callable[[GaussianSampler], dict[str, Any]] | None = None,
    eval_every: int | None = None,
    checkpoints: str | os.PathLike[str] | None = None,
    tensorboard: str | None = None,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> tuple[RLSampler, list[dict[str, Any]]]:
    """Train an SB3 ``algo`` policy on the env's reward (``reward_mode``: the energy by
    default, or the ground-truth error, alone or combined); returns the sampler and its
    history.

    Parameters
    ----------
    graph, clips, scenarios, k, latent_dim, action_scale, action_mode, max_frames
        The training env (:func:`make_training_env`).
    algo : {"ppo", "sac"}
    timesteps : int
        Env steps.
    seed : int
        SB3's seed (it seeds Python, numpy and torch, as SB3 does) and the env's.
    features : sequence of str
        Observation fields the policy reads.
    anchor, anchor_style
        The Gaussian's anchor (:class:`~policies.sampler.FeatureMap`): the policy's action is
        an offset from it.
    hyperparameters : dict, optional
        Overrides of :data:`RL_DEFAULTS`.
    reward_mode : {"energy", "energy-gain", "error", "combined", "smooth"}
        The env's reward (:class:`~fpg_gym.env.KinectPoseEnv`; ``"energy-gain"``:
        :class:`EnergyGain`); ``error_weight`` weighs the error in ``"combined"``,
        ``smooth_weight`` the output's acceleration in ``"smooth"``.
    error_weight, smooth_weight : float
    evaluate : callable, optional
        ``evaluate(sampler) -> {"mean": {...}}`` run every ``eval_every`` steps (a checkpoint
        is saved then too, in ``checkpoints``).
    tensorboard : str, optional
        SB3's ``tensorboard_log`` folder (needs tensorboard).
    progress : bool
        A tqdm bar over the steps.
    log : callable, optional
        Receives one-line messages.

    Returns
    -------
    sampler : RLSampler
    history : list of dict
        ``{"timesteps", "reward_per_step"}`` every twentieth of the run (the mean reward of
        the steps since the last record) and the periodic evaluations (``eval_*``, between
        updates: the first at step 0, before any training, the last of the returned policy).
    """
    import_learn("stable_baselines3")
    algo_class = _algo_class(algo)
    hyper = _rl_hyperparameters(algo, hyperparameters, timesteps)
    env = make_training_env(
        graph,
        clips,
        scenarios,
        k=k,
        latent_dim=latent_dim,
        action_scale=action_scale,
        action_mode=action_mode,
        max_frames=max_frames,
        reward_mode=reward_mode,
        error_weight=error_weight,
        smooth_weight=smooth_weight,
    )
    spec = _rl_spec(env, algo, hyper, features, anchor, anchor_style)
    model = _sb3_model(algo_class, env, spec, seed, tensorboard)
    sampler = RLSampler(spec, model.policy, seed)
    say = log or (lambda text: None)
    folder = None if checkpoints is None else Path(checkpoints)
    callback = training_callback(sampler, timesteps, evaluate, eval_every, folder, progress, say)
    model.learn(total_timesteps=timesteps, callback=callback, tb_log_name=f"sampler_{algo}")
    env.close()
    return sampler, callback.history


def _rl_spec(
    env: Any,
    algo: str,
    hyper: dict[str, Any],
    features: Sequence[str],
    anchor: str,
    anchor_style: float,
) -> SamplerSpec:
    """The spec of an RL sampler trained on ``env`` (its layout, weights and actions) with
    the algorithm's hyper-parameters, the features it reads and its anchor."""
    return SamplerSpec.for_env(
        env,
        "rl",
        algo,
        features=list(features),
        anchor=anchor,
        anchor_style=anchor_style,
        hyperparameters=dict(hyper),
    )


def _sb3_model(
    algo_class: Any, env: Any, spec: SamplerSpec, seed: int, tensorboard: str | None
) -> Any:
    """The SB3 ``algo_class`` model with ``spec``'s hyper-parameters on ``env`` seen through
    the spec's features (:meth:`FeatureMap.wrap`), seeded, on the CPU."""
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    hyper = spec.hyperparameters
    feature_map = spec.feature_map()
    vec_env = DummyVecEnv([lambda: Monitor(feature_map.wrap(env))])
    policy_kwargs = {key: hyper[key] for key in _POLICY_KEYS}
    policy_kwargs["net_arch"] = [int(w) for w in policy_kwargs["net_arch"]]
    algo_kwargs = {key: v for key, v in hyper.items() if key not in _POLICY_KEYS}
    return algo_class(
        "MlpPolicy",
        vec_env,
        seed=seed,
        device="cpu",
        verbose=0,
        policy_kwargs=policy_kwargs,
        tensorboard_log=tensorboard,
        **algo_kwargs,
    )


def _rl_hyperparameters(
    algo: str, hyperparameters: dict[str, Any] | None, timesteps: int
) -> dict[str, Any]:
    """:data:`RL_DEFAULTS` of ``algo`` with ``hyperparameters`` over them (unknown keys
    refused); PPO's rollout and batch no longer than the run."""
    hyper = {**RL_DEFAULTS[algo], **(hyperparameters or {})}
    unknown = sorted(set(hyper) - set(RL_DEFAULTS[algo]))
    if unknown:
        raise ValueError(f"hyperparameters for {algo}: unknown {unknown}")
    if algo == "ppo":
        hyper["n_steps"] = int(min(hyper["n_steps"], max(timesteps, 2)))
        hyper["batch_size"] = int(min(hyper["batch_size"], hyper["n_steps"]))
    return hyper
