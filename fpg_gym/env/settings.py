"""The env's settings: the values of its modes and the energy weights of its arguments."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fpg_gym.reconstruct import EnergyWeights

__all__ = ["ACTION_MODES", "OBSERVATION_MODES", "REWARD_MODES", "energy_weights_of"]

#: Values of ``reward_mode``.
REWARD_MODES: tuple[str, ...] = ("energy", "error", "combined", "smooth")
#: Values of ``action_mode``.
ACTION_MODES: tuple[str, ...] = ("delta", "absolute")
#: Values of ``observation_mode``.
OBSERVATION_MODES: tuple[str, ...] = ("vector", "dict")


def energy_weights_of(value: Any) -> EnergyWeights:
    """``energy_weights`` as given to the env: None (the defaults), an ``EnergyWeights``, a
    mapping of its fields or 4 or 5 numbers (control, style, kinematic, motion[, prior])."""
    if value is None:
        return EnergyWeights()
    if isinstance(value, EnergyWeights):
        return value
    if isinstance(value, Mapping):
        try:
            return EnergyWeights(**{str(k): float(v) for k, v in value.items()})
        except TypeError:
            raise ValueError(
                "energy_weights: expected keys among control, style, kinematic, motion, prior, got "
                f"{sorted(value)}"
            ) from None
    values = list(value)
    if len(values) not in (4, 5):
        raise ValueError(
            "energy_weights: expected 4 or 5 weights (control, style, kinematic, motion[, "
            f"prior]), got {len(values)}"
        )
    return EnergyWeights(*(float(v) for v in values))
