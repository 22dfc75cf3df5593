"""The env's settings: the values of its modes, its checked scalar settings and the energy
weights of its arguments."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fpg_gym.core.validation import check_choice, check_integer, check_number
from fpg_gym.reconstruct import EnergyWeights

__all__ = [
    "ACTION_MODES",
    "OBSERVATION_MODES",
    "RENDER_MODES",
    "REWARD_MODES",
    "EnvSettings",
    "energy_weights_of",
]

#: Values of ``reward_mode``.
REWARD_MODES: tuple[str, ...] = ("energy", "error", "combined", "smooth")
#: Values of ``action_mode``.
ACTION_MODES: tuple[str, ...] = ("delta", "absolute")
#: Values of ``observation_mode``.
OBSERVATION_MODES: tuple[str, ...] = ("vector", "dict")
#: Values of ``render_mode`` (besides None).
RENDER_MODES: tuple[str, ...] = ("human", "rgb_array")


@dataclass(frozen=True)
class EnvSettings:
    """The scalar settings of a :class:`~fpg_gym.env.KinectPoseEnv`, checked on construction.

    The fields are the env's constructor keywords of the same names (see *Arguments* there),
    and the env's attributes of the same names. Numbers are stored as ``float`` / ``int``.

    Raises
    ------
    ValueError
        On a value out of its range or choices, naming the keyword.
    """

    reward_mode: str = "energy"
    error_weight: float = 1.0
    smooth_weight: float = 0.002
    action_mode: str = "delta"
    action_scale: float = 3.0
    clip_actions: bool = True
    observation_mode: str = "vector"
    latent_dim: int = 20
    max_episode_steps: int | None = None
    simulator_seeds: int | None = None
    render_mode: str | None = None

    def __post_init__(self) -> None:
        if self.render_mode is not None and self.render_mode not in RENDER_MODES:
            raise ValueError(
                f"render_mode: expected None, 'human' or 'rgb_array', got {self.render_mode!r}"
            )
        check_choice(self.reward_mode, "reward_mode", REWARD_MODES)
        check_choice(self.action_mode, "action_mode", ACTION_MODES)
        check_choice(self.observation_mode, "observation_mode", OBSERVATION_MODES)
        check_number(self.action_scale, "action_scale", low=0.0, low_open=True)
        check_number(self.error_weight, "error_weight", low=0.0)
        check_number(self.smooth_weight, "smooth_weight", low=0.0)
        check_integer(self.latent_dim, "latent_dim", low=1)
        if self.max_episode_steps is not None:
            check_integer(self.max_episode_steps, "max_episode_steps", low=1)
        if self.simulator_seeds is not None:
            check_integer(self.simulator_seeds, "simulator_seeds", low=1)
        normalised = {
            "error_weight": float(self.error_weight),
            "smooth_weight": float(self.smooth_weight),
            "action_scale": float(self.action_scale),
            "clip_actions": bool(self.clip_actions),
            "latent_dim": int(self.latent_dim),
            "max_episode_steps": (
                None if self.max_episode_steps is None else int(self.max_episode_steps)
            ),
            "simulator_seeds": None if self.simulator_seeds is None else int(self.simulator_seeds),
        }
        for name, value in normalised.items():
            object.__setattr__(self, name, value)


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
