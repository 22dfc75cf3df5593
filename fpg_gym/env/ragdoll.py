"""The env's ragdoll: a :class:`~fpg_gym.physics.ragdoll.Ragdoll` that counts its resets,
builds and (through the frame records) divergences for the step's ``info``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from fpg_gym.physics.ragdoll import Ragdoll

__all__ = ["CountingRagdollFactory", "RagdollProbe", "ragdoll_keywords"]


class RagdollProbe:
    """The env's ragdoll: a :class:`~fpg_gym.physics.ragdoll.Ragdoll` that counts resets and builds.

    A divergence already resets the body to its target and is counted in the step's info (from
    the frame record's ``new_divergences``), so the factory builds the ragdoll with
    ``on_divergence="quiet"`` (no :class:`~fpg_gym.physics.ragdoll.PhysicsWarning`) unless
    ``"raise"`` is asked for.
    """

    def __init__(self, ragdoll: Any, counts: dict[str, int]) -> None:
        self.ragdoll = ragdoll
        self.counts = counts

    def reset(self, pose: np.ndarray) -> np.ndarray:
        self.counts["ragdoll_resets"] += 1
        return np.asarray(self.ragdoll.reset(pose))

    def track(self, target_pose: np.ndarray) -> np.ndarray:
        return np.asarray(self.ragdoll.track(target_pose))

    @property
    def info(self) -> dict[str, Any]:
        return self.ragdoll.info  # a new dict at each call

    def rebuild(self, bone_lengths: np.ndarray) -> None:
        self.counts["ragdoll_builds"] += 1
        self.ragdoll.rebuild(bone_lengths, stand=False)  # the ragdoll stage resets it next

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        return np.asarray(self.ragdoll.render(width, height))

    def close(self) -> None:
        self.ragdoll.close()


class CountingRagdollFactory:
    """Builds the env's ragdolls (``lengths -> RagdollProbe``), counting the builds."""

    def __init__(self, kwargs: Mapping[str, Any], counts: dict[str, int]) -> None:
        self.kwargs = dict(kwargs)
        if self.kwargs.get("on_divergence", "reset") == "reset":  # counted, not warned
            self.kwargs["on_divergence"] = "quiet"
        self.counts = counts

    def __call__(self, lengths: np.ndarray) -> RagdollProbe:

        self.counts["ragdoll_builds"] += 1
        return RagdollProbe(Ragdoll(bone_lengths=lengths, **self.kwargs), self.counts)


def ragdoll_keywords(ragdoll: bool | Mapping[str, Any]) -> dict[str, Any] | None:
    """The env's ``ragdoll`` argument as :class:`~fpg_gym.physics.ragdoll.Ragdoll` keyword
    arguments: a mapping as given, True as none, False as None (no ragdoll)."""
    return dict(ragdoll) if isinstance(ragdoll, Mapping) else ({} if ragdoll else None)
