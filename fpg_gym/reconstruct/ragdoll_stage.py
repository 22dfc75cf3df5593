"""The reconstructor's ragdoll stage: the injected ragdoll tracking the camera-space output.

The ragdoll runs in camera space shifted down by the floor height (the lowest joint of the
targets so far: camera space has no floor) and is rebuilt when the user's reference bone lengths
move by more than ``rebuild_m`` (see :mod:`fpg_gym.reconstruct.reconstructor`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fpg_gym.core.poses import FloorShift
from fpg_gym.reconstruct.config import RagdollFactory, RagdollLike

__all__ = ["RagdollStage"]


class RagdollStage:
    """A ragdoll made by ``factory`` (``lengths -> ragdoll``) for a stream of targets.

    Parameters
    ----------
    factory : callable or None
        The injected factory; None: no ragdoll (:meth:`track` is then not called).
    rebuild_m : float
        Bone-length change (m) that rebuilds the ragdoll.
    """

    def __init__(self, factory: RagdollFactory | None, rebuild_m: float) -> None:
        self.factory = factory
        self.rebuild_m = rebuild_m
        self.body: RagdollLike | None = None
        self.lengths: np.ndarray | None = None
        self.rebuilds = 0
        self.divergences = 0  # the body's count after the last frame
        self.restart()

    def restart(self) -> None:
        """A new stream: a new floor, and the physics rebuilt at the first tracked frame."""
        self.floor = FloorShift()
        self.needs_reset = True
        self.settle = False
        self.lengths = None

    def close(self) -> None:
        """Release the ragdoll, if any."""
        if self.body is not None:
            self.body.close()
            self.body = None

    def __getstate__(self) -> dict[str, Any]:
        """Pickle support: the ragdoll (a pybullet client) is left out and rebuilt on use."""
        state = self.__dict__.copy()
        state["body"] = None
        state["needs_reset"] = True
        return state

    def track(self, target: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """Send a camera-space target through the ragdoll (floor shifted to y = 0)."""
        assert self.factory is not None
        new_stream = self.lengths is None
        settle, self.settle = self.settle, False
        if (
            self.body is None
            or new_stream
            or np.max(np.abs(self.lengths - lengths)) > self.rebuild_m
            or (settle and np.max(np.abs(self.lengths - lengths)) > 1e-3)
        ):
            lengths64 = np.asarray(lengths, dtype=np.float64)
            rebuild = getattr(self.body, "rebuild", None)
            if self.body is not None and callable(rebuild):
                rebuild(lengths64)  # same client, fresh physics: cheaper than a new ragdoll
            else:
                if self.body is not None:
                    self.body.close()
                self.body = self.factory(lengths64)
            if not new_stream:
                self.rebuilds += 1
            self.lengths = lengths64.copy()
            self.needs_reset = True
        if self.needs_reset:  # a new or rebuilt body: its count may have restarted
            self.divergences = int((getattr(self.body, "info", {}) or {}).get("divergences", 0))
        before = self.divergences
        world = self.floor.down(target)
        if self.needs_reset:
            out = self.body.reset(world)
            self.needs_reset = False
        else:
            out = self.body.track(world)
        info = dict(getattr(self.body, "info", {}) or {})
        info["rebuilds"] = self.rebuilds
        info["floor_y"] = self.floor.floor_y
        # The ragdoll's counter is cumulative and restarts with a rebuild: report this frame's.
        self.divergences = int(info.get("divergences", 0))
        info["new_divergences"] = self.divergences - before
        return self.floor.up(out), info
