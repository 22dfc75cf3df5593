"""What :meth:`~fpg_gym.env.KinectPoseEnv.step` takes and gives beside arrays: an action used
exactly as given, and the step's stage times."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

__all__ = ["ExactAction", "StageTimes"]


class ExactAction(np.ndarray):
    """An action that :meth:`KinectPoseEnv.step` uses as given, never clipped.

    :meth:`KinectPoseEnv.action_for` with ``exact=True`` returns one: it selects exactly the
    latent point an optimiser found, even when that point lies outside the action box, whatever
    the env's ``clip_actions`` (which it does not change). It is a float64 ``ndarray`` view with the
    same values as the plain action, so wrappers that pass actions through (``gym.make``'s
    checkers) keep it; a wrapper that transforms the action returns a plain array, which the env
    clips as usual.
    """

    def __new__(cls, values: Any) -> ExactAction:
        return np.asarray(values, dtype=np.float64).view(cls)


class StageTimes(Mapping[str, float]):
    """Milliseconds per stage of one step: read it like a dict (``info["timings"]["ragdoll"]``).

    Wall-clock times are measurements, not part of the environment's deterministic output, so two
    ``StageTimes`` compare equal when they time the same stages, whatever the values (Gymnasium's
    ``check_env`` compares the infos of two seeded runs). Compare ``dict(a) == dict(b)`` for the
    values.
    """

    def __init__(self, milliseconds: Mapping[str, float]) -> None:
        self._ms = {str(k): float(v) for k, v in milliseconds.items()}

    def __getitem__(self, key: str) -> float:
        return self._ms[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._ms)

    def __len__(self) -> int:
        return len(self._ms)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, StageTimes):
            return self._ms.keys() == other._ms.keys()
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        inner = ", ".join(f"{k}={v:.3f}" for k, v in self._ms.items())
        return f"StageTimes({inner})"
