"""PD-controlled ragdoll in pybullet: the final kinematic filter (Shum 2013 §VII, FPG 2016 §7).

A :class:`Ragdoll` simulates one body of 19 rigid capsules, one per Kinect bone of
:data:`fpg_gym.core.skeleton.BONES`, joined by ball joints (point-to-point constraints) at the
Kinect joints, with masses and sizes from :mod:`fpg_gym.physics.ragdoll_model` (de Leva 1996), on a
floor plane under gravity. Each :meth:`Ragdoll.track` call advances one Kinect frame: the targets
are interpolated between the previous and the new frame over ``substeps`` physics steps (4 at 30 Hz:
120 Hz physics) and the simulated pose is returned.

Frame of the poses
------------------
:meth:`Ragdoll.reset` and :meth:`Ragdoll.track` take and return ``(20, 3)`` Kinect-20 joint
positions in metres in the *simulation world*: Y up, gravity ``(0, -9.81, 0)``, the floor is the
plane ``y = floor_height`` (0 by default; ``floor_height=None`` removes it). Poses must therefore
stand on that floor, as the embedded DeepMimic clips and the Bandai Namco clips do when read. A
normalised pose (root at the origin, :func:`fpg_gym.core.poses.normalise`) is put on the floor by
adding its root height, ``pose + (0, root_height, 0)``, and the output is moved back the same
way; a camera-space stream by subtracting ``(0, y_floor, 0)``, with ``y_floor`` the lowest joint
minus :attr:`Ragdoll.foot_clearance` (a foot joint lies that far above the sole). Yaw and
horizontal position are free. Only the target's root position and bone directions are tracked:
the output always has the model's bone lengths (see below).

Control, against the papers
---------------------------
Shum §VII / FPG §7 pull each body part toward its target with a bounded PD force
``F = Ke (p_t − p) + Kd (ṗ_t − ṗ)`` and add a bounded PD torque about the segment's axis toward a
target twist. Computing and applying 19 forces from Python at every physics step would exceed the
frame budget and is unstable with stiff gains, so each body part is driven by pybullet's own
implicit (constraint-based) PD instead: a 6-DOF "fixed" constraint between the capsule's centre
of mass and a target frame that moves every physics step, whose solver impulse on every row is
clipped to ``maxForce × dt``:

* **force** (three linear rows): toward the target centre of mass, the midpoint of the bone's two
  target joints; each step the constraint asks for the velocity that removes the fraction
  ``erp`` of the position error (the implicit ``Ke``) and cancels the rest of the velocity
  (the implicit ``Kd``); ``|F| ≤ strength × m g`` per axis, ``m`` the segment mass, so a part
  can accelerate at most ``(strength − 1) g`` against gravity;
* **torque** (three angular rows): toward the target orientation of the segment, i.e. its bone
  direction *and* its twist, with the same bound (the constraint has a single ``maxForce``, so
  the torque bound is numerically ``strength × m g`` in N m);
* **twist** target (Kinect positions do not observe the rotation about a bone): the documented
  simpler rule instead of Shum §VII-B's twist from the neighbouring database poses — each bone's
  target frame is the shortest-arc swing, in its parent's target frame, from its rest direction
  to its target direction (zero twist relative to the parent); the root frame comes from the
  spine direction and the hip line.

``erp`` is pybullet's global error-reduction parameter (pybullet ignores it per constraint), so
it also sets how firmly the joints hold together. Lower values track with more lag and smooth
more (a first-order lag of time constant ``dt / erp`` per body part), higher values follow the
target more tightly. The defaults, 120 Hz, ``erp`` 0.6 and 15 solver iterations, track clean
mocap to a few millimetres and lower the jitter of noisy targets; they replaced 240 Hz, 0.4 and
10 iterations (issue 38: half the physics steps, the same error against the ground truth to
0.3 %, see ``docs/performance.md``), which ``physics_rate=240, erp=0.4, solver_iterations=10``
still give.

The per-frame arithmetic around pybullet (the target's bone frames, the capsules' goals at
each step, the forward kinematics of the simulated capsules) runs compiled with numba when
``fpg-gym[fast]`` is installed (:mod:`fpg_gym.physics.compiled_ragdoll`), else in numpy, with
the same results. The physics client has no renderer (bodies are built in half the time);
:meth:`Ragdoll.render` draws in a client of its own.

Targets are interpolated between frames on the skeleton — root linearly, bone frames by
normalised quaternion interpolation, then forward kinematics to the capsules — and moved at
every physics step. A root target that jumps by more than ``jump_distance`` in one
frame (a teleport) is approached by a glide within the force bounds instead (see
:meth:`Ragdoll._catch_up`); its count is ``info["jumps"]``.

The joints are point-to-point constraints (force bound 100 body weights: physics, not control).
The output pose is the forward kinematics of the simulated segments — the root (the HipCenter
end of the HipCenter–Spine capsule) plus each capsule's axis times its bone length — so bone
lengths are exact by construction. How far the iterative solver lets the joint constraints drift
apart is reported as ``info["joint_gap"]`` / ``info["max_joint_gap"]``: about a millimetre
typically at the default ``erp``, up to about 2 cm in the fastest motions and a few centimetres
while a target pushes a body part into the floor (contact, bounded tracking and joint then
disagree); beyond ``max_joint_gap`` the step counts as a divergence. Self-collisions are off
(Kinect targets often pass limbs through the body); every capsule collides with the floor.

Examples
--------
>>> from fpg_gym.core import poses
>>> from fpg_gym.physics.ragdoll import Ragdoll
>>> pose = poses.rest_pose() + (0.0, 0.96, 0.0)
>>> with Ragdoll() as body:
...     _ = body.reset(pose)
...     out = body.track(pose)
>>> out.shape
(20, 3)
"""

from __future__ import annotations

import math
import warnings
from types import TracebackType
from typing import Any, Literal

import numpy as np

from fpg_gym.core import poses, skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.errors import FpgGymError
from fpg_gym.core.poses import FloorShift
from fpg_gym.core.rotations import cross_product, shortest_arc
from fpg_gym.physics.pybullet_utils import connect_direct, pybullet
from fpg_gym.physics.ragdoll_model import GRAVITY, BodyModel, build_body_model

# FloorShift (fpg_gym.core.poses) is imported here too: the shift a camera-space stream takes around
# the ragdoll.
__all__ = ["FloorShift", "PhysicsError", "PhysicsWarning", "Ragdoll"]

_NB = skeleton.NUM_BONES
_HIP_LEFT = skeleton.joint_index("HipLeft")
_HIP_RIGHT = skeleton.joint_index("HipRight")
_SHOULDER_LEFT = skeleton.joint_index("ShoulderLeft")
_SHOULDER_RIGHT = skeleton.joint_index("ShoulderRight")
_DEGENERATE_M = 1e-6
_JOINT_FORCE_BODY_WEIGHTS = 100.0
_BODY_GROUP, _FLOOR_GROUP = 1, 2
#: Rebuilds that remove the body before one resets the whole simulation (which frees the
#: collision shapes pybullet keeps after a body is removed).
_REBUILDS_PER_RESET = 64


class PhysicsError(FpgGymError, RuntimeError):
    """The simulation diverged (non-finite state, a joint impossibly fast or far from its target,
    or the joints pulled apart). The ragdoll has already been reset to the target when this is
    raised, so the caller may go on tracking."""


class PhysicsWarning(UserWarning):
    """The simulation diverged and the ragdoll was reset to the target
    (``on_divergence="reset"``)."""


# --------------------------------------------------------------------------- tree of the bones


def _parent_bones() -> np.ndarray:
    """Parent bone of each bone: the bone ending at its start joint; the bones leaving the root
    (the pelvis halves) hang from bone 0 (HipCenter–Spine). -1 for bone 0."""
    parents = np.array([skeleton.BONE_OF_JOINT[p] for p, _ in skeleton.BONES], dtype=np.intp)
    parents[parents < 0] = 0
    parents[0] = -1
    return parents


_PARENT_BONE = _parent_bones()


def _levels() -> list[np.ndarray]:
    """Bones grouped by depth below bone 0 (a parent always sits in an earlier group)."""
    depth = np.zeros(_NB, dtype=np.intp)
    for bone in range(1, _NB):  # BONES is ordered so that a parent bone comes first
        depth[bone] = depth[_PARENT_BONE[bone]] + 1
    return [np.flatnonzero(depth == d) for d in range(1, int(depth.max()) + 1)]


_LEVELS = _levels()
_PATH = np.array(skeleton.PATH_MATRIX)  # joint = root + PATH @ bone vectors
_STARTS = np.array(skeleton.BONES[:, 0])
_BONES = np.ascontiguousarray(skeleton.BONES, dtype=np.intp)
_LINES = np.array([[_HIP_LEFT, _HIP_RIGHT], [_SHOULDER_LEFT, _SHOULDER_RIGHT]], dtype=np.intp)


# --------------------------------------------------------------------------- quaternions (x y z w)
# Written out component by component: these run on (19, 4) arrays every frame, where numpy's
# generic cross/moveaxis cost more than the arithmetic.


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
    out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


def _quat_conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def _quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    u = q[..., :3]
    t = 2.0 * cross_product(u, v)
    return v + q[..., 3:] * t + cross_product(u, t)


def _matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """One rotation matrix ``(3, 3)`` to a unit quaternion (x, y, z, w) (Shepperd's method)."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-12))
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i] = s / 4
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
    out = np.array(q)
    return out / np.linalg.norm(out)


# --------------------------------------------------------------------------- the ragdoll


class Ragdoll:
    """A PD-controlled ragdoll that tracks Kinect-20 target poses (Shum §VII, FPG §7).

    Parameters
    ----------
    bone_lengths : array_like, shape (19,), optional
        The user's bone lengths (m) in :data:`skeleton.BONES` order;
        :data:`poses.DEFAULT_BONE_LENGTHS` when omitted.
    body_mass : float, optional
        Body mass in kg; de Leva's 73 kg scaled by size when omitted
        (:func:`fpg_gym.physics.ragdoll_model.default_body_mass`).
    frame_rate : float
        Target (Kinect) frames per second; one :meth:`track` call advances ``1 / frame_rate`` s.
    physics_rate : float
        Minimum physics steps per second; the step is ``1 / (frame_rate × substeps)`` with
        ``substeps = ceil(physics_rate / frame_rate)`` (4 at the defaults: 120 Hz).
    strength : float
        Bound of each body part's tracking force, per axis, in multiples of its weight
        (``strength × m g`` N; the tracking torque has the same bound in N m).
    erp : float
        Error reduction parameter of every constraint, in (0, 1]: the fraction of a position or
        orientation error (tracking or joint) that the solver removes per physics step, i.e.
        the implicit PD stiffness of the tracking and how firmly the joints hold together
        (lower: smoother and laggier).
    floor_height : float or None
        Height of the floor plane (m); ``None`` for no floor.
    friction : float
        Coulomb friction coefficient between the body and the floor.
    solver_iterations : int
        Constraint-solver iterations per physics step.
    on_divergence : {"reset", "raise"}
        What :meth:`track` does when the simulation diverges. Both reset the body to the target
        and count the event in :attr:`info`; ``"reset"`` then warns (:class:`PhysicsWarning`)
        and returns the target's pose, ``"raise"`` raises :class:`PhysicsError`.
    max_speed : float
        A joint faster than this (m/s) counts as divergence.
    max_distance : float
        A joint farther than this (m) from its target (during a teleport glide: from where the
        glide has brought the target) counts as divergence.
    max_joint_gap : float
        Joint constraints pulled further apart than this (m) count as divergence.
    jump_distance : float
        A root target that moves further than this (m) in one frame is a teleport: the body
        glides to it (see :meth:`_catch_up`) rather than being pulled at full force.
    recovery_frequency : float
        Rate (1/s) at which that glide closes the remaining distance once near (about
        ``5 / recovery_frequency`` s for the last stretch).

    Attributes
    ----------
    model : BodyModel
        Masses, radii and inertias of the segments.
    client : int
        The pybullet client id (DIRECT mode, owned by this object).
    bodies : list of int
        The 19 capsule bodies, in :data:`skeleton.BONES` order.
    substeps : int
        Physics steps per :meth:`track`.
    time_step : float
        Physics step (s).
    force_bounds : ndarray, shape (19,)
        Tracking force bound of each body part (N per axis; N m per axis for the torque).
    """

    def __init__(
        self,
        bone_lengths: np.ndarray | None = None,
        *,
        body_mass: float | None = None,
        frame_rate: float = 30.0,
        physics_rate: float = 120.0,
        strength: float = 10.0,
        erp: float = 0.6,
        floor_height: float | None = 0.0,
        friction: float = 0.9,
        solver_iterations: int = 15,
        on_divergence: Literal["reset", "raise"] = "reset",
        max_speed: float = 50.0,
        max_distance: float = 5.0,
        max_joint_gap: float = 0.1,
        jump_distance: float = 0.3,
        recovery_frequency: float = 10.0,
    ) -> None:
        self._closed = True  # until the client exists
        for name, value in (
            ("frame_rate", frame_rate),
            ("physics_rate", physics_rate),
            ("strength", strength),
            ("max_speed", max_speed),
            ("max_distance", max_distance),
            ("max_joint_gap", max_joint_gap),
            ("jump_distance", jump_distance),
            ("recovery_frequency", recovery_frequency),
        ):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive number, got {value!r}")
        if not 0 < erp <= 1:
            raise ValueError(f"erp: expected a number in (0, 1], got {erp!r}")
        if not (np.isfinite(friction) and friction >= 0):
            raise ValueError(f"friction: expected a non-negative number, got {friction!r}")
        if int(solver_iterations) < 1:
            raise ValueError(f"solver_iterations: expected at least 1, got {solver_iterations!r}")
        if on_divergence not in ("reset", "raise"):
            raise ValueError(f"on_divergence: expected 'reset' or 'raise', got {on_divergence!r}")
        if floor_height is not None and not np.isfinite(floor_height):
            raise ValueError(
                f"floor_height: expected a finite number or None, got {floor_height!r}"
            )

        self.frame_rate = float(frame_rate)
        self.substeps = max(1, math.ceil(physics_rate / frame_rate - 1e-9))
        self.time_step = 1.0 / (self.frame_rate * self.substeps)
        self.floor_height = None if floor_height is None else float(floor_height)
        self.erp = float(erp)
        self.on_divergence = on_divergence
        self.max_speed = float(max_speed)
        self.max_distance = float(max_distance)
        self.max_joint_gap = float(max_joint_gap)
        self.jump_distance = float(jump_distance)
        self.recovery_frequency = float(recovery_frequency)
        self._strength = float(strength)
        self._glide = 0.5 * max(self._strength - 1.0, 0.5) * GRAVITY
        self._friction = float(friction)
        self._solver_iterations = int(solver_iterations)

        self._rest_directions = np.array(poses.REST_DIRECTIONS, dtype=np.float64)
        self._root_arc = shortest_arc(np.array([0.0, 1.0, 0.0]), self._rest_directions[0])
        # The per-frame arithmetic compiled, when numba is installed (the same formulas).
        self._kernels = compiled_module("fpg_gym.physics.compiled_ragdoll")
        # Each capsule body's frame at rest: centre of mass, Z along the bone (pybullet
        # capsules lie along Z), so its inertia is diagonal in it.
        self._capsule_frames = shortest_arc(
            np.tile([0.0, 0.0, 1.0], (_NB, 1)), self._rest_directions
        )
        # The physics client draws nothing (building bodies costs half as much without the
        # renderer); render() draws the body in a client of its own, built on first use.
        self.client = connect_direct(renderer=False)
        self._closed = False
        self._scene: _Scene | None = None
        self.bodies: list[int] = []
        self._tracking: list[int] = []
        self._joints: list[int] = []
        self._removals = 0
        try:
            self.rebuild(bone_lengths, body_mass=body_mass)
        except BaseException:
            self.close()
            raise

    def rebuild(
        self, bone_lengths: np.ndarray | None = None, *, body_mass: float | None = None
    ) -> None:
        """Rebuild the body for new bone lengths in the same pybullet client, from scratch.

        Cheaper than a new :class:`Ragdoll` (no new client) and just as deterministic: the
        previous body's capsules and constraints are removed (the world keeps only its floor,
        which holds no state) and new ones built, so that the body tracks as a new ragdoll's
        does, to the bit (tested). pybullet keeps a removed body's collision shapes, so every
        :data:`_REBUILDS_PER_RESET` rebuilds the whole simulation is reset instead (the same
        results). The counters in :attr:`info` restart and the body stands in
        :meth:`standing_pose`.
        """
        self._check_open()
        self.model: BodyModel = build_body_model(bone_lengths, body_mass)
        self.force_bounds = self._strength * self.model.masses * GRAVITY
        self._rest_vectors = self._rest_directions * self.model.bone_lengths[:, None]
        self._frames = 0
        self._divergences = 0
        self._last_error = ""
        self._joint_gap = 0.0
        self._max_joint_gap = 0.0
        self._target = np.zeros((skeleton.NUM_JOINTS, 3), dtype=np.float32)
        self._output = np.zeros((skeleton.NUM_JOINTS, 3), dtype=np.float32)
        self._directions = self._rest_directions.copy()
        self._root_frame = np.array([0.0, 0.0, 0.0, 1.0])
        self._goal = (np.zeros(3), np.tile([0.0, 0.0, 0.0, 1.0], (_NB, 1)))
        self._offset = np.zeros(3)
        self._offset_velocity = np.zeros(3)
        self._jumps = 0
        if self.bodies and self._removals < _REBUILDS_PER_RESET:
            self._remove_body()
            self._removals += 1
        else:
            self._build_world(self._friction, self._solver_iterations)
            self._removals = 0
        self._build_body(self._friction)
        self.reset(self.standing_pose())

    # ----------------------------------------------------------------------- construction

    @property
    def foot_clearance(self) -> float:
        """Radius of the foot capsules (m): how far above the floor a foot joint sits when the
        foot lies on it. A caller that places poses on the floor (``floor_height`` = lowest
        joint − this) avoids pushing the feet into it."""
        foot = int(skeleton.BONE_OF_JOINT[skeleton.joint_index("FootLeft")])
        return float(self.model.radii[foot])

    def standing_pose(self) -> np.ndarray:
        """The rest pose of :func:`poses.rest_pose` with the model's bone lengths, its feet on
        the floor (capsule radius included), facing +Z at the origin, ``(20, 3)`` float32."""
        rest = poses.rest_pose(self.model.bone_lengths).astype(np.float64)
        floor = 0.0 if self.floor_height is None else self.floor_height
        lift = floor - rest[:, 1].min() + self.foot_clearance
        return (rest + np.array([0.0, lift, 0.0])).astype(np.float32)

    def _build_world(self, friction: float, solver_iterations: int) -> None:
        """The physics settings and the floor, in an empty world."""
        pb, cid = pybullet, self.client
        pb.resetSimulation(physicsClientId=cid)
        self.bodies, self._tracking, self._joints = [], [], []
        pb.setGravity(0.0, -GRAVITY, 0.0, physicsClientId=cid)
        pb.setPhysicsEngineParameter(
            fixedTimeStep=self.time_step,
            numSubSteps=0,
            numSolverIterations=solver_iterations,
            erp=self.erp,
            deterministicOverlappingPairs=1,
            physicsClientId=cid,
        )
        self.floor = -1
        if self.floor_height is not None:
            plane = pb.createCollisionShape(
                pb.GEOM_PLANE, planeNormal=[0.0, 1.0, 0.0], physicsClientId=cid
            )
            self.floor = pb.createMultiBody(
                baseMass=0.0,
                baseCollisionShapeIndex=plane,
                basePosition=[0.0, self.floor_height, 0.0],
                physicsClientId=cid,
            )
            pb.changeDynamics(
                self.floor, -1, lateralFriction=friction, restitution=0.0, physicsClientId=cid
            )
            pb.setCollisionFilterGroupMask(
                self.floor, -1, _FLOOR_GROUP, _BODY_GROUP, physicsClientId=cid
            )

    def _build_body(self, friction: float) -> None:
        """The capsules of :attr:`model`, their tracking constraints and their joints."""
        pb, cid = pybullet, self.client
        model = self.model
        rest = poses.rest_pose(model.bone_lengths).astype(np.float64)
        centres = rest[_STARTS] + 0.5 * self._rest_vectors
        for bone in range(_NB):  # one-off construction, not a hot path
            radius, length = float(model.radii[bone]), float(model.bone_lengths[bone])
            shape = pb.createCollisionShape(
                pb.GEOM_CAPSULE, radius=radius, height=length, physicsClientId=cid
            )
            body = pb.createMultiBody(
                baseMass=float(model.masses[bone]),
                baseCollisionShapeIndex=shape,
                basePosition=centres[bone].tolist(),
                baseOrientation=self._capsule_frames[bone].tolist(),
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
            self.bodies.append(body)
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
                childFrameOrientation=self._capsule_frames[bone].tolist(),
                physicsClientId=cid,
            )
            pb.changeConstraint(
                tracking, maxForce=float(self.force_bounds[bone]), physicsClientId=cid
            )
            self._tracking.append(tracking)
        # Ball joints: each bone's start to its parent at the shared Kinect joint.
        joint_force = _JOINT_FORCE_BODY_WEIGHTS * model.total_mass * GRAVITY
        for bone in range(1, _NB):
            parent = int(_PARENT_BONE[bone])
            joint = rest[_STARTS[bone]]
            constraint = pb.createConstraint(
                self.bodies[parent],
                -1,
                self.bodies[bone],
                -1,
                pb.JOINT_POINT2POINT,
                [0.0, 0.0, 0.0],
                parentFramePosition=self._in_body(parent, joint - centres[parent]).tolist(),
                childFramePosition=self._in_body(bone, joint - centres[bone]).tolist(),
                physicsClientId=cid,
            )
            pb.changeConstraint(constraint, maxForce=joint_force, physicsClientId=cid)
            self._joints.append(constraint)

    def _remove_body(self) -> None:
        """Remove the body's constraints and capsules (the floor stays)."""
        pb, cid = pybullet, self.client
        for constraint in self._joints + self._tracking:
            pb.removeConstraint(constraint, physicsClientId=cid)
        for body in self.bodies:
            pb.removeBody(body, physicsClientId=cid)
        self.bodies, self._tracking, self._joints = [], [], []

    def _in_body(self, bone: int, vector: np.ndarray) -> np.ndarray:
        """A rest-pose world vector in the bone's body frame."""
        return _quat_rotate(_quat_conj(self._capsule_frames[bone]), vector)

    # ----------------------------------------------------------------------- targets

    def _bone_frames(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Root position and world orientations (x, y, z, w) of the 19 bones relative to the
        rest pose, that put every bone along the target's bone direction; twist by the
        zero-twist rule (module docstring)."""
        pose64 = np.asarray(pose, dtype=np.float64)
        if self._kernels is not None:
            world, self._directions = self._kernels.bone_frames(
                pose64,
                self._directions,
                self._root_frame,
                self._rest_directions,
                self._root_arc,
                _BONES,
                _PARENT_BONE,
                _LINES,
            )
            self._root_frame = world[0]
            return pose64[skeleton.ROOT], world
        vectors = poses.bone_vectors(pose64)
        norms = np.sqrt(np.sum(vectors * vectors, axis=-1, keepdims=True))
        ok = norms > _DEGENERATE_M
        directions = np.where(ok, vectors / np.where(ok, norms, 1.0), self._directions)
        # Root frame: spine direction and the hip line (shoulder line, then the last frame's).
        up = directions[0]
        left = None
        for a, b in ((_HIP_LEFT, _HIP_RIGHT), (_SHOULDER_LEFT, _SHOULDER_RIGHT)):
            line = pose64[a] - pose64[b]
            line = line - up * float(line @ up)
            if float(line @ line) > 1e-6:
                left = line
                break
        if left is None:
            line = _quat_rotate(self._root_frame, np.array([1.0, 0.0, 0.0]))
            left = line - up * float(line @ up)
        left = left / np.linalg.norm(left)
        frame = np.stack([left, up, cross_product(left, up)], axis=1)  # columns: rest X, Y, Z
        world = np.empty((_NB, 4))
        world[0] = _quat_mul(_matrix_to_quat(frame), self._root_arc)
        for level in _LEVELS:  # at most 5 groups, vectorised within each
            parent = world[_PARENT_BONE[level]]
            in_parent = _quat_rotate(_quat_conj(parent), directions[level])
            local = shortest_arc(self._rest_directions[level], in_parent)
            world[level] = _quat_mul(parent, local)
        self._directions = directions
        self._root_frame = world[0]
        return pose64[skeleton.ROOT], world

    def _body_goals(self, root: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre-of-mass positions and body orientations of the capsules for a root position
        ``(..., 3)`` and bone frames ``(..., 19, 4)``."""
        vectors = _quat_rotate(world, self._rest_vectors)
        joints = root[..., None, :] + _PATH @ vectors
        centres = joints[..., _STARTS, :] + 0.5 * vectors
        return centres, _quat_mul(world, self._capsule_frames)

    def _catch_up(self, root: np.ndarray) -> np.ndarray:
        """Offset added to the target root this frame (teleport recovery, module docstring).

        A root target that jumps by more than ``jump_distance`` in one frame leaves the goal
        where it was; the offset then decays at a rate of ``recovery_frequency`` (1/s) but with
        at most half the acceleration the force bounds allow (``(strength − 1) g / 2``), so the
        body glides to the new place instead of being flung there at full force and
        overshooting.
        """
        previous_goal = self._goal[0]
        jump = root + self._offset - previous_goal
        if float(np.sqrt(jump @ jump)) > self.jump_distance:
            self._offset = previous_goal - root
            self._offset_velocity = np.zeros(3)
            self._jumps += 1
        distance = float(np.sqrt(self._offset @ self._offset))
        if distance > 0.0:
            dt = 1.0 / self.frame_rate
            # Approach speed: exponential near the end, never faster than the speed from which
            # half the available acceleration can still stop the body in time.
            speed = min(self.recovery_frequency * distance, math.sqrt(2.0 * self._glide * distance))
            change = -self._offset * (speed / distance) - self._offset_velocity
            limit = self._glide * dt
            norm = float(np.sqrt(change @ change))
            if norm > limit:
                change *= limit / norm
            self._offset_velocity = self._offset_velocity + change
            self._offset = self._offset + dt * self._offset_velocity
            if distance < 1e-4:
                self._offset = np.zeros(3)
                self._offset_velocity = np.zeros(3)
        return self._offset

    # ----------------------------------------------------------------------- public API

    def reset(self, pose: np.ndarray) -> np.ndarray:
        """Place the body on ``pose`` (root position and bone directions), at rest.

        Parameters
        ----------
        pose : array_like, shape (20, 3)
            Joint positions (m) in the simulation world (see the module docstring).

        Returns
        -------
        ndarray, shape (20, 3), float32
            The body's joint positions: the pose with the model's bone lengths.
        """
        self._check_open()
        target = poses.as_poses(pose, "pose", ndim=2)
        self._directions = self._rest_directions.copy()
        self._root_frame = np.array([0.0, 0.0, 0.0, 1.0])
        goal = self._bone_frames(target)
        self._place(*self._body_goals(*goal))
        self._goal = goal
        self._offset = np.zeros(3)
        self._offset_velocity = np.zeros(3)
        self._target = target.copy()
        self._output = self._read_pose()
        return self._output.copy()

    def track(self, target_pose: np.ndarray) -> np.ndarray:
        """Advance one frame (``1 / frame_rate`` s) toward ``target_pose``; return the pose.

        Parameters
        ----------
        target_pose : array_like, shape (20, 3)
            Target joint positions (m) in the simulation world (see the module docstring). Only
            the root position and the bone directions are tracked.

        Returns
        -------
        ndarray, shape (20, 3), float32
            Simulated joint positions at the end of the frame, with the model's bone lengths.

        Raises
        ------
        PhysicsError
            With ``on_divergence="raise"``, when the simulation diverged (the body has been
            reset to the target).
        """
        self._check_open()
        target = poses.as_poses(target_pose, "target_pose", ndim=2)
        root0, world0 = self._goal
        target_root, world1 = self._bone_frames(target)
        root1 = target_root + self._catch_up(target_root)
        n = self.substeps
        # Interpolate the skeleton, not the capsules: root linearly, bone frames by normalised
        # quaternion interpolation (short way round), then forward kinematics, so that every
        # intermediate target keeps the joints together.
        if self._kernels is not None:
            centres_all, orientations_all, world1 = self._kernels.substep_goals(
                root0, world0, root1, world1, n, self._rest_vectors, self._capsule_frames, _BONES
            )
        else:
            fractions = (np.arange(1, n + 1) / n)[:, None]
            sign = np.where(np.sum(world0 * world1, axis=-1, keepdims=True) < 0, -1.0, 1.0)
            world1 = sign * world1
            blend = (1 - fractions[:, :, None]) * world0 + fractions[:, :, None] * world1
            blend /= np.sqrt(np.sum(blend * blend, axis=-1, keepdims=True))
            roots = root0 + fractions * (root1 - root0)
            centres_all, orientations_all = self._body_goals(roots, blend)
        centres = centres_all.tolist()
        orientations = orientations_all.tolist()
        goal = (root1, world1)
        change, step, cid = pybullet.changeConstraint, pybullet.stepSimulation, self.client
        pairs = list(enumerate(self._tracking))
        for k in range(n):  # the pybullet call boundary: one call per body part and step
            centres_k, orientations_k = centres[k], orientations[k]
            for bone, constraint in pairs:
                change(
                    constraint,
                    jointChildPivot=centres_k[bone],
                    jointChildFrameOrientation=orientations_k[bone],
                    physicsClientId=cid,
                )
            step(physicsClientId=cid)
        self._goal = goal
        self._target = target.copy()
        self._frames += 1
        output = self._read_pose()
        problem = self._divergence(output, target)
        if problem:
            self._divergences += 1
            self._last_error = f"frame {self._frames}: {problem}"
            self._goal = (target_root, world1)
            self._offset = np.zeros(3)
            self._offset_velocity = np.zeros(3)
            self._place(*self._body_goals(*self._goal))
            output = self._read_pose()
            self._output = output
            message = f"ragdoll diverged at {self._last_error}; reset to the target"
            if self.on_divergence == "raise":
                raise PhysicsError(message)
            warnings.warn(message, PhysicsWarning, stacklevel=2)
            return output.copy()
        self._output = output
        return output.copy()

    def _divergence(self, output: np.ndarray, target: np.ndarray) -> str:
        # Distances against the goal (the target shifted by a teleport glide's remaining
        # offset) and the last output.
        if self._kernels is not None:
            finite, distance, moved = self._kernels.divergence_measures(
                output, target, self._offset, self._output
            )
        else:
            finite = bool(np.all(np.isfinite(output)))
            distance = float(np.max(np.linalg.norm(output - (target + self._offset), axis=-1)))
            moved = float(np.max(np.linalg.norm(output - self._output, axis=-1)))
        if not (finite and math.isfinite(self._joint_gap)):
            return "non-finite joint positions"
        if distance > self.max_distance:
            return f"a joint is {distance:.3g} m from its target (max_distance {self.max_distance})"
        if moved * self.frame_rate > self.max_speed:
            speed = moved * self.frame_rate
            return f"a joint moves at {speed:.3g} m/s (max_speed {self.max_speed})"
        if self._joint_gap > self.max_joint_gap:
            return (
                f"joint constraints {self._joint_gap:.3g} m apart "
                f"(max_joint_gap {self.max_joint_gap})"
            )
        return ""

    def _place(self, centres: np.ndarray, orientations: np.ndarray) -> None:
        """Put every capsule exactly on its goal, at rest, with the tracking targets there."""
        pb, cid = pybullet, self.client
        zero = [0.0, 0.0, 0.0]
        for bone, (body, constraint) in enumerate(zip(self.bodies, self._tracking, strict=True)):
            centre, orientation = centres[bone].tolist(), orientations[bone].tolist()
            pb.resetBasePositionAndOrientation(body, centre, orientation, physicsClientId=cid)
            pb.resetBaseVelocity(body, zero, zero, physicsClientId=cid)
            pb.changeConstraint(
                constraint,
                jointChildPivot=centre,
                jointChildFrameOrientation=orientation,
                physicsClientId=cid,
            )

    # ----------------------------------------------------------------------- state

    def _body_states(self) -> tuple[np.ndarray, np.ndarray]:
        get, cid = pybullet.getBasePositionAndOrientation, self.client
        states = [get(body, physicsClientId=cid) for body in self.bodies]
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def _pose_from(
        self, centres: np.ndarray, orientations: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics of the capsules: joints ``(20, 3)`` and bone vectors ``(19, 3)``."""
        frames = _quat_mul(orientations, _quat_conj(self._capsule_frames))
        vectors = _quat_rotate(frames, self._rest_vectors)
        root = centres[0] - 0.5 * vectors[0]
        return root + _PATH @ vectors, vectors

    def _read_pose(self) -> np.ndarray:
        centres, orientations = self._body_states()
        if self._kernels is not None:
            joints, gap = self._kernels.pose_from(
                centres, orientations, self._capsule_frames, self._rest_vectors, _BONES
            )
            self._joint_gap = float(gap)
        else:
            joints, vectors = self._pose_from(centres, orientations)
            # How far each capsule's start end is from the joint it should share with its parent.
            gaps = centres - 0.5 * vectors - joints[_STARTS]
            self._joint_gap = float(np.sqrt(np.max(np.sum(gaps * gaps, axis=-1))))
        if math.isfinite(self._joint_gap):
            self._max_joint_gap = max(self._max_joint_gap, self._joint_gap)
        return joints.astype(np.float32)

    @property
    def joint_positions(self) -> np.ndarray:
        """Current joint positions ``(20, 3)`` float32 (m), Kinect-20 order."""
        self._check_open()
        return self._pose_from(*self._body_states())[0].astype(np.float32)

    @property
    def joint_velocities(self) -> np.ndarray:
        """Current joint velocities ``(20, 3)`` float32 (m/s), Kinect-20 order: each joint moves
        with the capsule that ends there (the root with the HipCenter–Spine capsule)."""
        self._check_open()
        centres, orientations = self._body_states()
        joints, _ = self._pose_from(centres, orientations)
        get, cid = pybullet.getBaseVelocity, self.client
        velocities = [get(body, physicsClientId=cid) for body in self.bodies]
        linear = np.array([v[0] for v in velocities])
        angular = np.array([v[1] for v in velocities])
        out = np.empty((skeleton.NUM_JOINTS, 3))
        out[skeleton.BONES[:, 1]] = linear + cross_product(
            angular, joints[skeleton.BONES[:, 1]] - centres
        )
        out[skeleton.ROOT] = linear[0] + cross_product(
            angular[0], joints[skeleton.ROOT] - centres[0]
        )
        return out.astype(np.float32)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Names of the rows of :attr:`joint_positions` (:data:`skeleton.JOINT_NAMES`)."""
        return skeleton.JOINT_NAMES

    @property
    def target(self) -> np.ndarray:
        """The last target pose given to :meth:`reset` or :meth:`track`, ``(20, 3)``."""
        return self._target.copy()

    @property
    def tracking_forces(self) -> np.ndarray:
        """Control effort of the last physics step, ``(19, 6)``: per body part (in
        :data:`skeleton.BONES` order) the tracking force (N, world X, Y, Z) then torque (N m).
        Every entry is bounded in magnitude by the part's :attr:`force_bounds` entry."""
        self._check_open()
        get, cid = pybullet.getConstraintState, self.client
        return np.array([get(c, physicsClientId=cid) for c in self._tracking], dtype=np.float64)

    @property
    def info(self) -> dict[str, Any]:
        """Counts and settings: frames tracked, divergences (each reset to the target) and the
        last one's message, the joint gap of the last frame and the largest so far (m), target
        jumps (teleports) seen and the root offset still being caught up (m), physics substeps
        and rate, body mass (kg)."""
        return {
            "frames": self._frames,
            "divergences": self._divergences,
            "last_divergence": self._last_error,
            "joint_gap": self._joint_gap,
            "max_joint_gap": self._max_joint_gap,
            "jumps": self._jumps,
            "catch_up_offset": float(np.sqrt(self._offset @ self._offset)),
            "substeps": self.substeps,
            "physics_rate": 1.0 / self.time_step,
            "body_mass": self.model.total_mass,
        }

    # ----------------------------------------------------------------------- rendering

    def render(self, width: int = 320, height: int = 240) -> np.ndarray:
        """An RGB image ``(height, width, 3)`` uint8 of the body seen from its front left,
        through pybullet's software renderer (``ER_TINY_RENDERER``: no display needed).

        Parameters
        ----------
        width, height : int
            Image size in pixels, 1 to 4096.
        """
        self._check_open()
        for name, value in (("width", width), ("height", height)):
            if not (isinstance(value, int | np.integer) and 1 <= value <= 4096):
                raise ValueError(f"{name}: expected an integer in [1, 4096], got {value!r}")
        pose = self.joint_positions.astype(np.float64)
        centre = 0.5 * (pose.min(axis=0) + pose.max(axis=0))
        yaw = float(poses.facing_yaw(pose))
        forward = np.array([math.sin(yaw), 0.0, math.cos(yaw)])
        side = np.array([math.cos(yaw), 0.0, -math.sin(yaw)])
        eye = centre + 2.6 * forward + 1.3 * side + np.array([0.0, 0.5, 0.0])
        if self._scene is None or self._scene.model is not self.model:
            if self._scene is not None:
                self._scene.close()
            self._scene = _Scene(self.model, self.floor_height)
        return self._scene.picture(*self._body_states(), eye, centre, int(width), int(height))

    # ----------------------------------------------------------------------- lifetime

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this Ragdoll is closed")

    def close(self) -> None:
        """Disconnect the pybullet client (idempotent)."""
        if not self._closed:
            self._closed = True
            if self._scene is not None:
                self._scene.close()
                self._scene = None
            try:
                pybullet.disconnect(physicsClientId=self.client)
            except pybullet.error:
                pass

    def __enter__(self) -> Ragdoll:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"client={self.client}"
        return (
            f"Ragdoll(mass={self.model.total_mass:.1f} kg, substeps={self.substeps}, "
            f"frames={self._frames}, {state})"
        )


class _Scene:
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
        for bone, colour in enumerate(_bone_colours()):
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


def _bone_colours() -> list[list[float]]:
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
