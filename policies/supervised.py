"""Supervised sampler: a torch MLP that imitates a target action with a Gaussian.

The network reads a frame's features (:class:`policies.sampler.FeatureMap`, standardised with
the training set's mean and spread, kept in the model as buffers) and outputs, per latent axis,
a mean (relative to the sampler's anchor) and a log standard deviation, in action units. Two
losses over each frame's valid axes (``latent_mask``):

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
that does not carry over to new subjects or takes falls back to the anchor. The result is the
Gaussian the ``learned:PATH`` optimiser draws from. The targets are
:func:`policies.training.collect_imitation_data`'s: the best search optimum (``"best"``), the
papers' local-search optimum (``"search"``) or the ground truth (``"truth"``).

Saved as ``MODEL.pt`` (``torch.save`` of the ``state_dict``: tensors only; loaded with
``weights_only=True``) and ``MODEL.json`` (:class:`~policies.sampler.SamplerSpec`).
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
from fpg_gym.core.validation import check_number
from fpg_gym.io.files import read_json
from fpg_gym.io.npz import check_zip
from policies.sampler import (
    WEIGHTS_SUFFIX,
    GaussianSampler,
    SamplerSpec,
    check_layer_widths,
    import_learn,
    load_weights_into,
    model_paths,
)

__all__ = [
    "FIT_STATE_FORMAT",
    "LOSSES",
    "SUPERVISED_DEFAULTS",
    "FitState",
    "SupervisedSampler",
    "fit_supervised",
    "gaussian_nll",
]

#: ``format`` of a :class:`FitState` JSON.
FIT_STATE_FORMAT = "fpg-gym-supervised-fit-state"

#: Losses of :func:`fit_supervised`.
LOSSES: tuple[str, ...] = ("mse", "nll")

#: Network hyper-parameters (``SamplerSpec.hyperparameters``) and their defaults.
SUPERVISED_DEFAULTS: dict[str, Any] = {
    "hidden": [256, 256],
    "activation": "relu",
    "min_log_std": -4.0,
    "max_log_std": 1.0,
}


@functools.cache
def _module_class() -> Any:
    """The ``torch.nn.Module`` class (defined on first use: torch is an optional extra)."""
    torch = import_learn("torch")
    nn = torch.nn

    class GaussianMLP(nn.Module):  # type: ignore[name-defined]
        """Standardise, MLP, then a mean head and a clamped log-std head."""

        def __init__(
            self,
            in_size: int,
            out_size: int,
            hidden: list[int],
            activation: str,
            min_log_std: float,
            max_log_std: float,
        ) -> None:
            super().__init__()
            acts = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU}
            if activation not in acts:
                raise ValueError(f"activation: expected one of {sorted(acts)}, got {activation!r}")
            self.register_buffer("feature_mean", torch.zeros(in_size))
            self.register_buffer("feature_scale", torch.ones(in_size))
            self.register_buffer("std_scale", torch.ones(()))
            self.register_buffer("mean_scale", torch.ones(()))
            layers: list[Any] = []
            size = in_size
            for width in hidden:
                layers += [nn.Linear(size, int(width)), acts[activation]()]
                size = int(width)
            self.body = nn.Sequential(*layers)
            self.mean_head = nn.Linear(size, out_size)
            self.log_std_head = nn.Linear(size, out_size)
            with torch.no_grad():  # start at the anchor: a zero mean offset
                self.mean_head.weight.zero_()
                self.mean_head.bias.zero_()
            self.min_log_std = float(min_log_std)
            self.max_log_std = float(max_log_std)

        def forward(self, features: Any) -> tuple[Any, Any]:
            h = self.body((features - self.feature_mean) / self.feature_scale)
            log_std = self.log_std_head(h).clamp(self.min_log_std, self.max_log_std)
            return self.mean_scale * self.mean_head(h), log_std + self.std_scale.log()

    return GaussianMLP


def gaussian_nll(mean: Any, log_std: Any, target: Any, mask: Any) -> Any:
    """Mean Gaussian negative log-likelihood (without the constant) over ``mask`` entries."""
    z = (target - mean) * (-log_std).exp()
    per_entry = 0.5 * z * z + log_std
    return (per_entry * mask).sum() / mask.sum().clamp(min=1.0)


def masked_mse(mean: Any, target: Any, mask: Any) -> Any:
    """Mean squared error over ``mask`` entries (``mask`` may weight them)."""
    diff = target - mean
    return (diff * diff * mask).sum() / mask.sum().clamp(min=1.0)


class SupervisedSampler(GaussianSampler):
    """A :class:`~policies.sampler.GaussianSampler` backed by a torch MLP.

    Build one with :meth:`create` (fresh weights) or :func:`policies.loading.load_sampler`.

    Attributes
    ----------
    module : torch.nn.Module
        The network (``eval`` mode outside :func:`fit_supervised`).
    """

    def __init__(self, spec: SamplerSpec, module: Any, seed: int | None = 0) -> None:
        super().__init__(spec, seed)
        if spec.kind != "supervised":
            raise ValueError(f"SupervisedSampler: spec.kind is {spec.kind!r}")
        self.module = module
        self.module.eval()

    @classmethod
    def create(
        cls,
        spec: SamplerSpec,
        feature_mean: np.ndarray | None = None,
        feature_scale: np.ndarray | None = None,
        *,
        seed: int = 0,
    ) -> SupervisedSampler:
        """A new network for ``spec`` (weights initialised from ``seed``; torch's global RNG
        is left as it was)."""
        torch = import_learn("torch")
        hyper = {**SUPERVISED_DEFAULTS, **spec.hyperparameters}
        spec.hyperparameters = hyper
        size = spec.feature_map().size
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(seed))
            module = _build(spec, size)
        with torch.no_grad():
            if feature_mean is not None:
                module.feature_mean.copy_(torch.as_tensor(feature_mean, dtype=torch.float32))
            if feature_scale is not None:
                module.feature_scale.copy_(torch.as_tensor(feature_scale, dtype=torch.float32))
        return cls(spec, module, seed)

    @classmethod
    def load_weights(
        cls, spec: SamplerSpec, weights: str | os.PathLike[str], *, seed: int | None = 0
    ) -> SupervisedSampler:
        """A sampler from ``spec`` and its ``state_dict`` file (``torch.load(...,
        weights_only=True)``).

        Raises
        ------
        DataFormatError
            If the file is not a tensor file or its tensors do not fit the network ``spec``
            describes.
        """
        torch = import_learn("torch")
        module = _build(spec, spec.feature_map().size, source=weights)
        load_weights_into(module, weights, defaults={"mean_scale": torch.ones(())})
        return cls(spec, module, seed)

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std ``(n, L)`` of feature rows ``(n, F)`` (no gradient)."""
        torch = import_learn("torch")
        with torch.inference_mode():
            mean, log_std = self.module(torch.as_tensor(np.asarray(features, dtype=np.float32)))
        return mean.double().numpy(), log_std.double().exp().numpy()

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``MODEL.pt`` (state dict) and ``MODEL.json``; returns the JSON's path."""
        torch = import_learn("torch")
        json_path, stem = model_paths(path)
        weights = stem.with_name(stem.name + ".pt")
        state = {k: v.detach().clone() for k, v in self.module.state_dict().items()}
        with atomic_path(weights) as temporary:
            torch.save(state, temporary)
        self.spec.weights = weights.name
        return self.spec.save(json_path)


def _build(spec: SamplerSpec, in_size: int, source: str | os.PathLike[str] = "") -> Any:
    hyper = {**SUPERVISED_DEFAULTS, **spec.hyperparameters}
    hidden = check_layer_widths(hyper["hidden"], "hyperparameters.hidden", source)
    for name in ("min_log_std", "max_log_std"):  # a std of e^1e308 is no model's
        try:
            check_number(hyper[name], name, low=-20.0, high=5.0)
        except ValueError as error:
            raise DataFormatError(source, str(error), field=f"hyperparameters.{name}") from None
    if hyper["min_log_std"] > hyper["max_log_std"]:
        raise DataFormatError(
            source,
            f"min_log_std {hyper['min_log_std']} is above max_log_std {hyper['max_log_std']}",
            field="hyperparameters",
        )
    try:
        return _module_class()(
            in_size,
            spec.latent_dim,
            hidden,
            str(hyper["activation"]),
            float(hyper["min_log_std"]),
            float(hyper["max_log_std"]),
        )
    except (TypeError, ValueError, KeyError) as error:
        raise DataFormatError(source, f"bad network description ({error})") from None


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

    def tensors(
        obs: np.ndarray,
        act: np.ndarray,
        mask: np.ndarray,
        transformed: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[Any, Any, Any]:
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

    def objective(mean: Any, log_std: Any, target: Any, mask: Any) -> Any:
        if loss == "nll":
            return gaussian_nll(mean, log_std, target, mask)
        return masked_mse(mean, target, mask) + gaussian_nll(mean.detach(), log_std, target, mask)

    x, y, m = tensors(observations, actions, masks, transformed)
    val = None
    if validation is not None and len(validation[0]):
        val = tensors(*validation)
    module = sampler.module
    with torch.no_grad():
        module.std_scale.fill_(1.0)
    optimiser = torch.optim.Adam(module.parameters(), lr=learning_rate, weight_decay=weight_decay)
    rng = np.random.default_rng(seed)
    history: list[dict[str, Any]] = []
    best_mse, best_state, best_epoch = np.inf, None, None
    if state is not None:
        if not 0 <= state.epoch <= epochs:
            raise ValueError(f"state: {state.epoch} epochs done, expected 0..{epochs}")
        module.load_state_dict(state.module)
        optimiser.load_state_dict(state.optimiser)
        rng.bit_generator.state = state.shuffling
        history = [dict(record) for record in state.history]
        best_mse, best_state, best_epoch = state.best_mse, state.best_module, state.best_epoch
    first_epoch = 1 if state is None else state.epoch + 1
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
            module.train()
            order = torch.as_tensor(rng.permutation(len(x)))
            total = 0.0
            for i in range(0, len(x), batch_size):
                idx = order[i : i + batch_size]
                mean, log_std = module(x[idx])
                value = objective(mean, log_std, y[idx], m[idx])
                optimiser.zero_grad()
                value.backward()
                optimiser.step()
                total += float(value.detach()) * len(idx)
            module.eval()
            record: dict[str, Any] = {"epoch": epoch, "train_loss": total / len(x)}
            if val is not None:
                with torch.inference_mode():
                    mean, log_std = module(val[0])
                    record["val_loss"] = float(objective(mean, log_std, val[1], val[2]))
                    record["val_mse"] = float(masked_mse(mean, val[1], val[2]))
            record["seconds"] = time.perf_counter() - start
            if restore_best and val is not None and record["val_mse"] < best_mse:
                best_mse, best_epoch = record["val_mse"], epoch
                best_state = {k: v.detach().clone() for k, v in module.state_dict().items()}
            history.append(record)
            if bar is not None:
                bar.update(1)
                bar.set_postfix({k: f"{v:.3f}" for k, v in record.items() if "loss" in k})
            if on_epoch is not None:
                on_epoch(record)
            if on_state is not None:
                on_state(
                    FitState(
                        epoch=epoch,
                        module=module.state_dict(),
                        optimiser=optimiser.state_dict(),
                        shuffling=dict(rng.bit_generator.state),
                        best_mse=float(best_mse),
                        best_epoch=best_epoch,
                        best_module=best_state,
                        history=history,
                    )
                )
    finally:
        if bar is not None:
            bar.close()
        module.eval()
    if best_state is not None and best_epoch is not None:
        module.load_state_dict(best_state)
        history[best_epoch - 1]["best"] = True
    if shrink and val is not None:
        # The learned offset, scaled by the factor in [0, 1] that fits the validation targets
        # best (least squares): 0 when nothing learned carries over, i.e. the anchor alone.
        with torch.no_grad():
            module.mean_scale.fill_(1.0)
            mean, _ = module(val[0])
            num = float((val[1] * mean * val[2]).sum())
            den = float((mean * mean * val[2]).sum())
            module.mean_scale.fill_(float(np.clip(num / den, 0.0, 1.0)) if den > 0 else 0.0)
        history[-1]["mean_scale"] = float(module.mean_scale)
    if calibrate and val is not None:
        with torch.inference_mode():
            mean, log_std = module(val[0])
            z = (val[1] - mean) * (-log_std).exp()
            ratio = float((z * z * val[2]).sum() / val[2].sum().clamp(min=1.0))
            module.std_scale.fill_(float(np.sqrt(max(ratio, 1e-6))))
        history[-1]["std_scale"] = float(module.std_scale)
    return history
