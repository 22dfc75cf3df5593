"""The simulated Kinect: pose in the scene, camera space and field of view.

Camera space is the Kinect SDK's skeleton space: metres, origin at the sensor, Z along the
optical axis away from the sensor, Y up, X towards the sensor's left (right-handed). A user who
faces the sensor has the left shoulder at negative X. The scene ("stage") is any right-handed
Y-up frame; the camera's heading ``yaw`` is measured like :func:`fpg_gym.core.poses.facing_yaw`
(from +Z towards +X) and ``pitch`` is positive when looking up.

The default field of view and range are the Kinect for Windows v1 sensor's (57° x 43°, default
range 0.8-4 m, Kinect for Windows SDK v1 documentation, "Kinect for Windows Sensor Components
and Specifications").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

_UP = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class Camera:
    """A depth camera placed in the stage.

    Attributes
    ----------
    position : tuple of 3 floats
        Optical centre in stage coordinates, metres.
    yaw, pitch : float
        Heading (from +Z towards +X) and elevation of the optical axis, radians.
    h_fov_deg, v_fov_deg : float
        Full horizontal and vertical fields of view, degrees.
    near, far : float
        Depth range in metres (Z in camera space) in which the skeleton tracker works.
    """

    position: tuple[float, float, float]
    yaw: float
    pitch: float
    h_fov_deg: float = 57.0
    v_fov_deg: float = 43.0
    near: float = 0.8
    far: float = 4.0

    def __post_init__(self) -> None:
        position = tuple(float(v) for v in np.asarray(self.position, dtype=np.float64).reshape(-1))
        if len(position) != 3 or not all(np.isfinite(position)):
            raise ValueError(f"camera position: expected 3 finite numbers, got {self.position}")
        if not 0.0 < self.near < self.far:
            raise ValueError(f"camera range: expected 0 < near < far, got {self.near}, {self.far}")
        if not (0 < self.h_fov_deg < 180 and 0 < self.v_fov_deg < 180):
            raise ValueError("camera field of view: expected angles in (0, 180) degrees")
        if abs(self.pitch) >= np.pi / 2:
            raise ValueError(f"camera pitch: expected |pitch| < 90 degrees, got {self.pitch} rad")
        object.__setattr__(self, "position", position)

    @classmethod
    def look_at(cls, position: npt.ArrayLike, target: npt.ArrayLike, **kwargs: Any) -> Camera:
        """A camera at ``position`` whose optical axis passes through ``target``."""
        start = np.asarray(position, dtype=np.float64)
        direction = np.asarray(target, dtype=np.float64) - start
        horizontal = float(np.hypot(direction[0], direction[2]))
        if horizontal < 1e-9:
            raise ValueError("look_at: the target is straight above or below the camera")
        yaw = float(np.arctan2(direction[0], direction[2]))
        pitch = float(np.arctan2(direction[1], horizontal))
        return cls(position=tuple(start.tolist()), yaw=yaw, pitch=pitch, **kwargs)

    @property
    def rotation(self) -> np.ndarray:
        """``(3, 3)``: columns are the camera's X (sensor's left), Y (up), Z (optical axis)."""
        forward = np.array(
            [
                np.cos(self.pitch) * np.sin(self.yaw),
                np.sin(self.pitch),
                np.cos(self.pitch) * np.cos(self.yaw),
            ]
        )
        left = np.cross(_UP, forward)
        left /= np.linalg.norm(left)
        up = np.cross(forward, left)
        return np.stack([left, up, forward], axis=1)

    def world_to_camera(self, points: npt.ArrayLike) -> np.ndarray:
        """Stage coordinates ``(..., 3)`` -> camera space ``(..., 3)`` (float64)."""
        points = np.asarray(points, dtype=np.float64)
        return (points - np.asarray(self.position)) @ self.rotation

    def camera_to_world(self, points: npt.ArrayLike) -> np.ndarray:
        """Camera space ``(..., 3)`` -> stage coordinates ``(..., 3)`` (float64)."""
        points = np.asarray(points, dtype=np.float64)
        return points @ self.rotation.T + np.asarray(self.position)

    def in_view(self, points_camera: npt.ArrayLike) -> np.ndarray:
        """Whether camera-space points lie inside the field of view and the depth range."""
        p = np.asarray(points_camera, dtype=np.float64)
        z = p[..., 2]
        safe = np.where(z > 1e-9, z, 1.0)
        inside_x = np.abs(p[..., 0] / safe) <= np.tan(np.radians(self.h_fov_deg) / 2)
        inside_y = np.abs(p[..., 1] / safe) <= np.tan(np.radians(self.v_fov_deg) / 2)
        return np.asarray((z >= self.near) & (z <= self.far) & inside_x & inside_y)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly description (angles in degrees)."""
        return {
            "position_m": list(self.position),
            "yaw_deg": float(np.degrees(self.yaw)),
            "pitch_deg": float(np.degrees(self.pitch)),
            "h_fov_deg": self.h_fov_deg,
            "v_fov_deg": self.v_fov_deg,
            "near_m": self.near,
            "far_m": self.far,
        }
