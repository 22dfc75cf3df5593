"""The ragdoll's world in pybullet: the floor, the capsules, their drives and joints.

Construction (one-off, not a hot path), removal and placing of the body of
:class:`fpg_gym.physics.ragdoll.Ragdoll`.
"""

from __future__ import annotations

import numpy as np

from fpg_gym.core import poses
from fpg_gym.physics.pybullet_utils import pybullet
from fpg_gym.physics.ragdoll_kinematics import (
    NUM_BONES,
    PARENT_BONE,
    STARTS,
    quat_conj,
    quat_rotate,
)
from fpg_gym.physics.ragdoll_model import GRAVITY, BodyModel

__all__ = ["build_body", "build_world", "place_body", "remove_body"]

_JOINT_FORCE_BODY_WEIGHTS = 100.0
_BODY_GROUP, _FLOOR_GROUP = 1, 2


def build_world(
    client: int,
    *,
    time_step: float,
    erp: float,
    solver_iterations: int,
    solver_tolerance: float,
    floor_height: float | None,
    friction: float,
) -> int:
    """Reset the simulation to an empty world: the physics settings and the floor plane at
    ``floor_height`` (none for None). Returns the floor's body id, -1 without a floor."""
    pb, cid = pybullet, client
    pb.resetSimulation(physicsClientId=cid)
    pb.setGravity(0.0, -GRAVITY, 0.0, physicsClientId=cid)
    pb.setPhysicsEngineParameter(
        fixedTimeStep=time_step,
        numSubSteps=0,
        numSolverIterations=solver_iterations,
        solverResidualThreshold=solver_tolerance**2,  # of the rows' squared velocity changes
        erp=erp,
        deterministicOverlappingPairs=1,
        physicsClientId=cid,
    )
    floor = -1
    if floor_height is not None:
        plane = pb.createCollisionShape(
            pb.GEOM_PLANE, planeNormal=[0.0, 1.0, 0.0], physicsClientId=cid
        )
        floor = pb.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=plane,
            basePosition=[0.0, floor_height, 0.0],
            physicsClientId=cid,
        )
        pb.changeDynamics(floor, -1, lateralFriction=friction, restitution=0.0, physicsClientId=cid)
        pb.setCollisionFilterGroupMask(floor, -1, _FLOOR_GROUP, _BODY_GROUP, physicsClientId=cid)
    return floor


def build_body(
    client: int,
    model: BodyModel,
    rest_vectors: np.ndarray,
    capsule_frames: np.ndarray,
    force_bounds: np.ndarray,
    friction: float,
) -> tuple[list[int], list[int], list[int]]:
    """The capsules of ``model`` standing in the rest pose (bone vectors ``rest_vectors``, each
    capsule in its rest frame ``capsule_frames``), their tracking constraints (bounded by
    ``force_bounds``) and their ball joints. Returns the body ids, the tracking constraints and
    the joint constraints."""
    pb, cid = pybullet, client
    bodies: list[int] = []
    trackings: list[int] = []
    joints: list[int] = []
    rest = poses.rest_pose(model.bone_lengths).astype(np.float64)
    centres = rest[STARTS] + 0.5 * rest_vectors
    # Each ball joint (a bone's start) in its parent's and in its own body frame, at rest.
    children = np.arange(1, NUM_BONES)
    parents = PARENT_BONE[children]
    joint_points = rest[STARTS[children]]
    in_parent = quat_rotate(
        quat_conj(capsule_frames[parents]), joint_points - centres[parents]
    ).tolist()
    in_child = quat_rotate(
        quat_conj(capsule_frames[children]), joint_points - centres[children]
    ).tolist()

    for bone in range(NUM_BONES):  # one-off construction, not a hot path
        radius, length = float(model.radii[bone]), float(model.bone_lengths[bone])
        shape = pb.createCollisionShape(
            pb.GEOM_CAPSULE, radius=radius, height=length, physicsClientId=cid
        )
        body = pb.createMultiBody(
            baseMass=float(model.masses[bone]),
            baseCollisionShapeIndex=shape,
            basePosition=centres[bone].tolist(),
            baseOrientation=capsule_frames[bone].tolist(),
            physicsClientId=cid,
        )
        pb.changeDynamics(
            body,
            -1,
            localInertiaDiagonal=model.inertia[bone].tolist(),
            linearDamping=0.0,
            angularDamping=0.0,
            lateralFriction=friction,
            restitution=0.0,
            physicsClientId=cid,
        )
        pb.setCollisionFilterGroupMask(body, -1, _BODY_GROUP, _FLOOR_GROUP, physicsClientId=cid)
        bodies.append(body)
        # The body part's PD drive: its centre of mass frame to a moving world frame.
        tracking = pb.createConstraint(
            body,
            -1,
            -1,
            -1,
            pb.JOINT_FIXED,
            [0.0, 0.0, 0.0],
            parentFramePosition=[0.0, 0.0, 0.0],
            childFramePosition=centres[bone].tolist(),
            childFrameOrientation=capsule_frames[bone].tolist(),
            physicsClientId=cid,
        )
        pb.changeConstraint(tracking, maxForce=float(force_bounds[bone]), physicsClientId=cid)
        trackings.append(tracking)
    # Ball joints: each bone's start to its parent at the shared Kinect joint.
    joint_force = _JOINT_FORCE_BODY_WEIGHTS * model.total_mass * GRAVITY
    for i, bone in enumerate(range(1, NUM_BONES)):
        constraint = pb.createConstraint(
            bodies[int(PARENT_BONE[bone])],
            -1,
            bodies[bone],
            -1,
            pb.JOINT_POINT2POINT,
            [0.0, 0.0, 0.0],
            parentFramePosition=in_parent[i],
            childFramePosition=in_child[i],
            physicsClientId=cid,
        )
        pb.changeConstraint(constraint, maxForce=joint_force, physicsClientId=cid)
        joints.append(constraint)
    return bodies, trackings, joints


def remove_body(client: int, bodies: list[int], constraints: list[int]) -> None:
    """Remove a body's constraints and capsules (the floor stays)."""
    for constraint in constraints:
        pybullet.removeConstraint(constraint, physicsClientId=client)
    for body in bodies:
        pybullet.removeBody(body, physicsClientId=client)


def place_body(
    client: int,
    bodies: list[int],
    trackings: list[int],
    centres: np.ndarray,
    orientations: np.ndarray,
) -> None:
    """Put every capsule exactly on its goal, at rest, with its tracking target there."""
    pb, cid = pybullet, client
    zero = [0.0, 0.0, 0.0]
    for bone, (body, constraint) in enumerate(zip(bodies, trackings, strict=True)):
        centre, orientation = centres[bone].tolist(), orientations[bone].tolist()
        pb.resetBasePositionAndOrientation(body, centre, orientation, physicsClientId=cid)
        pb.resetBaseVelocity(body, zero, zero, physicsClientId=cid)
        pb.changeConstraint(
            constraint,
            jointChildPivot=centre,
            jointChildFrameOrientation=orientation,
            physicsClientId=cid,
        )
