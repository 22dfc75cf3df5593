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
target more tightly. The defaults, 120 Hz, ``erp`` 0.6 and at most 15 solver iterations (fewer
once an iteration changes no row's velocity by more than ``solver_tolerance``, 0.1 m/s), track
clean mocap to a few millimetres and lower the jitter of noisy targets; they replaced 240 Hz,
0.4 and 10 iterations (issue 38: half the physics steps, the same error against the ground truth
to 0.3 %, see ``docs/performance.md``), which ``physics_rate=240, erp=0.4, solver_iterations=10``
with ``solver_tolerance=1e-7 ** 0.5`` (pybullet's own threshold, to rounding) still give.

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
from itertools import chain, repeat
from types import TracebackType
from typing import Any, Literal

import numpy as np

from fpg_gym.core import poses, skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.errors import FpgGymError
from fpg_gym.core.poses import FloorShift
from fpg_gym.core.rotations import shortest_arc
from fpg_gym.physics.pybullet_utils import hand_back, pybullet, reuse_direct
from fpg_gym.physics.ragdoll_build import build_body, build_world, place_body, remove_body
from fpg_gym.physics.ragdoll_guards import divergence, glide
from fpg_gym.physics.ragdoll_kinematics import (
    BONES,
    LINES,
    NUM_BONES,
    PARENT_BONE,
    body_goals,
    bone_frames,
    joint_velocities,
    pose_and_gap,
    pose_from,
    substep_goals,
)
from fpg_gym.physics.ragdoll_model import GRAVITY, BodyModel, build_body_model
from fpg_gym.physics.ragdoll_scene import Scene, front_left_view

# FloorShift (fpg_gym.core.poses) is imported here too: the shift a camera-space stream takes around
# the ragdoll.
__all__ = ["FloorShift", "PhysicsError", "PhysicsWarning", "Ragdoll"]

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
#: ``pybullet.changeConstraint``'s values that leave a setting as it is: maxForce, gearRatio,
#: gearAuxLink, relativePositionTarget, erp (positional, in pybullet's order).
_UNCHANGED = (-1.0, 0.0, -1, 1e32, -1.0)


class PhysicsError(FpgGymError, RuntimeError):
    """The simulation diverged (non-finite state, a joint impossibly fast or far from its target,
    or the joints pulled apart). The ragdoll has already been reset to the target when this is
    raised, so the caller may go on tracking."""


class PhysicsWarning(UserWarning):
    """The simulation diverged and the ragdoll was reset to the target
    (``on_divergence="reset"``)."""


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
        Constraint-solver iterations per physics step, at most.
    solver_tolerance : float
        The solver stops before ``solver_iterations`` once an iteration changes no constraint
        row's velocity by more than this (m/s, rad/s for the angular rows; pybullet's
        ``solverResidualThreshold`` is its square, 1e-7 by default: about 3.2e-4). 0.1 m/s
        over a 120 Hz step is 0.8 mm.
    on_divergence : {"reset", "quiet", "raise"}
        What :meth:`track` does when the simulation diverges. All reset the body to the target
        and count the event in :attr:`info`; ``"reset"`` then warns (:class:`PhysicsWarning`)
        and returns the target's pose, ``"quiet"`` returns it without a warning, ``"raise"``
        raises :class:`PhysicsError`.
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
        solver_tolerance: float = 0.1,
        on_divergence: Literal["reset", "quiet", "raise"] = "reset",
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
            ("solver_tolerance", solver_tolerance),
        ):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive number, got {value!r}")
        if not 0 < erp <= 1:
            raise ValueError(f"erp: expected a number in (0, 1], got {erp!r}")
        if not (np.isfinite(friction) and friction >= 0):
            raise ValueError(f"friction: expected a non-negative number, got {friction!r}")
        if int(solver_iterations) < 1:
            raise ValueError(f"solver_iterations: expected at least 1, got {solver_iterations!r}")
        if on_divergence not in ("reset", "quiet", "raise"):
            raise ValueError(
                f"on_divergence: expected 'reset', 'quiet' or 'raise', got {on_divergence!r}"
            )
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
        self._solver_tolerance = float(solver_tolerance)

        self._rest_directions = np.array(poses.REST_DIRECTIONS, dtype=np.float64)
        self._root_arc = shortest_arc(np.array([0.0, 1.0, 0.0]), self._rest_directions[0])
        # The per-frame arithmetic compiled, when numba is installed (the same formulas).
        self._kernels = compiled_module("fpg_gym.physics.compiled_ragdoll")
        # Each capsule body's frame at rest: centre of mass, Z along the bone (pybullet
        # capsules lie along Z), so its inertia is diagonal in it.
        self._capsule_frames = shortest_arc(
            np.tile([0.0, 0.0, 1.0], (NUM_BONES, 1)), self._rest_directions
        )
        # The physics client draws nothing (building bodies costs half as much without the
        # renderer); render() draws the body in a client of its own, built on first use. A
        # closed ragdoll's client is reused (the first rebuild resets its world and settings).
        self.client = reuse_direct("ragdoll")
        # pybullet.changeConstraint's trailing positional arguments in track(), for map().
        self._unchanged = tuple(repeat(value) for value in (*_UNCHANGED, self.client))
        self._closed = False
        self._scene: Scene | None = None
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
        self,
        bone_lengths: np.ndarray | None = None,
        *,
        body_mass: float | None = None,
        stand: bool = True,
    ) -> None:
        """Rebuild the body for new bone lengths in the same pybullet client, from scratch.

        Cheaper than a new :class:`Ragdoll` (no new client) and just as deterministic: the
        previous body's capsules and constraints are removed (the world keeps only its floor,
        which holds no state) and new ones built, so that the body tracks as a new ragdoll's
        does, to the bit (tested). pybullet keeps a removed body's collision shapes, so every
        :data:`_REBUILDS_PER_RESET` rebuilds the whole simulation is reset instead (the same
        results). The counters in :attr:`info` restart and the body stands in
        :meth:`standing_pose`; with ``stand=False`` it is left where it was built, for a caller
        that places it with :meth:`reset` next (the same results as after standing).
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
        self._goal = (np.zeros(3), np.tile([0.0, 0.0, 0.0, 1.0], (NUM_BONES, 1)))
        self._offset = np.zeros(3)
        self._offset_velocity = np.zeros(3)
        self._jumps = 0
        if self.bodies and self._removals < _REBUILDS_PER_RESET:
            self._remove_body()
            self._removals += 1
        else:
            self.bodies, self._tracking, self._joints = [], [], []
            self.floor = build_world(
                self.client,
                time_step=self.time_step,
                erp=self.erp,
                solver_iterations=self._solver_iterations,
                solver_tolerance=self._solver_tolerance,
                floor_height=self.floor_height,
                friction=self._friction,
            )
            self._removals = 0
        self.bodies, self._tracking, self._joints = build_body(
            self.client,
            self.model,
            self._rest_vectors,
            self._capsule_frames,
            self.force_bounds,
            self._friction,
        )
        if stand:
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

    def _remove_body(self) -> None:
        """Remove the body's constraints and capsules (the floor stays)."""
        remove_body(self.client, self.bodies, self._joints + self._tracking)
        self.bodies, self._tracking, self._joints = [], [], []

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
                BONES,
                PARENT_BONE,
                LINES,
            )
        else:
            world, self._directions = bone_frames(
                pose64, self._directions, self._root_frame, self._rest_directions, self._root_arc
            )
        self._root_frame = world[0]
        return pose64[skeleton.ROOT], world

    def _body_goals(self, root: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre-of-mass positions and body orientations of the capsules for a root position
        ``(..., 3)`` and bone frames ``(..., 19, 4)``."""
        return body_goals(root, world, self._rest_vectors, self._capsule_frames)

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
        self._offset, self._offset_velocity = glide(
            self._offset,
            self._offset_velocity,
            dt=1.0 / self.frame_rate,
            recovery_frequency=self.recovery_frequency,
            acceleration=self._glide,
        )
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
                root0, world0, root1, world1, n, self._rest_vectors, self._capsule_frames, BONES
            )
        else:
            centres_all, orientations_all, world1 = substep_goals(
                root0, world0, root1, world1, n, self._rest_vectors, self._capsule_frames
            )
        goal = (root1, world1)
        change, step, cid = pybullet.changeConstraint, pybullet.stepSimulation, self.client
        tracking, unchanged = self._tracking, self._unchanged
        # The pybullet call boundary: one call per body part and step, made by map (no Python
        # frame per call), positional (half the cost of keywords): the pivot and orientation,
        # then pybullet's "leave unchanged" maxForce, gearRatio, gearAuxLink,
        # relativePositionTarget and erp, then the client.
        for centres_k, orientations_k in zip(
            centres_all.tolist(), orientations_all.tolist(), strict=True
        ):
            for _ in map(change, tracking, centres_k, orientations_k, *unchanged):
                pass
            step(physicsClientId=cid)
        self._goal = goal
        self._target = target.copy()
        self._frames += 1
        output = self._read_pose()
        problem = divergence(
            output,
            target,
            self._offset,
            self._output,
            self._joint_gap,
            frame_rate=self.frame_rate,
            max_speed=self.max_speed,
            max_distance=self.max_distance,
            max_joint_gap=self.max_joint_gap,
            kernels=self._kernels,
        )
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
            if self.on_divergence == "reset":
                warnings.warn(message, PhysicsWarning, stacklevel=2)
            return output.copy()
        self._output = output
        return output.copy()

    def _place(self, centres: np.ndarray, orientations: np.ndarray) -> None:
        """Put every capsule exactly on its goal, at rest, with the tracking targets there."""
        place_body(self.client, self.bodies, self._tracking, centres, orientations)

    # ----------------------------------------------------------------------- state

    def _body_states(self) -> tuple[np.ndarray, np.ndarray]:
        """The capsules' centres ``(19, 3)`` and orientations ``(19, 4)`` (x, y, z, w)."""
        states = map(pybullet.getBasePositionAndOrientation, self.bodies, repeat(self.client))
        flat = np.fromiter(chain.from_iterable(chain.from_iterable(states)), np.float64)
        flat = flat.reshape(len(self.bodies), 7)
        return flat[:, :3].copy(), flat[:, 3:].copy()

    def _pose_from(
        self, centres: np.ndarray, orientations: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics of the capsules: joints ``(20, 3)`` and bone vectors ``(19, 3)``."""
        return pose_from(centres, orientations, self._capsule_frames, self._rest_vectors)

    def _read_pose(self) -> np.ndarray:
        centres, orientations = self._body_states()
        if self._kernels is not None:
            joints, gap = self._kernels.pose_from(
                centres, orientations, self._capsule_frames, self._rest_vectors, BONES
            )
            self._joint_gap = float(gap)
        else:
            joints, self._joint_gap = pose_and_gap(
                centres, orientations, self._capsule_frames, self._rest_vectors
            )
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
        return joint_velocities(joints, centres, linear, angular).astype(np.float32)

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
        eye, centre = front_left_view(self.joint_positions.astype(np.float64))
        if self._scene is None or self._scene.model is not self.model:
            if self._scene is not None:
                self._scene.close()
            self._scene = Scene(self.model, self.floor_height)
        return self._scene.picture(*self._body_states(), eye, centre, int(width), int(height))

    # ----------------------------------------------------------------------- lifetime

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("this Ragdoll is closed")

    def close(self) -> None:
        """Release the pybullet client (idempotent): emptied and kept for the next ragdoll
        (:func:`fpg_gym.physics.pybullet_utils.hand_back`)."""
        if not self._closed:
            self._closed = True
            if self._scene is not None:
                self._scene.close()
                self._scene = None
            hand_back("ragdoll", self.client)

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
