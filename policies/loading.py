"""Loading a saved sampler: the JSON spec and tensor weights, rebuilt as the right class.

Kept apart from :mod:`policies.sampler` (the base class) because it needs both subclasses
(:mod:`policies.supervised`, :mod:`policies.rl`), which import the base.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from fpg_gym.errors import DataFormatError
from policies.pose_sampler import LINEAR_WEIGHTS_SUFFIX, LinearPoseSampler
from policies.rl import RLSampler
from policies.sampler import (
    WEIGHTS_SUFFIX,
    GaussianSampler,
    SamplerSpec,
    load_weights_file,
    model_paths,
)
from policies.supervised import SupervisedSampler

__all__ = ["load_sampler"]


def load_sampler(
    path: str | os.PathLike[str], *, env: Any = None, seed: int | None = 0
) -> GaussianSampler:
    """Load a sampler saved by ``fpg-gym train-sampler`` (``MODEL``, ``.json`` or ``.pt``).

    The weights are tensors only, read with ``weights_only=True``, and the network is rebuilt
    from the JSON: nothing in the files is executed. An RL sampler saved by an earlier fpg-gym as
    SB3's ``.zip`` is refused.

    With ``env`` (a :class:`~fpg_gym.env.KinectPoseEnv`, wrapped or not), refuse an env whose
    observation or actions differ from the ones the model was trained on
    (:meth:`SamplerSpec.check_env`).

    Raises
    ------
    FileNotFoundError
        No ``MODEL.json`` or no weights file beside it.
    DataFormatError
        Not a sampler description, a weights file that is not a tensor file (an SB3 ``.zip``
        included), or tensors that do not fit the network the JSON describes.
    ValueError
        ``env`` has another observation size or action mode.
    optimizers.MissingDependency
        torch / stable-baselines3 are not installed (``pip install 'fpg-gym[learn]'``).
    """
    json_path, stem = model_paths(path)
    if not json_path.is_file():
        raise FileNotFoundError(
            f"{path}: no sampler description {json_path} (models are saved as MODEL.json "
            "beside MODEL.pt by fpg-gym train-sampler)"
        )
    spec = SamplerSpec.load(json_path)
    if env is not None:
        spec.check_env(env)
    suffix = {"rl": ".zip", "linear": LINEAR_WEIGHTS_SUFFIX}.get(spec.kind, WEIGHTS_SUFFIX)
    name = spec.weights or stem.name + suffix
    if not isinstance(name, str) or Path(name).name != name or name in ("", ".", ".."):
        raise DataFormatError(
            json_path, f"expected a file name beside the JSON, got {name!r}", field="weights"
        )
    weights = json_path.parent / name
    if spec.kind == "linear":
        if weights.suffix != LINEAR_WEIGHTS_SUFFIX or not weights.is_file():
            raise FileNotFoundError(
                f"{json_path}: its weights file {weights} is missing (a linear sampler's "
                f"weights are a {LINEAR_WEIGHTS_SUFFIX} beside the JSON)"
            )
        return LinearPoseSampler.load_weights(spec, weights, seed=seed)
    if weights.suffix != WEIGHTS_SUFFIX:
        load_weights_file(weights)  # refuses it, naming the format
    if not weights.is_file():
        raise FileNotFoundError(f"{json_path}: its weights file {weights} is missing")
    if spec.kind == "supervised":
        return SupervisedSampler.load_weights(spec, weights, seed=seed)

    return RLSampler.load_weights(spec, weights, seed=seed)
