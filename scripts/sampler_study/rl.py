"""An RL sampler as a search accelerator: PPO trained on the energy's gain, its proposals
against the local search, the untrained policy and the zero action, paired per episode."""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import numpy as np

from fpg_gym.core import metrics
from fpg_gym.reconstruct import Reconstructor
from policies.learned_optimizers import LearnedSampler
from policies.training import TrainConfig, simulate_episodes, train_sampler
from sampler_study import SCENARIOS
from sampler_study.tables import change

#: ``train-sampler`` settings of the RL search accelerator (``--protocols rl``): no closed
#: form (the Gaussian centred on the search's start), the energy's gain as the reward, the
#: latent coordinates of the sensor, prediction and start with the reliabilities as features,
#: and PPO settings for a one-frame problem (no discount).
RL_ACCELERATOR: dict[str, Any] = {
    "kind": "rl",
    "algo": "ppo",
    "graph": "default",
    "anchor": "none",
    "action_mode": "delta",
    "reward": "energy-gain",
    "features": ["x0", "z_kinect", "z_prediction", "reliability", "latent_std", "latent_mask"],
    "hyperparameters": {
        "learning_rate": 1e-3,
        "n_steps": 2048,
        "batch_size": 256,
        "n_epochs": 10,
        "gamma": 0.0,
        "gae_lambda": 0.0,
        "net_arch": [64, 64],
    },
    "timesteps": 300_000,
    "eval_every": 75_000,
}


def _agents(model: str) -> dict[str, tuple[int, Any]]:
    """Each row's ``(evaluations per frame, optimiser)``: the local search at 2,000 and 200,
    closed-form, the model of ``model`` as ``learned+search:``, ``learned:`` and its mean
    alone, its untrained policy and its zero action."""
    import optimizers.local_search as local
    from policies.learned_optimizers import LearnedSearch
    from policies.loading import load_sampler
    from policies.rl import UNTRAINED_CHECKPOINT, zero_action

    trained = load_sampler(model)
    untrained = load_sampler(f"{model}.checkpoints/{UNTRAINED_CHECKPOINT}")
    return {
        "local-search": (2000, local.LocalSearch()),
        "local-search (200)": (200, local.LocalSearch(iterations=2)),
        "closed-form": (1, "closed-form"),
        "learned+search": (200, LearnedSearch(trained)),
        "learned": (200, LearnedSampler(trained)),
        "mean alone": (1, LearnedSampler(trained, samples=1)),
        "untrained, learned+search": (200, LearnedSearch(untrained)),
        "zero action, learned+search": (200, LearnedSearch(zero_action(trained))),
    }


def _evaluate(
    agents: dict[str, tuple[int, Any]], graph: Any, recordings: list[Any]
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Each agent's mean error and mean energy per episode, with the per-frame problem
    (temporal stage off, as the env's), optimiser seed = episode number."""
    from fpg_gym.reconstruct import TemporalConfig

    errors: dict[str, list[float]] = {name: [] for name in agents}
    energies: dict[str, list[float]] = {name: [] for name in agents}
    for i, recording in enumerate(recordings):
        with Reconstructor(graph, ragdoll=False, temporal=TemporalConfig.off()) as reconstructor:
            for name, (_, agent) in agents.items():
                result = reconstructor.reconstruct(recording, agent, rng=i)
                errors[name].append(
                    float(metrics.frame_error(recording.ground_truth, result.poses).mean())
                )
                energies[name].append(float(result.arrays()["energy"].mean()))
    return errors, energies


def _comparison(
    agents: dict[str, tuple[int, Any]],
    errors: dict[str, list[float]],
    energies: dict[str, list[float]],
) -> str:
    """The table of every agent against the local search (paired 95 % bootstrap intervals)
    and the sentence of ``learned+search`` against its untrained policy, its zero action and
    the local search at 200."""
    rng = np.random.default_rng(2016)
    base = np.array(errors["local-search"])
    lines = [
        "| method | evaluations/frame | mean error (m) [95 % CI] | vs local-search [95 % CI] "
        "| lower than local-search on | mean energy |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for name, (evaluations, _) in agents.items():
        values = np.array(errors[name])
        low, high = metrics.bootstrap_mean_ci(values, rng=rng)
        lines.append(
            f"| {name} | {evaluations:,} | {values.mean():.4f} [{low:.4f}, {high:.4f}] | "
            f"{change(values, base, rng)} | {(values < base).sum()} of {len(values)} | "
            f"{np.mean(energies[name]):.4f} |"
        )
    learned = np.array(errors["learned+search"])
    against = [
        f"against {name}: {change(learned, np.array(errors[name]), rng)}, lower on "
        f"{(learned < np.array(errors[name])).sum()} of {len(learned)}"
        for name in (
            "untrained, learned+search",
            "zero action, learned+search",
            "local-search (200)",
        )
    ]
    return "\n".join(lines) + "\n\n`learned+search` " + "; ".join(against) + ".\n"


def rl_protocol(args: argparse.Namespace) -> str:
    """An RL sampler's proposals against the local search (module docstring): train one
    (unless ``--rl-model``), then every agent on the embedded held-out clips x the ``*-many``
    scenarios x ``--rl-eval-seeds``, each episode with the per-frame problem (temporal stage
    off, as the env's), errors paired against ``local-search`` (2,000) and against the
    untrained policy and the zero action."""
    from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
    from fpg_gym.graph import load_graph
    from policies.training import training_clips

    folder = args.out / "rl"
    folder.mkdir(parents=True, exist_ok=True)
    model = args.rl_model
    trained_note = f"model {model}"
    if model is None:
        model = str(folder / "sampler_rl")
        c0, w0 = time.process_time(), time.perf_counter()
        train_sampler(TrainConfig(out=model, seed=args.rl_seed, progress=False, **RL_ACCELERATOR))
        trained_note = (
            f"trained in {time.process_time() - c0:.0f} s CPU, {time.perf_counter() - w0:.0f} s "
            f"wall (seed {args.rl_seed})"
        )
    agents = _agents(model)
    graph = load_graph("default", exclude=DEFAULT_HOLDOUT_CLIPS)
    clips = training_clips(list(DEFAULT_HOLDOUT_CLIPS))
    seeds = [int(s) for s in args.rl_eval_seeds.split(",")]
    recordings = simulate_episodes(clips, SCENARIOS.split(","), seeds)
    c0 = time.process_time()
    errors, energies = _evaluate(agents, graph, recordings)
    report = (
        f"### RL sampler as a search accelerator ({len(recordings)} episodes: the embedded "
        f"held-out clips x {SCENARIOS} x seeds {args.rl_eval_seeds}, "
        f"{sum(r.num_frames for r in recordings)} frames; {trained_note}; evaluation "
        f"{time.process_time() - c0:.0f} s CPU)\n\n" + _comparison(agents, errors, energies)
    )
    (folder / "table.md").write_text(report)
    (folder / "errors.json").write_text(json.dumps({"errors": errors, "energies": energies}))
    print(report, flush=True)
    return report
