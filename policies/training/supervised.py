"""The supervised sampler's training step: its imitation pairs, a tenth of their episodes
held out, the fit (:func:`policies.supervised_fit.fit_supervised`) with periodic held-out
evaluations and checkpoints, going on from a stopped run's fit state."""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from policies.checkpoints import RunCheckpoints
from policies.sampler import GaussianSampler
from policies.supervised import SupervisedSampler
from policies.supervised_fit import fit_supervised
from policies.training.config import TrainConfig
from policies.training.pairs import imitation_pairs, imitation_spec

__all__ = ["tensorboard_dir", "train_supervised"]


def train_supervised(
    config: TrainConfig,
    graph: Any,
    train_clips: Sequence[Any],
    scenarios: Sequence[str],
    options: dict[str, Any],
    training_info: dict[str, Any],
    evaluate: Callable[..., dict[str, Any]],
    checkpoints: Path,
    run: RunCheckpoints,
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> tuple[GaussianSampler, list[dict[str, Any]]]:
    """The supervised sampler (:mod:`policies.supervised`) fitted on imitation pairs of
    simulated streams of ``train_clips``, a tenth of their episodes held out for the fit's
    validation; every ``eval_every`` epochs (and at the last), ``evaluate`` scores its mean
    action on the held-out episodes and a checkpoint is saved in ``checkpoints``. Adds the
    frames and the target to ``training_info``."""
    spec = imitation_spec(config, "supervised", "mlp", config.features, epochs=config.epochs)
    data, _, _ = imitation_pairs(
        config, graph, train_clips, scenarios, options, spec, run, seconds, say
    )
    # Validation pairs: a tenth of the episodes, by whole episodes.
    episode_ids = np.unique(data.episodes)
    rng = np.random.default_rng(config.seed + 1)
    held = rng.permutation(episode_ids)[: max(1, len(episode_ids) // 10)]
    is_val = np.isin(data.episodes, held) if len(episode_ids) > 1 else np.zeros(len(data), bool)
    train = ~is_val
    train_observations = data.observations[train]
    # Features and anchors of the training pairs, computed once (fit_supervised reuses them).
    transformed = spec.feature_map().transform(train_observations)
    features = transformed[0]
    mean = features.mean(axis=0)
    scale = np.maximum(features.std(axis=0), 1e-3)
    sampler = SupervisedSampler.create(spec, mean, scale, seed=config.seed)
    eval_every = config.eval_every or max(config.epochs // 5, 1)
    fit_keys = ("batch_size", "learning_rate", "weight_decay", "loss", "weighting")
    fit_args = {k: config.hyperparameters[k] for k in fit_keys if k in config.hyperparameters}
    tensorboard = _tensorboard_writer(config.tensorboard, say)

    def on_epoch(record: dict[str, Any]) -> None:
        epoch = int(record["epoch"])
        if tensorboard is not None:
            for key in ("train_loss", "val_loss"):
                if key in record:
                    tensorboard.add_scalar(f"supervised/{key}", record[key], epoch)
        if epoch % eval_every == 0 or epoch == config.epochs:
            table = evaluate(sampler)["mean"]
            record.update({f"eval_{k}": v for k, v in table.items()})
            path = sampler.save(checkpoints / f"epoch-{epoch:04d}")
            say(
                f"epoch {epoch}: train loss {record['train_loss']:.3f}, validation loss "
                f"{record.get('val_loss', float('nan')):.3f}, MSE "
                f"{record.get('val_mse', float('nan')):.4f}; held-out mean action: energy "
                f"{table['mean_energy']:.4f}, error {table['mean_error']:.4f} m "
                f"(checkpoint {path.name})"
            )
            if tensorboard is not None:
                tensorboard.add_scalar("eval/mean_energy", table["mean_energy"], epoch)
                tensorboard.add_scalar("eval/mean_error", table["mean_error"], epoch)

    fit = run.load_fit()
    if fit is not None:
        say(f"{checkpoints}: going on from epoch {fit.epoch}")
    t0 = time.perf_counter()
    try:
        history = fit_supervised(
            sampler,
            train_observations,
            data.actions[train],
            data.masks[train],
            epochs=config.epochs,
            seed=config.seed,
            validation=(data.observations[is_val], data.actions[is_val], data.masks[is_val])
            if is_val.any()
            else None,
            on_epoch=on_epoch,
            progress=config.progress,
            transformed=transformed,
            state=fit,
            on_state=run.save_fit,
            **fit_args,
        )
    finally:
        if tensorboard is not None:
            tensorboard.close()
    seconds["train"] = time.perf_counter() - t0
    best = [r["epoch"] for r in history if r.get("best")]
    if best:
        say(
            f"kept the weights of epoch {best[0]} (lowest validation MSE); spread x "
            f"{history[-1].get('std_scale', 1.0):.2f} (calibrated on the validation pairs)"
        )
    training_info["frames"] = len(data)
    training_info["target"] = config.target
    return sampler, history


def _tensorboard_available() -> bool:
    return importlib.util.find_spec("tensorboard") is not None


def tensorboard_dir(folder: str | None, say: Callable[[str], None]) -> str | None:
    """``folder`` when TensorBoard logs can be written there (tensorboard installed), else
    None (with a note when a folder was asked for)."""
    if folder is None:
        return None
    if not _tensorboard_available():
        say("train-sampler: tensorboard is not installed; no TensorBoard logs are written")
        return None
    return folder


def _tensorboard_writer(folder: str | None, say: Callable[[str], None]) -> Any:
    """A TensorBoard ``SummaryWriter`` of ``folder`` (None: no logs, :func:`tensorboard_dir`)."""
    if tensorboard_dir(folder, say) is None:
        return None
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(log_dir=folder)
