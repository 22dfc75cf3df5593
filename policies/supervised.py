"""Supervised sampler: a torch MLP that imitates a target action with a Gaussian.

The network reads a frame's features (:class:`policies.sampler.FeatureMap`, standardised with
the training set's mean and spread, kept in the model as buffers) and outputs, per latent axis,
a mean (relative to the sampler's anchor) and a log standard deviation, in action units, scaled
by the buffers ``mean_scale`` and ``std_scale`` its fit sets (:mod:`policies.supervised_fit`).
The result is the Gaussian the ``learned:PATH`` optimiser draws from.

Saved as ``MODEL.pt`` (``torch.save`` of the ``state_dict``: tensors only; loaded with
``weights_only=True``) and ``MODEL.json`` (:class:`~policies.sampler.SamplerSpec`).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import atomic_path
from fpg_gym.core.validation import check_number
from policies.sampler import (
    GaussianSampler,
    SamplerSpec,
    check_layer_widths,
    import_learn,
    load_weights_into,
    model_paths,
)

__all__ = ["SUPERVISED_DEFAULTS", "SupervisedSampler"]


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


class SupervisedSampler(GaussianSampler):
    """A :class:`~policies.sampler.GaussianSampler` backed by a torch MLP.

    Build one with :meth:`create` (fresh weights) or :func:`policies.loading.load_sampler`.

    Attributes
    ----------
    module : torch.nn.Module
        The network (``eval`` mode outside :func:`policies.supervised_fit.fit_supervised`).
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
