"""What :meth:`fpg_gym.physics.ragdoll.Ragdoll.render` draws, in a pybullet client of its own."""

from __future__ import annotations

import math

import numpy as np

from fpg_gym.core import poses, skeleton
from fpg_gym.physics.pybullet_utils import connect_direct, pybullet
from fpg_gym.physics.ragdoll_model import BodyModel

__all__ = ["Scene", "bone_colours", "front_left_view"]


class Scene:
    """What :meth:`Ragdoll.render` draws: the capsules and the floor tile, without physics, in
    a pybullet client of their own (the ragdoll's physics client has no renderer)."""

    def __init__(self, model: BodyModel, floor_height: float | None) -> None:
        self.model = model
        self.client = connect_direct()
        pb, cid = pybullet, self.client
        if floor_height is not None:
            tile = pb.createVisualShape(
                pb.GEOM_BOX,
                halfExtents=[5.0, 0.005, 5.0],
                visualFramePosition=[0.0, -0.005, 0.0],
                rgbaColor=[0.78, 0.78, 0.74, 1.0],
                physicsClientId=cid,
            )
            pb.createMultiBody(
                baseMass=0.0,
                baseVisualShapeIndex=tile,
                basePosition=[0.0, floor_height, 0.0],
                physicsClientId=cid,
            )
        self.bodies = []
        for bone, colour in enumerate(bone_colours()):
            visual = pb.createVisualShape(
                pb.GEOM_CAPSULE,
                radius=float(model.radii[bone]),
                length=float(model.bone_lengths[bone]),
                rgbaColor=colour,
                physicsClientId=cid,
            )
            self.bodies.append(
                pb.createMultiBody(baseMass=0.0, baseVisualShapeIndex=visual, physicsClientId=cid)
            )

    def picture(
        self,
        centres: np.ndarray,
        orientations: np.ndarray,
        eye: np.ndarray,
        target: np.ndarray,
        width: int,
        height: int,
    ) -> np.ndarray:
        """The capsules placed at ``centres``/``orientations`` seen from ``eye``, RGB uint8."""
        pb, cid = pybullet, self.client
        for body, centre, orientation in zip(
            self.bodies, centres.tolist(), orientations.tolist(), strict=True
        ):
            pb.resetBasePositionAndOrientation(body, centre, orientation, physicsClientId=cid)
        view = pb.computeViewMatrix(
            eye.tolist(), target.tolist(), [0.0, 1.0, 0.0], physicsClientId=cid
        )
        projection = pb.computeProjectionMatrixFOV(
            fov=50.0, aspect=width / height, nearVal=0.05, farVal=30.0, physicsClientId=cid
        )
        _, _, rgba, _, _ = pb.getCameraImage(
            width,
            height,
            view,
            projection,
            renderer=pb.ER_TINY_RENDERER,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=cid,
        )
        image = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        return image[..., :3].copy()

    def close(self) -> None:
        try:
            pybullet.disconnect(physicsClientId=self.client)
        except pybullet.error:
            pass


def bone_colours() -> list[list[float]]:
    """Left side blue, right side red, centre line grey (for :meth:`Ragdoll.render`)."""
    colours = []
    for _, child in skeleton.BONES:
        if skeleton.is_left(int(child)):
            colours.append([0.25, 0.45, 0.85, 1.0])
        elif skeleton.is_right(int(child)):
            colours.append([0.85, 0.3, 0.25, 1.0])
        else:
            colours.append([0.55, 0.55, 0.6, 1.0])
    return colours


def front_left_view(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's eye and the point it looks at (the centre of the pose's bounding box) to see
    ``pose`` ``(20, 3)`` from its front left."""
    centre = 0.5 * (pose.min(axis=0) + pose.max(axis=0))
    yaw = float(poses.facing_yaw(pose))
    forward = np.array([math.sin(yaw), 0.0, math.cos(yaw)])
    side = np.array([math.cos(yaw), 0.0, -math.sin(yaw)])
    eye = centre + 2.6 * forward + 1.3 * side + np.array([0.0, 0.5, 0.0])
    return eye, centre
