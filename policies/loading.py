"""Loading a saved sampler: the JSON spec and tensor weights, rebuilt as the right class.

Kept apart from :mod:`policies.sampler` (the base class) because it needs both subclasses
(:mod:`policies.supervised`, :mod:`policies.rl`), which import the base.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

from fpg_gym.core.errors import DataFormatError
from fpg_gym.io.files import file_digest
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

__all__ = ["LEARNED_PREFIXES", "load_sampler", "model_digest", "model_files"]

#: Optimiser name prefixes whose argument is a model path (``learned:MODEL``).
LEARNED_PREFIXES: tuple[str, ...] = ("learned", "learned+search")


def _description(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """``(MODEL.json, stem)`` of a model path, the JSON checked to exist."""
    if not str(path).strip():
        raise ValueError(
            "learned:MODEL: expected the path of a sampler after 'learned:' (the --out of "
            "fpg-gym train-sampler), got an empty name"
        )
    json_path, stem = model_paths(path)
    if not json_path.is_file():
        raise FileNotFoundError(
            f"{path}: no sampler description {json_path} (models are saved as MODEL.json "
            "beside MODEL.pt by fpg-gym train-sampler)"
        )
    return json_path, stem


def _weights_path(spec: SamplerSpec, json_path: Path, stem: Path) -> Path:
    """The weights file a sampler description names (a file beside it)."""
    suffix = {"rl": ".zip", "linear": LINEAR_WEIGHTS_SUFFIX}.get(spec.kind, WEIGHTS_SUFFIX)
    name = spec.weights or stem.name + suffix
    if not isinstance(name, str) or Path(name).name != name or name in ("", ".", ".."):
        raise DataFormatError(
            json_path, f"expected a file name beside the JSON, got {name!r}", field="weights"
        )
    return json_path.parent / name


def model_files(path: str | os.PathLike[str]) -> list[Path]:
    """The files a saved sampler is read from: its JSON, and its weights when they exist.

    Raises
    ------
    ValueError
        An empty name.
    FileNotFoundError
        No ``MODEL.json``.
    DataFormatError
        Not a sampler description.
    """
    json_path, stem = _description(path)
    weights = _weights_path(SamplerSpec.load(json_path), json_path, stem)
    return [json_path, *([weights] if weights.is_file() else [])]


def model_digest(path: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of a saved sampler's files (:func:`model_files`): a resume key that
    changes when the model's description or weights change, whatever their path."""
    digest = hashlib.sha256()
    for file in model_files(path):
        digest.update(file.name.encode() + b"\0" + file_digest(file).encode())
    return digest.hexdigest()


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
    ValueError
        An empty name.
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
    json_path, stem = _description(path)
    spec = SamplerSpec.load(json_path)
    if env is not None:
        spec.check_env(env)
    weights = _weights_path(spec, json_path, stem)
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
