"""The supervised sampler's fit (:func:`fit_supervised`) and its resumable state
(:class:`FitState`).

Two losses over each frame's valid axes (``latent_mask``):

* ``"mse"`` (default): ``(a - mu)^2`` fits the mean, and the Gaussian negative log-likelihood
  with the mean held fixed (``0.5 ((a - sg(mu)) / sigma)^2 + log sigma``) fits the spread:
  "MSE + learned log-std";
* ``"nll"``: the Gaussian negative log-likelihood of both.

Axes are weighted by their spread squared (``weighting="pose"``): the loss then measures the
error of the pose, not of the whitened coordinates, whose flat low-spread axes carry an
arbitrary optimum (on held-out embedded clips this weighting makes the learned mean cut the
pose-space error of the anchor by about 60 %, where the unweighted one barely learns).

Early stopping keeps the epoch with the lowest validation error of the mean; the spread is then
calibrated on the validation pairs (one factor ``c`` with ``mean(((a - mu) / (c sigma))^2) =
1``, stored as the buffer ``std_scale``), because a spread fitted on training frames is too
narrow on new ones; before that, the learned offset is shrunk towards the anchor by the factor
in [0, 1] that fits the validation targets best (the buffer ``mean_scale``), so that an offset
that does not carry over to new subjects or takes falls back to the anchor. The targets are
:func:`policies.training.collect_imitation_data`'s: the best search optimum (``"best"``), the
papers' local-search optimum (``"search"``) or the ground truth (``"truth"``).
"""

from __future__ import annotations

import functools
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.jsonable import jsonable
from fpg_gym.core.outputs import atomic_path
from fpg_gym.io.files import read_json
from fpg_gym.io.npz import check_zip
from policies.sampler import WEIGHTS_SUFFIX, import_learn
from policies.supervised import SupervisedSampler

__all__ = [
    "FIT_STATE_FORMAT",
    "LOSSES",
    "FitState",
    "fit_supervised",
    "gaussian_nll",
    "masked_mse",
]

#: ``format`` of a :class:`FitState` JSON.
FIT_STATE_FORMAT = "fpg-gym-supervised-fit-state"

#: Losses of :func:`fit_supervised`.
LOSSES: tuple[str, ...] = ("mse", "nll")


def gaussian_nll(mean: Any, log_std: Any, target: Any, mask: Any) -> Any:
    """Mean Gaussian negative log-likelihood (without the constant) over ``mask`` entries."""
    z = (target - mean) * (-log_std).exp()
    per_entry = 0.5 * z * z + log_std
    return (per_entry * mask).sum() / mask.sum().clamp(min=1.0)


def masked_mse(mean: Any, target: Any, mask: Any) -> Any:
    """Mean squared error over ``mask`` entries (``mask`` may weight them)."""
    diff = target - mean
    return (diff * diff * mask).sum() / mask.sum().clamp(min=1.0)


@dataclass
class FitState:
    """:func:`fit_supervised` after a finished epoch: what it needs to go on exactly.

    Attributes
    ----------
    epoch : int
        Epochs finished.
    module : dict
        The network's ``state_dict``.
    optimiser : dict
        Adam's ``state_dict``.
    shuffling : dict
        The shuffling generator's ``bit_generator.state`` (plain ints and strings).
    best_mse : float
        Lowest validation MSE so far (``inf`` without validation).
    best_epoch : int or None
        Its epoch.
    best_module : dict or None
        The network's ``state_dict`` at that epoch.
    history : list of dict
        The epoch records so far.
    """

    epoch: int
    module: dict[str, Any]
    optimiser: dict[str, Any]
    shuffling: dict[str, Any]
    best_mse: float
    best_epoch: int | None
    best_module: dict[str, Any] | None
    history: list[dict[str, Any]]

    def save(self, stem: str | os.PathLike[str]) -> Path:
        """Write ``STEM.pt`` (tensors: network, Adam, best network; ``torch.save``) and then
        ``STEM.json`` (the rest), each atomically; returns the JSON's path (written last, so a
        JSON on disk always has its tensors)."""
        torch = import_learn("torch")
        stem = Path(stem)
        tensors = {"module": self.module, "optimiser": self.optimiser}
        if self.best_module is not None:
            tensors["best_module"] = self.best_module
        with atomic_path(stem.with_suffix(WEIGHTS_SUFFIX)) as temporary:
            torch.save(tensors, temporary)
        description = {
            "format": FIT_STATE_FORMAT,
            "epoch": self.epoch,
            "shuffling": self.shuffling,
            "best_mse": None if not np.isfinite(self.best_mse) else self.best_mse,
            "best_epoch": self.best_epoch,
            "history": self.history,
        }
        target = stem.with_suffix(".json")
        with atomic_path(target) as temporary:
            temporary.write_text(json.dumps(jsonable(description), indent=1) + "\n")
        return target

    @classmethod
    def load(cls, stem: str | os.PathLike[str]) -> FitState:
        """Read :meth:`save`'s files (tensors with ``torch.load(..., weights_only=True)``).

        Raises
        ------
        DataFormatError
            Naming the file, when it is not a fit state.
        """
        torch = import_learn("torch")
        stem = Path(stem)
        source = stem.with_suffix(".json")
        data = read_json(source)
        if not isinstance(data, dict) or data.get("format") != FIT_STATE_FORMAT:
            raise DataFormatError(source, f"expected format {FIT_STATE_FORMAT!r}", field="format")
        weights = check_zip(stem.with_suffix(WEIGHTS_SUFFIX))  # sizes before torch inflates
        try:
            tensors = torch.load(weights, map_location="cpu", weights_only=True)
        except Exception as error:  # torch raises several kinds on a bad file
            raise DataFormatError(weights, f"not a fit-state tensor file ({error})") from None
        if not isinstance(tensors, dict) or not {"module", "optimiser"} <= set(tensors):
            raise DataFormatError(weights, "expected the entries 'module' and 'optimiser'")
        best = data.get("best_mse")
        try:
            return cls(
                epoch=int(data["epoch"]),
                module=tensors["module"],
                optimiser=tensors["optimiser"],
                shuffling=dict(data["shuffling"]),
                best_mse=float("inf") if best is None else float(best),
                best_epoch=None if data.get("best_epoch") is None else int(data["best_epoch"]),
                best_module=tensors.get("best_module"),
                history=list(data["history"]),
            )
        except (KeyError, TypeError, ValueError) as error:
            raise DataFormatError(source, f"bad fit state ({error!r})") from None


def fit_supervised(
    sampler: SupervisedSampler,
    observations: np.ndarray,
    actions: np.ndarray,
    masks: np.ndarray,
    *,
    epochs: int = 40,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    weight_decay: float = 1e-5,
    loss: str = "mse",
    weighting: str = "pose",
    seed: int = 0,
    validation: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    on_epoch: Callable[[dict[str, Any]], None] | None = None,
    restore_best: bool = True,
    calibrate: bool = True,
    shrink: bool = True,
    progress: bool = False,
    transformed: tuple[np.ndarray, np.ndarray] | None = None,
    state: FitState | None = None,
    on_state: Callable[[FitState], None] | None = None,
) -> list[dict[str, Any]]:
    """Fit ``sampler``'s network to target ``actions`` (see the module docstring).

    Parameters
    ----------
    sampler : SupervisedSampler
    observations : ndarray, shape (n, N)
        Env observations (the model reads its features).
    actions : ndarray, shape (n, L)
        Target actions (the network learns their offsets from the anchor).
    masks : ndarray, shape (n, L)
        1 for the valid latent axes of each frame.
    epochs, batch_size, learning_rate, weight_decay : training settings (Adam).
    loss : {"mse", "nll"}
    weighting : {"pose", "uniform"}
        Weights of the latent axes in the loss. ``"pose"``: each axis by its spread squared
        (``latent_std^2``), normalised per frame, so that the loss measures the error of the
        pose (the basis is orthonormal: ``||dx||^2 = sum_i (std_i dz_i)^2``) instead of
        treating the flat, low-spread axes, where the energy hardly changes and the optimum is
        arbitrary, like the others. ``"uniform"``: every valid axis alike.
    seed : int
        Shuffling order (a numpy generator); torch's global RNG is not touched.
    validation : (observations, actions, masks), optional
        Scored after every epoch: ``val_loss`` (the training loss) and ``val_mse`` (the
        weighted squared error of the mean).
    on_epoch : callable, optional
        Receives each epoch's record (``epoch``, ``train_loss``, ``val_loss``, ``val_mse``,
        ``seconds``) and may add to it; a periodic evaluation or a checkpoint hooks in here.
    restore_best : bool
        With ``validation``: end with the weights of the epoch with the lowest ``val_mse``
        (early stopping; its record gets ``"best": True``).
    calibrate : bool
        With ``validation``: scale the spread so that the validation targets' squared
        standardised offsets average 1 (``std_scale``).
    shrink : bool
        With ``validation``: scale the learned offset from the anchor by the factor in [0, 1]
        that fits the validation targets best (``mean_scale``; 0 falls back to the anchor when
        what was learned does not carry over to the validation split). Before ``calibrate``.
    progress : bool
        A tqdm bar over the epochs.
    transformed : (features, anchor), optional
        ``sampler.features.transform(observations)`` when the caller has it already (it is
        computed here otherwise).
    state : FitState, optional
        Go on from this state (a run with the same data and settings that stopped after
        ``state.epoch`` epochs): the result is the same as that of the uninterrupted run.
    on_state : callable, optional
        Receives the :class:`FitState` after every epoch (after ``on_epoch``), e.g. to save it.

    Returns
    -------
    list of dict
        The epoch records.
    """
    torch = import_learn("torch")
    _check_fit_inputs(observations, actions, masks, epochs, batch_size, loss, weighting)
    objective = functools.partial(_objective, loss)
    x, y, m = _loss_tensors(sampler, weighting, observations, actions, masks, transformed)
    val = None
    if validation is not None and len(validation[0]):
        val = _loss_tensors(sampler, weighting, *validation)
    module = sampler.module
    with torch.no_grad():
        module.std_scale.fill_(1.0)
    optimiser = torch.optim.Adam(module.parameters(), lr=learning_rate, weight_decay=weight_decay)
    run = _FitRun(module, optimiser, np.random.default_rng(seed), objective, (x, y, m), val)
    if state is not None:
        run.resume(state, epochs)
    first_epoch = 1 if state is None else state.epoch + 1
    run.run(first_epoch, epochs, batch_size, restore_best, progress, on_epoch, on_state)
    return run.finish(shrink=shrink, calibrate=calibrate)


def _check_fit_inputs(
    observations: np.ndarray,
    actions: np.ndarray,
    masks: np.ndarray,
    epochs: int,
    batch_size: int,
    loss: str,
    weighting: str,
) -> None:
    """Raise ``ValueError`` on :func:`fit_supervised` settings or data it cannot fit."""
    if loss not in LOSSES:
        raise ValueError(f"loss: expected one of {LOSSES}, got {loss!r}")
    if weighting not in ("pose", "uniform"):
        raise ValueError(f"weighting: expected 'pose' or 'uniform', got {weighting!r}")
    if len(observations) != len(actions) or len(actions) != len(masks):
        raise ValueError(
            f"observations, actions, masks: expected the same length, got {len(observations)}, "
            f"{len(actions)}, {len(masks)}"
        )
    if len(actions) == 0:
        raise ValueError("no training samples")
    if epochs < 1 or batch_size < 1:
        raise ValueError(f"epochs, batch_size: expected >= 1, got {epochs}, {batch_size}")


def _loss_tensors(
    sampler: SupervisedSampler,
    weighting: str,
    obs: np.ndarray,
    act: np.ndarray,
    mask: np.ndarray,
    transformed: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[Any, Any, Any]:
    """The network's inputs, its targets (the actions' offsets from the anchor) and the loss
    weights of the latent axes (``weighting``, see :func:`fit_supervised`), as tensors."""
    torch = import_learn("torch")
    # The network outputs the mean relative to the anchor: fit the targets' offsets.
    features, anchor = sampler.features.transform(obs) if transformed is None else transformed
    offsets = np.asarray(act, dtype=np.float64) - anchor
    weights = np.asarray(mask, dtype=np.float64)
    if weighting == "pose":
        spread = sampler.layout.split(np.asarray(obs))["latent_std"].astype(np.float64)
        weights = weights * spread**2
        valid = np.maximum(np.asarray(mask, dtype=np.float64).sum(axis=1, keepdims=True), 1)
        weights = weights / np.maximum(weights.sum(axis=1, keepdims=True) / valid, 1e-12)
    return (
        torch.as_tensor(features),
        torch.as_tensor(offsets.astype(np.float32)),
        torch.as_tensor(weights.astype(np.float32)),
    )


def _objective(loss: str, mean: Any, log_std: Any, target: Any, mask: Any) -> Any:
    """The training loss: the Gaussian NLL (``"nll"``), or the mean's weighted MSE plus the
    NLL of the spread alone (``"mse"``)."""
    if loss == "nll":
        return gaussian_nll(mean, log_std, target, mask)
    return masked_mse(mean, target, mask) + gaussian_nll(mean.detach(), log_std, target, mask)


def _validation_losses(
    module: Any, val: tuple[Any, Any, Any], objective: Callable[..., Any]
) -> dict[str, float]:
    """``val_loss`` (the training loss) and ``val_mse`` (the mean's weighted squared error)
    on the validation tensors."""
    torch = import_learn("torch")
    with torch.inference_mode():
        mean, log_std = module(val[0])
        return {
            "val_loss": float(objective(mean, log_std, val[1], val[2])),
            "val_mse": float(masked_mse(mean, val[1], val[2])),
        }


def _shrink_offset(module: Any, val: tuple[Any, Any, Any]) -> float:
    """Set and return the network's ``mean_scale``: the learned offset, scaled by the factor
    in [0, 1] that fits the validation targets best (least squares): 0 when nothing learned
    carries over, i.e. the anchor alone."""
    torch = import_learn("torch")
    with torch.no_grad():
        module.mean_scale.fill_(1.0)
        mean, _ = module(val[0])
        num = float((val[1] * mean * val[2]).sum())
        den = float((mean * mean * val[2]).sum())
        module.mean_scale.fill_(float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0)
    return float(module.mean_scale)


def _calibrate_spread(module: Any, val: tuple[Any, Any, Any]) -> float:
    """Set and return the network's ``std_scale``: the validation targets' squared
    standardised offsets then average 1."""
    torch = import_learn("torch")
    with torch.inference_mode():
        mean, log_std = module(val[0])
        z = (val[1] - mean) * (-log_std).exp()
        ratio = float((z * z * val[2]).sum() / val[2].sum().clamp(min=1.0))
        module.std_scale.fill_(float(np.sqrt(max(ratio, 1e-6))))
    return float(module.std_scale)


class _FitRun:
    """:func:`fit_supervised`'s epochs: the network, Adam, the shuffling generator, the
    training and validation tensors, the epoch records and the best validation MSE's epoch
    and weights."""

    def __init__(
        self,
        module: Any,
        optimiser: Any,
        rng: np.random.Generator,
        objective: Callable[..., Any],
        data: tuple[Any, Any, Any],
        val: tuple[Any, Any, Any] | None,
    ) -> None:
        self.module = module
        self.optimiser = optimiser
        self.rng = rng
        self.objective = objective
        self.data = data
        self.val = val
        self.history: list[dict[str, Any]] = []
        self.best_mse = np.inf
        self.best_epoch: int | None = None
        self.best_module: dict[str, Any] | None = None

    def resume(self, state: FitState, epochs: int) -> None:
        """Go on from ``state`` (its network, Adam, shuffling and records restored)."""
        if not 0 <= state.epoch <= epochs:
            raise ValueError(f"state: {state.epoch} epochs done, expected 0..{epochs}")
        self.module.load_state_dict(state.module)
        self.optimiser.load_state_dict(state.optimiser)
        self.rng.bit_generator.state = state.shuffling
        self.history = [dict(record) for record in state.history]
        self.best_mse, self.best_module = state.best_mse, state.best_module
        self.best_epoch = state.best_epoch

    def run(
        self,
        first_epoch: int,
        epochs: int,
        batch_size: int,
        keep_best: bool,
        progress: bool,
        on_epoch: Callable[[dict[str, Any]], None] | None,
        on_state: Callable[[FitState], None] | None,
    ) -> None:
        """Epochs ``first_epoch``..``epochs`` (:meth:`epoch`), each record to ``on_epoch``
        and then the state to ``on_state``; a tqdm bar with ``progress``."""
        bar = None
        if progress:
            bar = tqdm(
                total=epochs,
                initial=first_epoch - 1,
                desc="train supervised",
                unit="epoch",
                leave=False,
            )
        start = time.perf_counter()
        try:
            for epoch in range(first_epoch, epochs + 1):
                record = self.epoch(epoch, batch_size, start, keep_best=keep_best)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix({k: f"{v:.3f}" for k, v in record.items() if "loss" in k})
                if on_epoch is not None:
                    on_epoch(record)
                if on_state is not None:
                    on_state(self.state(epoch))
        finally:
            if bar is not None:
                bar.close()
            self.module.eval()

    def epoch(self, epoch: int, batch_size: int, start: float, keep_best: bool) -> dict[str, Any]:
        """Train one epoch (Adam over shuffled batches), score the validation tensors, keep
        the weights when their MSE is the lowest so far (``keep_best``); the epoch's record."""
        torch = import_learn("torch")
        x, y, m = self.data
        self.module.train()
        order = torch.as_tensor(self.rng.permutation(len(x)))
        total = 0.0
        for i in range(0, len(x), batch_size):
            idx = order[i : i + batch_size]
            mean, log_std = self.module(x[idx])
            value = self.objective(mean, log_std, y[idx], m[idx])
            self.optimiser.zero_grad()
            value.backward()
            self.optimiser.step()
            total += float(value.detach()) * len(idx)
        self.module.eval()
        record: dict[str, Any] = {"epoch": epoch, "train_loss": total / len(x)}
        if self.val is not None:
            record.update(_validation_losses(self.module, self.val, self.objective))
        record["seconds"] = time.perf_counter() - start
        if keep_best and self.val is not None and record["val_mse"] < self.best_mse:
            self.best_mse, self.best_epoch = record["val_mse"], epoch
            state = self.module.state_dict()
            self.best_module = {k: v.detach().clone() for k, v in state.items()}
        self.history.append(record)
        return record

    def state(self, epoch: int) -> FitState:
        """The :class:`FitState` after ``epoch``."""
        return FitState(
            epoch=epoch,
            module=self.module.state_dict(),
            optimiser=self.optimiser.state_dict(),
            shuffling=dict(self.rng.bit_generator.state),
            best_mse=float(self.best_mse),
            best_epoch=self.best_epoch,
            best_module=self.best_module,
            history=self.history,
        )

    def finish(self, *, shrink: bool, calibrate: bool) -> list[dict[str, Any]]:
        """Restore the best epoch's weights, then shrink the offset and calibrate the spread
        on the validation tensors (as asked); the epoch records."""
        history = self.history
        if self.best_module is not None and self.best_epoch is not None:
            self.module.load_state_dict(self.best_module)
            history[self.best_epoch - 1]["best"] = True
        if shrink and self.val is not None:
            history[-1]["mean_scale"] = _shrink_offset(self.module, self.val)
        if calibrate and self.val is not None:
            history[-1]["std_scale"] = _calibrate_spread(self.module, self.val)
        return history
