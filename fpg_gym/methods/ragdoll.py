"""The ragdoll of the methods: injected into the reconstructor (:func:`ragdoll_factory`) or run
as a final filter on a filter's output (:class:`RagdollStage`)."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.metrics import bones_tracked
from fpg_gym.core.poses import bone_lengths
from fpg_gym.physics.ragdoll import Ragdoll
from fpg_gym.reconstruct.config import RagdollFactory
from fpg_gym.reconstruct.ragdoll_stage import RagdollStage as ReconstructorRagdollStage

__all__ = ["RagdollStage", "ragdoll_factory", "reference_bone_lengths"]


def ragdoll_factory(ragdoll: bool | RagdollFactory | None) -> RagdollFactory | None:
    """The reconstructor's ``ragdoll=`` from a flag: ``True`` is the pybullet
    :class:`~fpg_gym.physics.ragdoll.Ragdoll` (built from the user's bone lengths), False/None
    no ragdoll, a factory itself (:class:`~fpg_gym.reconstruct.Reconstructor` imports no
    physics: the ragdoll is injected from here).

    Examples
    --------
    >>> Reconstructor(graph, ragdoll=ragdoll_factory(True))               # doctest: +SKIP
    """
    if ragdoll is True:
        return Ragdoll
    return ragdoll if callable(ragdoll) else None


def reference_bone_lengths(positions: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Median length of each bone over the frames where both its joints are tracked, ``(19,)``.

    Bones never tracked at both ends take the median over all frames. This is the calibration
    of :class:`RagdollStage` for the filters; it looks at the whole stream (an offline
    calibration), where the reconstructor estimates the lengths online.
    """
    lengths = bone_lengths(positions)  # (T, 19)
    both = bones_tracked(np.asarray(states) >= skeleton.TRACKED)
    masked = np.where(both, lengths, np.nan)
    seen = both.any(axis=0)
    result = np.median(lengths, axis=0)
    if seen.any():
        result[seen] = np.nanmedian(masked[:, seen], axis=0)
    return np.maximum(result, 0.01)


class RagdollStage(ReconstructorRagdollStage):
    """The reconstructor's ragdoll stage as a final filter on any stream of camera-space poses.

    :class:`fpg_gym.reconstruct.ragdoll_stage.RagdollStage` with the pybullet
    :class:`~fpg_gym.physics.ragdoll.Ragdoll` and the whole stream's bone lengths (from
    :func:`reference_bone_lengths`): the poses are shifted down by the lowest joint seen so far
    (camera space has no floor), the body is rebuilt for each stream (:meth:`Ragdoll.rebuild`,
    so a stream's output does not depend on the ones before it), reset on the first frame and
    tracks the following ones.
    """

    def __init__(self) -> None:
        super().__init__(Ragdoll, rebuild_m=math.inf)

    def run(
        self, poses: np.ndarray, lengths: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """Track ``poses`` ``(T, 20, 3)``; return the output poses, ms per frame and info."""
        lengths = np.asarray(lengths, dtype=np.float64)
        poses = np.asarray(poses, dtype=np.float64)
        out = np.empty(poses.shape, dtype=np.float32)
        ms = np.empty(len(poses))
        divergences = 0
        self.restart()
        for t, target in enumerate(poses):
            t0 = time.perf_counter()
            out[t], info = self.track(target, lengths)
            ms[t] = 1000.0 * (time.perf_counter() - t0)
            divergences += info["new_divergences"]
        return out, ms, {"ragdoll_divergences": divergences}
