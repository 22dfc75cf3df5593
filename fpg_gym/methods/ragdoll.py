"""The ragdoll of the methods: injected into the reconstructor (:func:`ragdoll_factory`) or run
as a final filter on a filter's output (:class:`RagdollStage`)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.metrics import bones_tracked
from fpg_gym.core.poses import FloorShift, bone_lengths
from fpg_gym.physics.ragdoll import Ragdoll
from fpg_gym.reconstruct.config import RagdollFactory

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


class RagdollStage:
    """The ragdoll as a final filter on any stream of camera-space poses.

    Mirrors what :class:`~fpg_gym.reconstruct.Reconstructor` does with its ragdoll: camera space
    has no floor, so the poses are shifted down by a floor height estimated as the lowest joint
    seen so far (a running minimum); the body is reset on the first frame and tracks the
    following ones. The ragdoll gets the stream's bone lengths from
    :func:`reference_bone_lengths`; every stream starts from freshly built physics
    (:meth:`Ragdoll.rebuild`), so a stream's output does not depend on the ones before it.
    """

    def __init__(self) -> None:
        self._ragdoll: Any = None

    def run(
        self, poses: np.ndarray, lengths: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """Track ``poses`` ``(T, 20, 3)``; return the output poses, ms per frame and info."""

        lengths = np.asarray(lengths, dtype=np.float64)
        if self._ragdoll is None:
            self._ragdoll = Ragdoll(bone_lengths=lengths)
        else:
            self._ragdoll.rebuild(lengths)
        body = self._ragdoll
        poses = np.asarray(poses, dtype=np.float64)
        out = np.empty(poses.shape, dtype=np.float32)
        ms = np.empty(len(poses))
        floor = FloorShift()
        for t, target in enumerate(poses):
            t0 = time.perf_counter()
            world = floor.down(target)
            out[t] = floor.up(body.reset(world) if t == 0 else body.track(world))
            ms[t] = 1000.0 * (time.perf_counter() - t0)
        # Freshly rebuilt for this stream, so its counter holds this stream's divergences.
        info = {"ragdoll_divergences": int(body.info["divergences"])}
        return out, ms, info

    def close(self) -> None:
        """Release the pybullet client."""
        if self._ragdoll is not None:
            self._ragdoll.close()
            self._ragdoll = None
