"""A sampler's weights file (``MODEL.pt``, a torch ``state_dict`` of tensors): reading it
without running code from it, the checks of its values and of the layer widths a JSON asks
for, and a model's file paths."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.errors import DataFormatError
from fpg_gym.io.npz import check_zip
from policies.sampler.extra import import_learn
from policies.sampler.spec import MAX_MODEL_VALUE

__all__ = [
    "WEIGHTS_SUFFIX",
    "check_layer_widths",
    "check_model_values",
    "load_weights_file",
    "load_weights_into",
    "model_paths",
]

#: Suffix of every weights file (a torch ``state_dict`` of tensors).
WEIGHTS_SUFFIX = ".pt"
#: Bounds on what a JSON may ask to build (a hostile file must not exhaust memory).
MAX_LAYER_WIDTH = 8192
MAX_LAYERS = 16


def check_layer_widths(widths: Any, name: str, source: str | os.PathLike[str] = "") -> list[int]:
    """``widths`` as a list of layer widths, checked: at most :data:`MAX_LAYERS` integers in
    1..:data:`MAX_LAYER_WIDTH` (a JSON must not make the loader allocate without bound).

    Raises
    ------
    DataFormatError
        Naming ``source`` and the field ``name``.
    """
    if (
        not isinstance(widths, list | tuple)
        or len(widths) > MAX_LAYERS
        or any(
            isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= MAX_LAYER_WIDTH
            for w in widths
        )
    ):
        raise DataFormatError(
            source,
            f"expected a list of at most {MAX_LAYERS} layer widths in 1..{MAX_LAYER_WIDTH}, got "
            f"{widths!r}",
            field=name,
        )
    return [int(w) for w in widths]


def load_weights_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``state_dict`` in a weights file: ``torch.load(..., weights_only=True)``, which
    rebuilds tensors and plain containers only and never runs code from the file.

    Raises
    ------
    DataFormatError
        If the file is not a ``.pt`` tensor file: an SB3 ``.zip`` (pickled entries), a
        pickle of Python objects, or anything that is not a mapping of names to tensors.
    """
    torch = import_learn("torch")
    source = Path(path)
    refuse = (
        "only tensor files are loaded (a torch state_dict saved by fpg-gym train-sampler, "
        "read with weights_only=True)"
    )
    if source.suffix != WEIGHTS_SUFFIX:
        raise DataFormatError(
            source,
            f"{refuse}; a '{source.suffix}' file is refused"
            + (
                " (stable-baselines3 .zip models hold pickled Python objects, which could run "
                "code; retrain the sampler with this fpg-gym: `fpg-gym train-sampler --kind rl`)"
                if source.suffix == ".zip"
                else ""
            ),
        )
    check_zip(source)  # declared sizes within the memory ceiling, before torch inflates it
    try:
        state = torch.load(source, map_location="cpu", weights_only=True)
    except Exception as error:  # the weights-only unpickler's errors vary (UnpicklingError, ...)
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise DataFormatError(source, f"{refuse}; this file is not one ({first[:300]})") from None
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise DataFormatError(source, f"{refuse}; expected a mapping of names to tensors")
    for name, tensor in state.items():
        if tensor.is_floating_point() or tensor.is_complex():
            check_model_values(source, name, tensor.detach().double().numpy())
    return dict(state)


def check_model_values(source: str | os.PathLike[str], name: str, values: Any) -> None:
    """Refuse a model array holding NaN, inf or a magnitude beyond :data:`MAX_MODEL_VALUE`.

    Raises
    ------
    DataFormatError
        Naming ``source`` and the array ``name``.
    """
    array = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise DataFormatError(source, "NaN or inf in a model's numbers", field=name)
    largest = float(np.abs(array).max(initial=0.0))
    if largest > MAX_MODEL_VALUE:
        raise DataFormatError(
            source,
            f"a value of {largest:g}: not a trained model's (expected magnitudes up to "
            f"{MAX_MODEL_VALUE:g})",
            field=name,
        )


def load_weights_into(
    module: Any, path: str | os.PathLike[str], defaults: Mapping[str, Any] | None = None
) -> None:
    """Load a weights file (:func:`load_weights_file`) into a torch module, strictly.

    ``defaults`` gives tensors that files written before they existed lack.

    Raises
    ------
    DataFormatError
        If the file is refused, or its tensors do not fit the module built from the JSON.
    """
    state = load_weights_file(path)
    for name, value in (defaults or {}).items():
        state.setdefault(name, value)
    try:
        module.load_state_dict(state, strict=True)
    except (RuntimeError, ValueError) as error:
        raise DataFormatError(
            path, f"the tensors do not fit the network in the JSON ({error})"
        ) from None


def model_paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """``(MODEL.json, stem)`` of a model path given as ``MODEL``, ``MODEL.json``, ``.pt`` or
    ``.zip``."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".json", ".pt", ".zip") else p
    return stem.with_name(stem.name + ".json"), stem
