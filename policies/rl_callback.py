"""The stable-baselines3 callback of :func:`policies.rl.train_rl`: the reward curve, the
periodic held-out evaluations and checkpoints."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from policies.sampler import GaussianSampler

__all__ = ["training_callback"]


def training_callback(
    sampler: GaussianSampler,
    timesteps: int,
    evaluate: Callable[[GaussianSampler], dict[str, Any]] | None,
    eval_every: int | None,
    checkpoints: Path | None,
    progress: bool,
    say: Callable[[str], None],
) -> Any:
    """The SB3 callback of a run of ``timesteps`` env steps training ``sampler``'s policy; its
    ``history`` attribute receives the reward every twentieth of the run and the evaluations
    (see :func:`~policies.rl.train_rl`).

    ``evaluate(sampler) -> {"mean": {...}}`` runs every ``eval_every`` steps, a checkpoint
    (``step-NNNNNNNN``) is saved then in ``checkpoints``, and ``say`` receives a line;
    ``progress``: a tqdm bar over the steps. Imports stable-baselines3 (the ``learn`` extra).
    """
    from stable_baselines3.common.callbacks import BaseCallback

    algo = sampler.spec.algo
    history: list[dict[str, Any]] = []
    record_every = max(timesteps // 20, 1)

    class TrainingCallback(BaseCallback):
        """Records the reward and evaluates the policy between updates: at the start of the
        first rollout after each ``eval_every`` steps, and once more at the end of training,
        so that every evaluated policy is one that updates left as it is, and the last
        evaluation is of the policy :func:`~policies.rl.train_rl` returns (a PPO update
        follows every rollout: an evaluation during the rollout would score a policy the run
        then changes)."""

        def __init__(self) -> None:
            super().__init__()
            self.history = history
            self.bar: Any = None
            self.rewards: list[float] = []
            self.started = time.perf_counter()
            self.evaluated_at: int | None = None

        def _on_training_start(self) -> None:
            if evaluate is not None and eval_every:
                self._evaluate(0)  # the untrained policy: the reference of the curve
            if progress:
                self.bar = tqdm(total=timesteps, desc=f"train {algo}", unit="step", leave=False)

        def _on_rollout_start(self) -> None:
            steps = int(self.num_timesteps)
            if evaluate is not None and eval_every:
                if (self.evaluated_at or 0) // eval_every < steps // eval_every:
                    self._evaluate(steps)

        def _on_step(self) -> bool:
            self.rewards.extend(float(r) for r in np.ravel(self.locals.get("rewards", [])))
            steps = int(self.num_timesteps)
            if self.bar is not None:
                self.bar.update(steps - self.bar.n)
            if steps % record_every == 0 and self.rewards:
                history.append(
                    {
                        "timesteps": steps,
                        "reward_per_step": float(np.mean(self.rewards)),
                        "seconds": time.perf_counter() - self.started,
                    }
                )
                if self.bar is not None:
                    self.bar.set_postfix({"reward/step": f"{history[-1]['reward_per_step']:.4f}"})
                self.rewards = []
            return True

        def _evaluate(self, steps: int) -> None:
            assert evaluate is not None
            self.evaluated_at = steps
            table = evaluate(sampler)["mean"]
            record = {"timesteps": steps, **{f"eval_{k}": v for k, v in table.items()}}
            history.append(record)
            self.logger.record("eval/mean_energy", table["mean_energy"])
            self.logger.record("eval/mean_error", table["mean_error"])
            name = ""
            if checkpoints is not None:  # step 0: the untrained policy, for reference
                name = sampler.save(checkpoints / f"step-{steps:08d}").name
            say(
                f"step {steps}: held-out mean action: energy {table['mean_energy']:.4f}, "
                f"error {table['mean_error']:.4f} m" + (f" (checkpoint {name})" if name else "")
            )

        def _on_training_end(self) -> None:
            if self.bar is not None:
                self.bar.close()
            steps = int(self.num_timesteps)
            if evaluate is not None and eval_every and self.evaluated_at != steps:
                self._evaluate(steps)  # the policy the run returns (after its last update)

    return TrainingCallback()
