"""The One-Euro filter: a speed-adaptive low-pass filter per joint (Casiez, Roussel & Vogel 2012).

Casiez, Roussel, Vogel, "1 € Filter: A Simple Speed-based Low-pass Filter for Noisy Input in
Interactive Systems", CHI 2012. Per joint, with sample ``x_n``, interval ``dt`` and the
exponential smoothing factor ``alpha(fc) = 1 / (1 + tau / dt)``, ``tau = 1 / (2 pi fc)``:

1. speed: ``dx_n = alpha(d_cutoff) (x_n - x_{n-1}) / dt + (1 - alpha(d_cutoff)) dx_{n-1}``;
2. cutoff: ``fc = min_cutoff + beta ||dx_n||`` (Hz): slow motion is smoothed hard (jitter goes),
   fast motion lightly (lag goes);
3. position: ``y_n = alpha(fc) x_n + (1 - alpha(fc)) y_{n-1}``.

The speed is the norm of the joint's 3-D velocity (one cutoff per joint, so the three axes of a
joint are filtered alike and a direction is not distorted). Every operation is vectorised over the
joints. Tracking states: a joint with no measurement (not tracked, or a non-finite position)
restarts its filter and is returned as is, like :class:`~fpg_gym.filters.holt.HoltFilter`.
A frame with ``dt <= 0`` (a repeated timestamp) returns the previous output.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from fpg_gym.core.compiled import compiled_module
from fpg_gym.filters.base import DEFAULT_DT, FloatArray, PresetFilter, valid_joints


@dataclass(frozen=True)
class OneEuroParams:
    """Parameters of the One-Euro filter.

    Attributes
    ----------
    min_cutoff : float
        Hz > 0: cutoff at rest; lower is smoother at rest (and laggier on slow motion).
    beta : float
        s/m >= 0: how fast the cutoff rises with the joint's speed; higher lags less on fast
        motion.
    d_cutoff : float
        Hz > 0: cutoff of the speed estimate (1 Hz in the paper).
    """

    min_cutoff: float = 1.0
    beta: float = 1.0
    d_cutoff: float = 1.0

    def __post_init__(self) -> None:
        for name in ("min_cutoff", "d_cutoff"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name}: expected a finite value > 0 Hz, got {value!r}")
        if not (np.isfinite(self.beta) and self.beta >= 0.0):
            raise ValueError(f"beta: expected a finite value >= 0, got {self.beta!r}")


#: Named parameter sets. ``default`` is the paper's starting point; ``output`` is the stage the
#: reconstructor applies to its output (chosen on validation takes, see the README).
ONE_EURO_PRESETS: Final[dict[str, OneEuroParams]] = {
    "default": OneEuroParams(1.0, 1.0, 1.0),
    "output": OneEuroParams(1.5, 4.0, 1.0),
}


def alpha(cutoff: npt.ArrayLike, dt: float) -> np.ndarray:
    """Exponential smoothing factor of a first-order low-pass with ``cutoff`` Hz at interval
    ``dt`` s: ``1 / (1 + 1 / (2 pi cutoff dt))``."""
    tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff, dtype=np.float64))
    return np.asarray(1.0 / (1.0 + tau / dt))


class OneEuroFilter(PresetFilter):
    """The One-Euro filter per joint (see the module docstring).

    Parameters
    ----------
    preset : str
        A key of :data:`ONE_EURO_PRESETS` (``"default"``, ``"output"``).
    **overrides
        ``min_cutoff``, ``beta``, ``d_cutoff`` replacing the preset's.
    """

    settings: OneEuroParams

    def __init__(self, preset: str = "default", **overrides: float) -> None:
        key = preset.strip().lower()
        if key not in ONE_EURO_PRESETS:
            raise ValueError(
                f"preset: unknown One-Euro preset {preset!r}; expected one of "
                f"{sorted(ONE_EURO_PRESETS)}"
            )
        super().__init__(key, ONE_EURO_PRESETS[key], overrides)
        self._value = np.zeros((0, 3))
        self._speed = np.zeros((0, 3))
        self._started = np.zeros(0, dtype=bool)

    def _start(self, num_joints: int) -> None:
        self._value = np.zeros((num_joints, 3))
        self._speed = np.zeros((num_joints, 3))
        self._started = np.zeros(num_joints, dtype=bool)

    def _step(self, frame: FloatArray, states: npt.NDArray[np.int8], dt: float) -> FloatArray:
        p = self.settings
        if dt <= 0.0:
            started = self._started & valid_joints(frame, states)
            if started.any():  # a repeated timestamp: nothing new to filter
                return np.where(started[:, None], self._value, frame)
        step = dt if dt > 0.0 else DEFAULT_DT
        compiled = compiled_module("fpg_gym.filters.compiled_filters")
        if compiled is not None:  # the same step as below, joint by joint in one call
            out: FloatArray = compiled.one_euro_step(
                np.ascontiguousarray(frame, dtype=np.float64),
                states,
                step,
                float(p.d_cutoff),
                float(p.min_cutoff),
                float(p.beta),
                self._value,
                self._speed,
                self._started,
            )
            return out
        speed_alpha = alpha(p.d_cutoff, step)
        valid = valid_joints(frame, states)
        raw = np.where(valid[:, None], frame, 0.0)
        started = self._started & valid
        speed = speed_alpha * (raw - self._value) / step
        speed = speed + (1.0 - speed_alpha) * self._speed
        cutoff = p.min_cutoff + p.beta * np.linalg.norm(speed, axis=1)
        a = alpha(cutoff, step)[:, None]
        value = a * raw + (1.0 - a) * self._value
        value = np.where(started[:, None], value, raw)
        self._speed = np.where(started[:, None], speed, 0.0)
        self._value = value
        self._started = valid
        return np.where(valid[:, None], value, frame)


__all__ = ["ONE_EURO_PRESETS", "OneEuroFilter", "OneEuroParams", "alpha"]
