"""The :class:`Clip`: a mocap sequence of Kinect-20 joint positions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fpg_gym.core.poses import as_poses


@dataclass(frozen=True)
class Clip:
    """A clean motion-capture clip on the Kinect-20 skeleton.

    Attributes
    ----------
    name : str
        Short identifier, unique within a database (usually the file stem).
    positions : ndarray, shape (T, 20, 3), float32
        Joint positions in metres, Y up, right-handed, in the capture's world space.
    fps : float
        Frames per second of ``positions``.
    source : str
        Where the clip came from (a path, or ``"pybullet_data:..."`` for the embedded default).
    """

    name: str
    positions: np.ndarray
    fps: float
    source: str = ""
    metadata: dict[str, object] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        positions = as_poses(self.positions, f"clip {self.name!r} positions", ndim=3)
        if len(positions) == 0:
            raise ValueError(f"clip {self.name!r} has no frames")
        if not self.fps > 0:
            raise ValueError(f"clip {self.name!r}: fps must be positive, got {self.fps}")
        object.__setattr__(self, "positions", positions)

    @property
    def num_frames(self) -> int:
        """Number of frames T."""
        return int(self.positions.shape[0])

    @property
    def duration(self) -> float:
        """Duration in seconds, ``(T - 1) / fps``."""
        return (self.num_frames - 1) / self.fps

    def __repr__(self) -> str:
        return f"Clip(name={self.name!r}, frames={self.num_frames}, fps={self.fps:g})"
