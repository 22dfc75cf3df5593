"""Occluders, the body's collision shapes and the ray caster (pybullet ``rayTestBatch``).

The stage is the body frame of a placed clip: Y up, origin on the floor under the body's mean
root position, the body facing +Z on average (its left side at +X). Occluders are boxes given in
that frame; a *carried* box follows the midpoint of the two hands and turns with the body.

Visibility of a joint is what a depth camera can see of the body surface around it: rays go from
the camera to points on a small disc in front of the joint (pulled towards the camera by the
body part's radius, spread across the view direction), and the joint's visible fraction is the
share of rays that reach their point. A ray is blocked by any scene box, and by any body shape
that does not belong to the joint itself (a hand is hidden by the torso, not by its own
forearm). The body is made of simple shapes sized from the clip's bone lengths: one capsule per
limb bone, a sphere for the head, a box for the torso. All shapes are static collision objects
in a pybullet DIRECT client of the caster's own, moved with ``resetBasePositionAndOrientation``;
one ``rayTestBatch`` per frame casts the rays that bounds do not settle
(:func:`fpg_gym.simulate.ray_bounds.rays_to_cast`: pybullet's answer without asking it), and
frames without such a ray cast nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import repeat
from typing import Any

import numpy as np
import numpy.typing as npt

from fpg_gym.core import poses, skeleton
from fpg_gym.core.rotations import matrix_to_quaternion_xyzw, shortest_arc
from fpg_gym.physics.pybullet_utils import hand_back, pybullet, reuse_direct
from fpg_gym.simulate.ray_bounds import rays_to_cast

__all__ = ["Box", "RayCaster", "TraceResult", "body_shape_poses", "box_poses"]

_J = skeleton.joint_index

#: Capsule radius (metres) of each limb bone, keyed by the bone's child joint. The spine, hip and
#: shoulder bones are covered by the torso box instead.
LIMB_RADIUS: dict[str, float] = {
    "Head": 0.05,  # the neck, ShoulderCenter-Head
    "ElbowLeft": 0.05,
    "WristLeft": 0.04,
    "HandLeft": 0.04,
    "ElbowRight": 0.05,
    "WristRight": 0.04,
    "HandRight": 0.04,
    "KneeLeft": 0.075,
    "AnkleLeft": 0.055,
    "FootLeft": 0.045,
    "KneeRight": 0.075,
    "AnkleRight": 0.055,
    "FootRight": 0.045,
}
HEAD_RADIUS = 0.10
TORSO_HALF_DEPTH = 0.10
_TORSO_JOINTS = (
    "HipCenter",
    "Spine",
    "ShoulderCenter",
    "ShoulderLeft",
    "ShoulderRight",
    "HipLeft",
    "HipRight",
)

#: Limb bones with a capsule: indices into :data:`skeleton.BONES`.
LIMB_BONES: np.ndarray = np.array(
    [b for b, (_, c) in enumerate(skeleton.BONES) if skeleton.JOINT_NAMES[c] in LIMB_RADIUS]
)
NUM_BODY_SHAPES = len(LIMB_BONES) + 2  # + head sphere + torso box
_HEAD_SHAPE = len(LIMB_BONES)
_TORSO_SHAPE = len(LIMB_BONES) + 1
#: A pybullet capsule lies along its local +Z.
_CAPSULE_AXIS = np.array([0.0, 0.0, 1.0])

#: How far (metres) each joint's ray targets are pulled towards the camera: the radius of the
#: body part around the joint, so that rays aim at the visible surface, not the joint centre.
SURFACE_OFFSET: np.ndarray = np.array(
    [
        HEAD_RADIUS if name == "Head" else TORSO_HALF_DEPTH if name in _TORSO_JOINTS else 0.05
        for name in skeleton.JOINT_NAMES
    ]
)


def _own_shapes() -> np.ndarray:
    """(20, NUM_BODY_SHAPES) bool: the body shapes that belong to each joint."""
    own = np.zeros((skeleton.NUM_JOINTS, NUM_BODY_SHAPES), dtype=bool)
    for shape, bone in enumerate(LIMB_BONES):
        parent, child = skeleton.BONES[bone]
        own[parent, shape] = own[child, shape] = True
    own[_J("Head"), _HEAD_SHAPE] = True
    for name in _TORSO_JOINTS:
        own[_J(name), _TORSO_SHAPE] = True
    return own


OWN_SHAPES = _own_shapes()

#: Builds that remove the body's shapes before one resets the whole scene.
_REMOVALS_PER_RESET = 64


@dataclass(frozen=True)
class Box:
    """A box occluder in the stage (body frame: Y up, body facing +Z, its left at +X).

    Attributes
    ----------
    name : str
        What it stands for (``"workbench"``, ``"shelf"``, ``"panel"``, ``"seat"``...).
    size : tuple of 3 floats
        Full extents along the box's own X (width), Y (height), Z (depth), metres.
    center : tuple of 3 floats
        Centre in the stage, metres; for a carried box, the offset from the carrying point in
        the body's heading frame (X to the body's left, Y up, Z forward).
    yaw_deg : float
        Rotation about +Y, degrees (for a carried box, relative to the body's heading).
    carried_by : str
        ``""`` for a static box; ``"hands"`` for a box that follows the midpoint of the two
        hands, or a joint name (e.g. ``"HandRight"``) for a box held by that joint.
    """

    name: str
    size: tuple[float, float, float]
    center: tuple[float, float, float]
    yaw_deg: float = 0.0
    carried_by: str = ""

    def __post_init__(self) -> None:
        size = np.asarray(self.size, dtype=np.float64)
        center = np.asarray(self.center, dtype=np.float64)
        if size.shape != (3,) or not np.all(size > 0) or not np.all(np.isfinite(size)):
            raise ValueError(f"box {self.name!r}: size must be 3 positive numbers, got {self.size}")
        if center.shape != (3,) or not np.all(np.isfinite(center)):
            raise ValueError(f"box {self.name!r}: center must be 3 finite numbers")
        if self.carried_by not in ("", "hands"):
            skeleton.joint_index(self.carried_by)  # raises KeyError naming the valid joints

    @property
    def carried(self) -> bool:
        """Whether the box moves with the body."""
        return bool(self.carried_by)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly description."""
        return {
            "name": self.name,
            "size_m": list(self.size),
            "center_m": list(self.center),
            "yaw_deg": self.yaw_deg,
            "carried_by": self.carried_by,
        }


# --------------------------------------------------------------------------- poses of shapes


def _yaw_quaternion(yaw: np.ndarray) -> np.ndarray:
    half = np.asarray(yaw, dtype=np.float64) / 2
    zero = np.zeros_like(half)
    return np.stack([zero, np.sin(half), zero, np.cos(half)], axis=-1)


def torso_size(joints: np.ndarray) -> tuple[float, float, float]:
    """Full extents (width, height, depth) of the torso box from a clip ``(T, 20, 3)``."""
    shoulders = np.linalg.norm(
        joints[:, _J("ShoulderLeft")] - joints[:, _J("ShoulderRight")], axis=-1
    )
    height = np.linalg.norm(joints[:, _J("ShoulderCenter")] - joints[:, _J("HipCenter")], axis=-1)
    width = float(np.clip(np.median(shoulders) * 0.85, 0.22, 0.42))
    return width, float(np.median(height)), 2 * TORSO_HALF_DEPTH


def body_shape_poses(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(T, S, 3)`` and quaternions ``(T, S, 4)`` of the body shapes, all frames.

    Shape order: the limb capsules (:data:`LIMB_BONES`), the head sphere, the torso box.
    """
    joints = np.asarray(joints, dtype=np.float64)
    count = len(joints)
    vectors = poses.bone_vectors(joints)[:, LIMB_BONES]
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    directions = np.where(norms > 1e-9, vectors / np.maximum(norms, 1e-9), (0.0, 1.0, 0.0))
    positions = np.empty((count, NUM_BODY_SHAPES, 3))
    quaternions = np.empty((count, NUM_BODY_SHAPES, 4))
    ends = joints[:, skeleton.BONES[LIMB_BONES]]  # (T, L, 2, 3): parent and child joints
    positions[:, : len(LIMB_BONES)] = ends.mean(axis=2)
    quaternions[:, : len(LIMB_BONES)] = shortest_arc(_CAPSULE_AXIS, directions)
    positions[:, _HEAD_SHAPE] = joints[:, _J("Head")]
    quaternions[:, _HEAD_SHAPE] = (0.0, 0.0, 0.0, 1.0)
    # Torso box: Y along hips -> shoulders, X towards the body's left, Z forward.
    bottom, top = joints[:, _J("HipCenter")], joints[:, _J("ShoulderCenter")]
    up = top - bottom
    up /= np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-9)
    left = (joints[:, _J("ShoulderLeft")] - joints[:, _J("ShoulderRight")]) + (
        joints[:, _J("HipLeft")] - joints[:, _J("HipRight")]
    )
    left -= np.sum(left * up, axis=-1, keepdims=True) * up
    small = np.linalg.norm(left, axis=-1) < 1e-6
    left[small] = np.cross(up[small], (0.0, 0.0, 1.0)) + 1e-6
    left /= np.linalg.norm(left, axis=-1, keepdims=True)
    forward = np.cross(left, up)
    positions[:, _TORSO_SHAPE] = (bottom + top) / 2
    quaternions[:, _TORSO_SHAPE] = matrix_to_quaternion_xyzw(np.stack([left, up, forward], axis=-1))
    return positions, quaternions


def box_poses(
    boxes: Sequence[Box], joints: np.ndarray, heading: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(T, B, 3)`` and quaternions ``(T, B, 4)`` of the scene boxes, all frames.

    ``heading`` ``(T,)`` is the body's facing yaw in the stage (radians), used by carried boxes.
    """
    count = len(joints)
    positions = np.empty((count, len(boxes), 3))
    quaternions = np.empty((count, len(boxes), 4))
    turn = poses.yaw_matrix(heading)  # heading frame -> stage (rotation about +Y)
    for index, box in enumerate(boxes):  # a handful of boxes; vectorised over frames
        offset = np.asarray(box.center, dtype=np.float64)
        if box.carried:
            if box.carried_by == "hands":
                anchor = (joints[:, _J("HandLeft")] + joints[:, _J("HandRight")]) / 2
            else:
                anchor = joints[:, _J(box.carried_by)]
            positions[:, index] = anchor + turn @ offset
            quaternions[:, index] = _yaw_quaternion(heading + np.radians(box.yaw_deg))
        else:
            positions[:, index] = offset
            quaternions[:, index] = _yaw_quaternion(np.full(count, np.radians(box.yaw_deg)))
    return positions, quaternions


# --------------------------------------------------------------------------- ray casting


@dataclass(frozen=True)
class TraceResult:
    """Per-frame, per-joint visibility from the camera.

    Attributes
    ----------
    visible : ndarray, shape (T, 20), float64
        Share of the joint's rays that reach the body surface around it, in [0, 1].
    blocker : ndarray, shape (T, 20), int
        What stops the joint's central ray: -1 nothing, -2 another body part, k >= 0 scene
        box k.
    hit_point : ndarray, shape (T, 20, 3), float64
        Where the central ray stops, stage coordinates (the target itself when nothing but the
        joint's own body part is in its way).
    """

    visible: np.ndarray
    blocker: np.ndarray
    hit_point: np.ndarray


class RayCaster:
    """Body shapes and scene boxes in a pybullet DIRECT client of its own.

    Parameters
    ----------
    rays_per_joint : int
        1 (central ray only) or 5 (centre and four points around it).
    spread : float
        Radius in metres of the disc of ray targets around each joint.
    """

    def __init__(self, rays_per_joint: int = 5, spread: float = 0.04) -> None:
        if rays_per_joint not in (1, 5):
            raise ValueError(f"rays_per_joint: expected 1 or 5, got {rays_per_joint}")
        self.rays_per_joint = rays_per_joint
        self.spread = float(spread)
        self._client: int | None = reuse_direct("rays")  # the first build resets its world
        self._uids: list[int] = []
        self._shape_of_uid = np.zeros(0, dtype=np.intp)
        self._radius = self._half_height = np.zeros(0)
        self._box_half = np.zeros((0, 3))
        self._boxes: tuple[Box, ...] = ()
        self._removals = 0

    # -- lifecycle
    def close(self) -> None:
        """Release the pybullet client (idempotent): emptied and kept for the next caster
        (:func:`fpg_gym.physics.pybullet_utils.hand_back`)."""
        if self._client is not None:
            client, self._client = self._client, None
            hand_back("rays", client)

    def __enter__(self) -> RayCaster:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - best effort
        try:
            self.close()
        except Exception:
            pass

    @property
    def client(self) -> int:
        if self._client is None:
            raise RuntimeError("RayCaster is closed")
        return self._client

    # -- scene
    def _reset_scene(self) -> None:
        pybullet.resetSimulation(physicsClientId=self.client)
        self._uids = []

    def _add(self, shape: int) -> None:
        uid = pybullet.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=shape,
            basePosition=[0.0, -100.0, 0.0],
            physicsClientId=self.client,
        )
        self._uids.append(int(uid))

    def build(self, joints: np.ndarray, boxes: Sequence[Box]) -> None:
        """Create the body shapes (sized from ``joints`` ``(T, 20, 3)``) and the boxes.

        The boxes of the last build stay when they are the same (a simulator builds its
        scenario's boxes once): only the body's shapes are removed and made again, and every
        :data:`_REMOVALS_PER_RESET` builds the whole scene is reset instead (pybullet keeps the
        collision shapes of removed bodies).
        """
        boxes = tuple(boxes)
        kept: list[int] = []
        if (
            boxes == self._boxes
            and len(self._uids) == NUM_BODY_SHAPES + len(boxes)
            and self._removals < _REMOVALS_PER_RESET
        ):
            for uid in self._uids[:NUM_BODY_SHAPES]:
                pybullet.removeBody(uid, physicsClientId=self.client)
            kept = self._uids[NUM_BODY_SHAPES:]
            self._uids = []
            self._removals += 1
        else:
            self._reset_scene()
            self._removals = 0
        self._boxes = boxes
        lengths = np.median(poses.bone_lengths(joints)[:, LIMB_BONES], axis=0)
        client = self.client
        radii, heights = [], []
        for bone, length in zip(LIMB_BONES, lengths, strict=True):
            radius = LIMB_RADIUS[skeleton.JOINT_NAMES[skeleton.BONES[bone, 1]]]
            height = max(float(length), 1e-3)
            shape = pybullet.createCollisionShape(
                pybullet.GEOM_CAPSULE, radius=radius, height=height, physicsClientId=client
            )
            self._add(shape)
            radii.append(radius)
            heights.append(height)
        self._add(
            pybullet.createCollisionShape(
                pybullet.GEOM_SPHERE, radius=HEAD_RADIUS, physicsClientId=client
            )
        )
        half = np.asarray(torso_size(joints)) / 2
        self._add(
            pybullet.createCollisionShape(
                pybullet.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=client
            )
        )
        for box in boxes if not kept else ():
            self._add(
                pybullet.createCollisionShape(
                    pybullet.GEOM_BOX,
                    halfExtents=(np.asarray(box.size) / 2).tolist(),
                    physicsClientId=client,
                )
            )
        self._uids.extend(kept)
        # The shapes as rays_to_cast takes them: capsules (the head a sphere), then boxes.
        self._radius = np.array([*radii, HEAD_RADIUS])
        self._half_height = np.array([*heights, 0.0]) / 2
        self._box_half = np.array([half, *(np.asarray(box.size) / 2 for box in boxes)])
        lookup = np.full(max(self._uids) + 1, -1, dtype=np.intp)
        lookup[self._uids] = np.arange(len(self._uids))
        self._shape_of_uid = lookup

    def trace(
        self,
        camera_position: npt.ArrayLike,
        joints: np.ndarray,
        boxes: Sequence[Box],
        heading: np.ndarray,
        *,
        bounds: bool = True,
    ) -> TraceResult:
        """Cast every joint's rays in every frame (one ``rayTestBatch`` per frame, with the rays
        that :func:`~fpg_gym.simulate.ray_bounds.rays_to_cast` leaves).

        Parameters
        ----------
        camera_position : array_like, shape (3,)
            Optical centre in the stage.
        joints : ndarray, shape (T, 20, 3)
            True joint positions in the stage.
        boxes : sequence of Box
            The scene boxes, as given to :meth:`build`.
        heading : ndarray, shape (T,)
            The body's facing yaw per frame (for carried boxes).
        bounds : bool
            False: pybullet casts every ray (the same result, slower; what the bounds are
            tested against).
        """
        joints = np.asarray(joints, dtype=np.float64)
        count = len(joints)
        if len(self._uids) != NUM_BODY_SHAPES + len(boxes):
            raise RuntimeError("RayCaster.trace: call build() with the same boxes first")
        camera = np.asarray(camera_position, dtype=np.float64)
        body_pos, body_quat = body_shape_poses(joints)
        box_pos, box_quat = box_poses(boxes, joints, heading)
        shape_pos = np.concatenate([body_pos, box_pos], axis=1)
        shape_quat = np.concatenate([body_quat, box_quat], axis=1)
        moving = list(range(NUM_BODY_SHAPES)) + [
            NUM_BODY_SHAPES + i for i, box in enumerate(boxes) if box.carried
        ]
        self._place_static_boxes(boxes, shape_pos[0], shape_quat[0])
        targets = self._targets(camera, joints)  # (T, 20, K, 3)
        rays = skeleton.NUM_JOINTS * self.rays_per_joint
        flat_targets = targets.reshape(count, rays, 3)
        own_shapes = np.zeros((rays, len(self._uids)), dtype=bool)
        own_shapes[:, :NUM_BODY_SHAPES] = np.repeat(OWN_SHAPES, self.rays_per_joint, axis=0)
        cast, shape = rays_to_cast(
            camera,
            flat_targets,
            shape_pos,
            shape_quat,
            self._radius,
            self._half_height,
            self._box_half,
            own_shapes,
            np.arange(rays) % self.rays_per_joint == 0,
        )
        if not bounds:
            cast, shape = np.ones_like(cast), np.full_like(shape, -1)
        hit_points = flat_targets.copy()
        uids, stops = self._cast(camera, flat_targets, cast, shape_pos, shape_quat, moving)
        shape[cast] = np.where(uids >= 0, self._shape_of_uid[np.maximum(uids, 0)], -1)
        hit_points[cast] = stops
        shape = shape.reshape(count, skeleton.NUM_JOINTS, self.rays_per_joint)
        central = hit_points.reshape(count, skeleton.NUM_JOINTS, self.rays_per_joint, 3)[:, :, 0]
        return _trace_result(shape, central, targets[:, :, 0])

    def _place_static_boxes(
        self, boxes: Sequence[Box], shape_pos: np.ndarray, shape_quat: np.ndarray
    ) -> None:
        """Put the boxes that stay where they are (not carried) at their place, once."""
        for i, box in enumerate(boxes):
            if not box.carried:
                pybullet.resetBasePositionAndOrientation(
                    self._uids[NUM_BODY_SHAPES + i],
                    shape_pos[NUM_BODY_SHAPES + i].tolist(),
                    shape_quat[NUM_BODY_SHAPES + i].tolist(),
                    physicsClientId=self.client,
                )

    def _cast(
        self,
        camera: np.ndarray,
        flat_targets: np.ndarray,
        cast: np.ndarray,
        shape_pos: np.ndarray,
        shape_quat: np.ndarray,
        moving: list[int],
    ) -> tuple[np.ndarray, np.ndarray]:
        """pybullet's ray casts of the rays ``cast`` (T, rays), frame by frame with the moving
        shapes placed: the body uid each hit (-1: none) and where each ray stopped."""
        per_frame = cast.sum(axis=1)
        ends = flat_targets[cast]  # the cast rays, frame by frame
        uids = np.empty(len(ends), dtype=np.intp)
        stops = ends.copy()
        start, first = camera.tolist(), 0
        client, reset = self.client, pybullet.resetBasePositionAndOrientation
        moving_uids = [self._uids[k] for k in moving]
        moving_pos, moving_quat = shape_pos[:, moving], shape_quat[:, moving]
        counts = per_frame.tolist()
        # Python objects live one frame at a time: a clip's worth at once sets off the garbage
        # collector, whose full passes cost as much as the rest in a process holding many.
        for t in np.flatnonzero(per_frame).tolist():
            # The moving shapes placed by map (no Python frame per call), positionally.
            for _ in map(
                reset, moving_uids, moving_pos[t].tolist(), moving_quat[t].tolist(), repeat(client)
            ):
                pass
            last = first + counts[t]
            result = pybullet.rayTestBatch(
                [start] * (last - first), ends[first:last].tolist(), physicsClientId=client
            )
            uids[first:last] = [r[0] for r in result]
            stops[first:last] = [r[3] for r in result]
            first = last
        return uids, stops

    def _targets(self, camera: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Ray targets ``(T, 20, K, 3)``: the joint's front surface and a disc around it."""
        towards = camera - joints
        distance = np.linalg.norm(towards, axis=-1, keepdims=True)
        view = towards / np.maximum(distance, 1e-9)
        front = joints + view * np.minimum(SURFACE_OFFSET[None, :, None], 0.5 * distance)
        if self.rays_per_joint == 1:
            return front[:, :, None, :]
        side = np.cross(view, (0.0, 1.0, 0.0))
        side_norm = np.linalg.norm(side, axis=-1, keepdims=True)
        side = np.where(side_norm > 1e-6, side / np.maximum(side_norm, 1e-9), (1.0, 0.0, 0.0))
        up = np.cross(side, view)
        offsets = np.stack([np.zeros_like(side), side, -side, up, -up], axis=-2) * self.spread
        return front[:, :, None, :] + offsets


def _trace_result(shape: np.ndarray, central: np.ndarray, targets: np.ndarray) -> TraceResult:
    """What the rays found: ``shape`` (T, 20, K) the shape each ray hit (-1: none), ``central``
    (T, 20, 3) where each joint's central ray stopped, ``targets`` (T, 20, 3) the central rays'
    targets."""
    own = np.zeros(shape.shape, dtype=bool)
    is_body = (shape >= 0) & (shape < NUM_BODY_SHAPES)
    joint_index = np.arange(skeleton.NUM_JOINTS)[None, :, None]
    own[is_body] = OWN_SHAPES[np.broadcast_to(joint_index, shape.shape)[is_body], shape[is_body]]
    blocked = (shape >= 0) & ~own
    visible = 1.0 - blocked.mean(axis=-1)
    center = shape[..., 0]
    blocker = np.where(
        ~blocked[..., 0], -1, np.where(center >= NUM_BODY_SHAPES, center - NUM_BODY_SHAPES, -2)
    )
    hits = np.where(blocked[..., :1], central, targets)
    return TraceResult(visible=visible, blocker=blocker, hit_point=hits)
