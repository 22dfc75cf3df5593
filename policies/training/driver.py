"""The training driver behind ``fpg-gym train-sampler``: :func:`train_sampler` runs a whole
training (:class:`~policies.training.config.TrainConfig` -> :class:`TrainResult`): data or env,
training with periodic held-out evaluation and checkpoints, save, final evaluation."""

from __future__ import annotations

import importlib.metadata as md
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fpg_gym.core.defaults import DEFAULT_EPISODE_SCENARIOS
from fpg_gym.runtime.ray_session import check_address, require_ray
from policies.checkpoints import RunCheckpoints
from policies.learned_optimizers import LearnedSampler
from policies.rl import train_rl
from policies.sampler import GaussianSampler, import_learn, model_paths
from policies.training.config import TrainConfig
from policies.training.data import RunData, load_training_graph, run_data
from policies.training.evaluation import evaluate_agents, final_agents, format_evaluation
from policies.training.linear import check_linear_units, train_linear
from policies.training.supervised import tensorboard_dir, train_supervised

__all__ = ["TrainResult", "train_sampler"]

#: ``evaluate(sampler, agents=None)``: an evaluation table on the held-out episodes.
Evaluate = Callable[..., dict[str, Any]]


@dataclass
class TrainResult:
    """What :func:`train_sampler` did.

    Attributes
    ----------
    model : str
        Path of the model's JSON.
    sampler : GaussianSampler
    history : list of dict
        Periodic evaluations (and, supervised, every epoch's losses).
    evaluation : dict
        Final evaluation on the held-out episodes (see
        :func:`~policies.training.evaluation.evaluate_agents`).
    seconds : dict
        Wall time per phase (``data``, ``train``, ``evaluate``, ``total``).
    """

    model: str
    sampler: GaussianSampler
    history: list[dict[str, Any]]
    evaluation: dict[str, dict[str, float]]
    seconds: dict[str, float]


def train_sampler(config: TrainConfig, *, log: Callable[[str], None] | None = None) -> TrainResult:
    """Train a sampler as ``config`` says: data / env, training with periodic held-out
    evaluation and checkpoints, save, final evaluation (learned, learned+search and the
    baselines none / random-search(200) / local-search on the held-out episodes).

    Raises
    ------
    ValueError
        Bad settings, or training clips that are the default protocol's evaluation clips.
    optimizers.MissingDependency
        torch / stable-baselines3 missing (``pip install 'fpg-gym[learn]'``).
    fpg_gym.ray_session.RayUnavailable
        ``backend="ray"`` without Ray (``pip install 'fpg-gym[distributed]'``).
    """

    _check_requirements(config)
    say = log or (lambda text: print(text, flush=True))
    started = time.perf_counter()
    seconds: dict[str, float] = {}
    scenarios = list(config.scenarios or DEFAULT_EPISODE_SCENARIOS)
    graph = load_training_graph(config.graph)
    options = config.reconstructor_options()
    data = run_data(config, graph, options, scenarios, say)
    if config.kind == "linear":  # before any work: the fit cross-validates over whole units
        check_linear_units(data.units())
    out_json, stem = model_paths(config.out)
    checkpoints = stem.with_name(stem.name + ".checkpoints")
    # A supervised run goes on from a stopped one's files (or refuses other settings) now,
    # before any work.
    run = (
        RunCheckpoints(checkpoints, config.run_settings(), restart=config.restart, log=say)
        if config.kind in ("supervised", "linear")
        else None
    )
    training_info: dict[str, Any] = {
        "graph": config.graph,
        **data.info,
        "sensor_map": config.sensor_map,
        "sensor_blend": config.sensor_blend,
        # Recordings: every frame unless timesteps caps them.
        "timesteps": config.timesteps if data.paired is not None else config.total_timesteps,
        "seed": config.seed,
        "max_frames": config.max_frames,
        "versions": _versions(config.kind),
    }
    evaluate = _evaluator(config, graph, data.validation, options)
    if run is not None and config.kind == "linear":
        source = data.paired if data.paired is not None else data.clips
        sampler, history = train_linear(
            config, graph, source, scenarios, options, run, seconds, say, data.databases
        )
    elif run is not None:
        sampler, history = train_supervised(
            config,
            graph,
            data.clips,
            scenarios,
            options,
            training_info,
            evaluate,
            checkpoints,
            run,
            seconds,
            say,
        )
    else:
        sampler, history = _train_rl(
            config, graph, data, scenarios, evaluate, checkpoints, training_info, seconds, say
        )
    sampler.spec.training = {**training_info, "seconds": dict(seconds), "history": history}
    final = _final_evaluation(config, sampler, data.validation, evaluate, checkpoints, seconds)
    seconds["total"] = time.perf_counter() - started
    sampler.spec.training["seconds"] = dict(seconds)
    if final is not None:
        sampler.spec.training["evaluation"] = final
    path = sampler.save(out_json)
    if run is not None:
        run.finish()  # the model is written: its data and fit state are no longer needed
    if final is None:
        say(f"saved {path} ({sampler.spec.weights}); no held-out group, no final evaluation")
        return TrainResult(str(path), sampler, history, {}, seconds)
    say(f"saved {path} ({sampler.spec.weights})")
    say(
        f"final evaluation on {len(data.validation)} held-out episodes:\n"
        + format_evaluation(final)
    )
    return TrainResult(str(path), sampler, history, final, seconds)


def _check_requirements(config: TrainConfig) -> None:
    """Fail now, before any work, on a missing extra or a dead Ray address."""
    if config.kind != "linear":  # the linear sampler needs numpy only
        import_learn("torch")
    if config.kind == "rl":
        import_learn("stable_baselines3")
    if config.backend == "ray":
        require_ray()  # before any work
        check_address(config.address)  # a dead address fails now, not after minutes


def _evaluator(
    config: TrainConfig, graph: Any, validation: Sequence[Any], options: dict[str, Any]
) -> Evaluate:
    """``evaluate(sampler, agents=None)``: :func:`evaluate_agents` of ``agents`` (the
    sampler's mean action by default) on the held-out episodes."""

    def evaluate(sampler: GaussianSampler, agents: dict[str, Any] | None = None) -> dict[str, Any]:
        return evaluate_agents(
            graph,
            validation,
            agents or {"mean": LearnedSampler(sampler, samples=1)},
            k=config.k,
            latent_dim=config.latent_dim,
            seed=config.seed,
            reconstructor_options=options,
        )

    return evaluate


def _train_rl(
    config: TrainConfig,
    graph: Any,
    data: RunData,
    scenarios: Sequence[str],
    evaluate: Evaluate,
    checkpoints: Path,
    training_info: dict[str, Any],
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> tuple[GaussianSampler, list[dict[str, Any]]]:
    """The RL sampler (:func:`policies.rl.train_rl`) on the training clips' env; adds its
    reward settings to ``training_info``."""
    t0 = time.perf_counter()
    sampler, history = train_rl(
        graph=graph,
        clips=data.clips,
        scenarios=scenarios,
        algo=config.algo,
        timesteps=config.total_timesteps,
        seed=config.seed,
        k=config.k,
        latent_dim=config.latent_dim,
        action_scale=config.action_scale,
        action_mode=config.action_mode,
        max_frames=config.max_frames,
        features=config.features,
        anchor=config.anchor,
        anchor_style=config.anchor_style,
        hyperparameters=config.hyperparameters,
        reward_mode=config.reward,
        error_weight=config.error_weight,
        smooth_weight=config.smooth_weight,
        evaluate=evaluate,
        eval_every=config.eval_every or max(config.total_timesteps // 10, 1),
        checkpoints=checkpoints,
        tensorboard=tensorboard_dir(config.tensorboard, say),
        progress=config.progress,
        log=say,
    )
    seconds["train"] = time.perf_counter() - t0
    training_info["reward"] = config.reward
    if config.reward == "combined":
        training_info["error_weight"] = config.error_weight
    if config.reward == "smooth":
        training_info["smooth_weight"] = config.smooth_weight
    return sampler, history


def _final_evaluation(
    config: TrainConfig,
    sampler: GaussianSampler,
    validation: Sequence[Any],
    evaluate: Evaluate,
    checkpoints: Path,
    seconds: dict[str, float],
) -> dict[str, dict[str, float]] | None:
    """The trained sampler against the baselines on the held-out episodes
    (:func:`~policies.training.evaluation.final_agents`); None without any (every group
    trained, ``val_share`` 0)."""
    if not validation:
        return None
    t0 = time.perf_counter()
    final = evaluate(sampler, final_agents(sampler, config.kind, checkpoints))
    seconds["evaluate"] = time.perf_counter() - t0
    return final


def _versions(kind: str) -> dict[str, str]:
    """The versions of the packages a ``kind`` sampler's training ran with."""
    names = ["fpg-gym", "numpy", "torch"] + (
        ["stable-baselines3", "gymnasium"] if kind == "rl" else []
    )
    out = {}
    for name in names:
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = "unknown"
    return out
