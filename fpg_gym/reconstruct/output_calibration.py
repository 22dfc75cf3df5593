"""The output's definitions fitted while a stream runs (``ReconstructorConfig.calibrate_output``):
where the database's body points sit against the sensor's on this user, learnt from the user's
own reliable frames, without paired data."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.definitions import joint_frames, symmetrise_offsets

__all__ = ["OnlineDefinitionFit"]


class OnlineDefinitionFit:
    """A definition map fitted while a stream runs, from the user's own reliable frames.

    Each frame adds the residual ``F_j(pose)^T (target_j - pose_j)`` of the joints in use (e.g.
    tracked joints) to a per-joint running mean; the pose is returned moved by the mean so
    far (``mapped(j) = p(j) + F_j(p) · o_j``, as :class:`DefinitionMap`). Causal: frame t uses
    frames 0..t only. With the reconstruction as ``pose`` and the sensor (or the sensor mapped
    to the wanted definitions) as ``target``, it learns where the database's body points sit
    against the sensor's on this user, without paired data; zero-mean tracking noise averages
    out, a definition difference does not.

    Parameters
    ----------
    symmetric : bool
        Average left and right offsets as mirror images (see :meth:`DefinitionMap.fit`).
    max_residual_m : float
        Residuals longer than this (a tracking failure, not a definition) are left out.
    """

    def __init__(self, *, symmetric: bool = True, max_residual_m: float = 0.25) -> None:
        if not max_residual_m > 0:
            raise ValueError(f"max_residual_m: expected > 0, got {max_residual_m}")
        self.symmetric = symmetric
        self.max_residual_m = float(max_residual_m)
        self.reset()

    def reset(self) -> None:
        """Forget every frame (a new user)."""
        self._sum = np.zeros((skeleton.NUM_JOINTS, 3))
        self._count = np.zeros(skeleton.NUM_JOINTS)

    @property
    def offsets(self) -> np.ndarray:
        """The current offsets ``(20, 3)`` in the joints' frames (0 where nothing was seen)."""
        offsets = self._sum / np.maximum(self._count, 1.0)[:, None]
        if self.symmetric:
            seen = self._count > 0
            left, right = skeleton.MIRROR_PAIRS[:, 0], skeleton.MIRROR_PAIRS[:, 1]
            both = seen[left] & seen[right]  # a side seen alone keeps its own mean
            symmetric = symmetrise_offsets(offsets)
            pairs = np.concatenate([left[both], right[both]])
            middle = np.setdiff1d(np.arange(skeleton.NUM_JOINTS), skeleton.MIRROR_PAIRS.ravel())
            offsets[pairs] = symmetric[pairs]
            offsets[middle] = symmetric[middle]
        return offsets

    @property
    def frames_seen(self) -> np.ndarray:
        """Frames that contributed to each joint's offset, ``(20,)``."""
        return self._count.astype(np.int64)

    def update(self, pose: npt.ArrayLike, target: npt.ArrayLike, use: npt.ArrayLike) -> np.ndarray:
        """Add one frame's evidence and return ``pose`` mapped with the offsets so far.

        Parameters
        ----------
        pose : array_like, shape (20, 3)
            The pose in the source definitions (e.g. the reconstruction).
        target : array_like, shape (20, 3)
            The same moment in the wanted definitions (e.g. the sensor), same space.
        use : array_like of bool, shape (20,)
            Joints whose target is trusted in this frame.
        """
        p = np.asarray(pose, dtype=np.float64)
        t = np.asarray(target, dtype=np.float64)
        mask = np.asarray(use, dtype=bool)
        if p.shape != (skeleton.NUM_JOINTS, 3) or t.shape != p.shape or mask.shape != (20,):
            raise ValueError(
                f"update: expected poses (20, 3) and a mask (20,), got {p.shape}, {t.shape}, "
                f"{mask.shape}"
            )
        frames = joint_frames(p)
        residual = np.einsum("jab,ja->jb", frames, t - p)
        mask = mask & np.all(np.isfinite(residual), axis=-1)
        mask &= np.linalg.norm(np.where(mask[:, None], residual, 0.0), axis=-1) <= (
            self.max_residual_m
        )
        self._sum[mask] += residual[mask]
        self._count[mask] += 1.0
        return p + np.einsum("jab,jb->ja", frames, self.offsets)
