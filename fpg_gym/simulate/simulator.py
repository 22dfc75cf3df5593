"""Turn a clean mocap clip into a Kinect-like :class:`~fpg_gym.io.recording.Recording`.

Steps for one clip (all vectorised over frames and joints except the ray casts of the frames
that need pybullet and the reported bones of hidden joints, which follow the previous frame's):

1. **Placement.** The clip is turned about the vertical so that its mean heading (circular mean
   of :func:`fpg_gym.core.poses.facing_yaw`) faces +Z, and moved so that its mean root position is
   above the stage origin with the floor at Y = 0 (the lowest joints of the clip, less 4 cm for
   the feet). The camera stands ``distance`` metres away at ``view_deg`` around the body,
   ``camera_height`` above the floor, looking at the body's vertical at ``target_height``.
   Ground truth is the clip in camera space: ``clip @ R.T + t`` with ``R``, ``t`` stored in
   ``metadata["clip_to_camera"]`` (a rigid transform).
2. **Visibility.** :class:`~fpg_gym.simulate.scene.RayCaster` casts rays to each joint against
   the body's own shapes and the scene boxes; joints outside the field of view or the depth range
   are hidden too.
3. **Sensor noise** of :class:`~fpg_gym.simulate.models.NoiseModel` on every joint.
4. **Occlusion effects** of :class:`~fpg_gym.simulate.models.OcclusionModel` on hidden joints:
   inferred with frozen, swung or collapsed bones that drift and glitch, snapping to nearby
   occluders (reported tracked), not tracked after long occlusions, skeleton lost when too few
   joints are seen.
5. **Left/right confusion** for side-on and back-facing bodies.

Not-tracked joints keep the simulated sensor's estimate (``untracked_positions == "simulated"``)
and frames where the skeleton is lost repeat the previous report, so every position is finite.
The per-frame parameters of the models assume about 30 frames per second (the Kinect's rate).
"""

from __future__ import annotations

import hashlib
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.core.poses import as_poses, facing_yaw, yaw_matrix
from fpg_gym.core.skeleton import TRACKED
from fpg_gym.io.clip import Clip
from fpg_gym.io.recording import Recording
from fpg_gym.simulate.camera import Camera
from fpg_gym.simulate.hidden_joints import occlusion_effects
from fpg_gym.simulate.scenarios import Scenario, get_scenario
from fpg_gym.simulate.scene import RayCaster, TraceResult

__all__ = [
    "ARM_JOINTS",
    "LEG_JOINTS",
    "KinectSimulator",
    "Placement",
    "place",
    "simulate",
]

FOOT_HEIGHT_M = 0.04
#: The joints of both arms and of both legs (a side-on body may get either set swapped).
ARM_JOINTS = np.array(
    [
        skeleton.joint_index(n)
        for n in skeleton.JOINT_NAMES
        if n.startswith(("Shoulder", "Elbow", "Wrist", "Hand")) and n != "ShoulderCenter"
    ]
)
LEG_JOINTS = np.array(
    [
        skeleton.joint_index(n)
        for n in skeleton.JOINT_NAMES
        if n.startswith(("Hip", "Knee", "Ankle", "Foot")) and n != "HipCenter"
    ]
)


@dataclass(frozen=True)
class Placement:
    """Where a clip stands in the stage and where the camera is.

    ``stage = (clip - origin) @ turn.T`` and ``camera_space = clip @ rotation.T + translation``.

    Attributes
    ----------
    turn : ndarray, shape (3, 3)
        Rotation about +Y from the clip's world to the stage.
    origin : ndarray, shape (3,)
        Clip-world point that becomes the stage origin.
    camera : Camera
    rotation, translation : ndarray
        The rigid transform clip world -> camera space.
    """

    turn: np.ndarray
    origin: np.ndarray
    camera: Camera
    rotation: np.ndarray
    translation: np.ndarray

    def to_stage(self, positions: npt.ArrayLike) -> np.ndarray:
        """Clip-world positions -> stage coordinates (float64)."""
        return (np.asarray(positions, dtype=np.float64) - self.origin) @ self.turn.T

    def to_camera(self, positions: npt.ArrayLike) -> np.ndarray:
        """Clip-world positions -> camera space (float64)."""
        return np.asarray(positions, dtype=np.float64) @ self.rotation.T + self.translation


def place(positions: npt.ArrayLike, scenario: Scenario) -> Placement:
    """Place a clip ``(T, 20, 3)`` in the stage and put the scenario's camera in front of it."""
    clip = np.asarray(positions, dtype=np.float64)
    yaw = facing_yaw(clip)
    heading = float(np.arctan2(np.sin(yaw).mean(), np.cos(yaw).mean()))
    root = clip[:, skeleton.ROOT]
    floor = float(np.percentile(clip[..., 1].min(axis=1), 5)) - FOOT_HEIGHT_M
    origin = np.array([root[:, 0].mean(), floor, root[:, 2].mean()])
    turn = yaw_matrix(np.array(-heading))
    view = np.radians(scenario.view_deg)
    position = np.array(
        [scenario.distance * np.sin(view), scenario.camera_height, scenario.distance * np.cos(view)]
    )
    camera = Camera.look_at(position, (0.0, scenario.target_height, 0.0))
    axes = camera.rotation
    rotation = axes.T @ turn
    translation = -axes.T @ (turn @ origin + np.asarray(camera.position))
    return Placement(
        turn=turn, origin=origin, camera=camera, rotation=rotation, translation=translation
    )


def _as_clip(clip: Clip | npt.ArrayLike, fps: float | None) -> tuple[np.ndarray, float, str, str]:
    if isinstance(clip, Clip):
        return clip.positions.astype(np.float64), float(fps or clip.fps), clip.name, clip.source
    positions = as_poses(clip, "clip", ndim=3).astype(np.float64)
    if len(positions) == 0:
        raise ValueError("clip: no frames")
    rate = 30.0 if fps is None else float(fps)
    if not rate > 0:
        raise ValueError(f"fps: expected a positive frame rate, got {fps}")
    return positions, rate, "array", ""


def _rng(seed: int | np.random.Generator | None) -> tuple[np.random.Generator, Any]:
    if isinstance(seed, np.random.Generator):
        return seed, "generator"
    if seed is None:
        raise ValueError("seed: pass an int or a numpy Generator (simulation is seeded)")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed: expected a non-negative int or a numpy Generator, got {seed!r}")
    return np.random.default_rng(int(seed)), int(seed)


class KinectSimulator:
    """A reusable simulator for one scenario (keeps its pybullet client between clips).

    Parameters
    ----------
    scenario : str or Scenario
        A name from :func:`~fpg_gym.simulate.scenarios.scenario_names` or a custom scenario.
    rays_per_joint : int
        1 or 5 rays per joint (5 measures partial occlusion).
    traces_kept : int
        How many clips' ray casts to keep (32; 0: none). The visibility of a clip's joints does
        not depend on the seed, so a clip simulated again (another seed, the next episode of an
        env) skips the ray casts, with the same result.
    caster : RayCaster, optional
        A ray caster to share (one pybullet client for many scenarios' simulators; it stays
        open when this simulator closes). None: one of its own, made on first use.

    Examples
    --------
    >>> from fpg_gym.io import load_default_clips
    >>> from fpg_gym.simulate import KinectSimulator
    >>> with KinectSimulator("front-few") as sim:  # doctest: +SKIP
    ...     recording = sim.simulate(load_default_clips()[0], seed=0)
    """

    def __init__(
        self,
        scenario: str | Scenario,
        *,
        rays_per_joint: int = 5,
        traces_kept: int = 32,
        caster: RayCaster | None = None,
    ) -> None:
        if traces_kept < 0:
            raise ValueError(f"traces_kept: expected >= 0, got {traces_kept}")
        if caster is not None and caster.rays_per_joint != rays_per_joint:
            raise ValueError(
                f"caster: casts {caster.rays_per_joint} rays per joint, expected {rays_per_joint}"
            )
        self.scenario = get_scenario(scenario)
        self.rays_per_joint = rays_per_joint
        self.traces_kept = int(traces_kept)
        self._caster = caster
        self._owns_caster = caster is None
        self._traces: OrderedDict[bytes, TraceResult] = OrderedDict()

    def close(self) -> None:
        """Release the pybullet client (not a shared caster's)."""
        if self._caster is not None and self._owns_caster:
            self._caster.close()
        self._caster = None

    def __enter__(self) -> KinectSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _trace(self, stage: np.ndarray, camera: Camera, heading: np.ndarray) -> TraceResult:
        """The visibility of ``stage``'s joints, from the kept traces when it was cast before."""
        if self.traces_kept == 0:
            return self._cast(stage, camera, heading)
        key = hashlib.blake2b(stage.tobytes(), digest_size=16, person=b"fpg-trace")
        key.update(np.asarray(stage.shape, dtype=np.int64).tobytes())
        key.update(np.asarray(camera.position, dtype=np.float64).tobytes())  # where rays start
        digest = key.digest()
        result = self._traces.get(digest)
        if result is None:
            result = self._cast(stage, camera, heading)
            for array in (result.visible, result.blocker, result.hit_point):
                array.flags.writeable = False
            self._traces[digest] = result
            if len(self._traces) > self.traces_kept:
                self._traces.popitem(last=False)
        else:
            self._traces.move_to_end(digest)
        return result

    def _cast(self, stage: np.ndarray, camera: Camera, heading: np.ndarray) -> TraceResult:
        scenario = self.scenario
        count = len(stage)
        if not scenario.occlusion_effects:
            return TraceResult(
                visible=np.ones((count, skeleton.NUM_JOINTS)),
                blocker=np.full((count, skeleton.NUM_JOINTS), -1),
                hit_point=stage.copy(),
            )
        if self._caster is None:
            if not self._owns_caster:
                raise RuntimeError("KinectSimulator: closed (its shared caster is gone)")
            self._caster = RayCaster(rays_per_joint=self.rays_per_joint)
        self._caster.build(stage, scenario.occluders)
        result = self._caster.trace(camera.position, stage, scenario.occluders, heading)
        if not scenario.self_occlusion:  # only the scene boxes may hide joints
            by_box = result.blocker >= 0
            return TraceResult(
                visible=np.where(by_box, result.visible, 1.0),
                blocker=np.where(by_box, result.blocker, -1),
                hit_point=result.hit_point,
            )
        return result

    def simulate(
        self,
        clip: Clip | npt.ArrayLike,
        seed: int | np.random.Generator = 0,
        *,
        fps: float | None = None,
    ) -> Recording:
        """Simulate the Kinect stream of one clip.

        Parameters
        ----------
        clip : Clip or array_like, shape (T, 20, 3)
            Clean joint positions in metres, Y up, in the capture's world.
        seed : int or numpy.random.Generator
            Same seed, same recording.
        fps : float, optional
            Frame rate (default: the clip's, or 30 for an array).

        Returns
        -------
        Recording
            ``positions``/``states`` as the simulated sensor reports them, ``ground_truth`` the
            clip in the same camera space, ``metadata`` with the scenario, seed, camera,
            transform and statistics.

        Raises
        ------
        ValueError
            On a wrong shape, NaN positions, a bad seed or frame rate.
        """
        start_time = time.perf_counter()
        positions, rate, name, source = _as_clip(clip, fps)
        rng, seed_label = _rng(seed)
        scenario = self.scenario
        count = len(positions)
        placement = place(positions, scenario)
        camera = placement.camera
        stage = placement.to_stage(positions)
        truth = placement.to_camera(positions)  # (T, 20, 3) ground truth in camera space
        heading = facing_yaw(stage)
        trace = self._trace(stage, camera, heading)
        in_view = camera.in_view(truth)
        visible = np.where(in_view, trace.visible, 0.0)
        # Partly hidden joints vibrate more; fully hidden ones get the occlusion model instead.
        seen_share = np.where(visible < scenario.occlusion.hidden_below, 1.0, visible)
        noise = scenario.noise.sample(rng, truth, rate, seen_share)
        sensed = truth
        if scenario.sensor_definitions is not None:  # the sensor's joints are not the clip's
            sensed = scenario.sensor_definitions.apply(truth)
        reported = sensed + noise
        states = np.full((count, skeleton.NUM_JOINTS), TRACKED, dtype=np.int8)
        stats: dict[str, Any] = {"out_of_view_share": float(1.0 - in_view.mean())}
        hidden = np.zeros((count, skeleton.NUM_JOINTS), dtype=bool)
        if scenario.occlusion_effects or not in_view.all():
            hidden = (visible < scenario.occlusion.hidden_below) | ~in_view
            hits = camera.world_to_camera(trace.hit_point)
            reported, states, occlusion_stats = occlusion_effects(
                scenario.occlusion,
                rng,
                truth,
                reported,
                hidden,
                np.where(in_view, trace.blocker, -1),
                hits,
            )
            stats.update(occlusion_stats)
        if scenario.left_right_confusion:
            reported, states, swap_stats = _left_right(
                scenario, rng, stage, heading, camera, reported, states
            )
            stats.update(swap_stats)
        seconds = time.perf_counter() - start_time
        stats["ms_per_frame"] = 1000.0 * seconds / count
        metadata: dict[str, Any] = {
            "source": source or name,
            "clip": name,
            "format": "simulated",
            "joint_set": "kinect20",
            "untracked_positions": "simulated",
            "scenario": scenario.name,
            "scenario_parameters": scenario.to_dict(),
            "seed": seed_label,
            "fps": rate,
            "camera": camera.to_dict(),
            "clip_to_camera": {
                "rotation": placement.rotation.tolist(),
                "translation": placement.translation.tolist(),
            },
            "stats": stats,
        }
        return Recording(
            positions=reported.astype(np.float32),
            states=states,
            timestamps=np.arange(count) / rate,
            ground_truth=truth.astype(np.float32),
            metadata=metadata,
            occluded=hidden,
        )


def simulate(
    clip: Clip | npt.ArrayLike,
    scenario: str | Scenario = "front-few",
    seed: int | np.random.Generator = 0,
    *,
    fps: float | None = None,
    rays_per_joint: int = 5,
) -> Recording:
    """Simulate a Kinect recording of ``clip`` in ``scenario`` (see :class:`KinectSimulator`).

    Deterministic: the same clip, scenario and seed give the same recording.

    Raises
    ------
    ValueError
        On an unknown scenario name, a wrong clip shape, NaN positions or a bad seed.
    """
    with KinectSimulator(scenario, rays_per_joint=rays_per_joint) as simulator:
        return simulator.simulate(clip, seed, fps=fps)


def _left_right(
    scenario: Scenario,
    rng: np.random.Generator,
    stage: np.ndarray,
    heading: np.ndarray,
    camera: Camera,
    reported: np.ndarray,
    states: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Swap limbs of side-on bodies, mirror back-facing ones (Shum 2013 §I)."""
    model = scenario.occlusion
    count = len(stage)
    root = stage[:, skeleton.ROOT]
    to_camera = np.arctan2(camera.position[0] - root[:, 0], camera.position[2] - root[:, 2])
    angle = np.degrees(np.abs(np.angle(np.exp(1j * (heading - to_camera)))))  # in [0, 180]
    mirrored = angle > model.mirror_beyond_deg
    hazard = model.swap_rate * np.clip(
        (angle - model.swap_start_deg) / max(90.0 - model.swap_start_deg, 1e-9), 0.0, 1.0
    )
    hazard = np.where(mirrored, 0.0, hazard)
    starts = rng.random(count) < hazard
    lengths = rng.geometric(1.0 / model.swap_mean_frames, size=count)
    limb = rng.random(count) < 0.5  # True: legs, False: arms
    permutation = np.tile(np.arange(skeleton.NUM_JOINTS), (count, 1))
    swap_frames = 0
    remaining, legs = 0, False
    for t in range(count):  # scalar episode bookkeeping only
        if remaining == 0 and starts[t]:
            remaining, legs = int(lengths[t]), bool(limb[t])
        if mirrored[t]:
            permutation[t] = skeleton.MIRROR_PERMUTATION
            remaining = 0
        elif remaining > 0:
            joints = LEG_JOINTS if legs else ARM_JOINTS
            permutation[t, joints] = skeleton.MIRROR_PERMUTATION[joints]
            remaining -= 1
            swap_frames += 1
    frames = np.arange(count)[:, None]
    stats = {
        "swapped_frames": swap_frames,
        "mirrored_frames": int(mirrored.sum()),
        "side_angle_mean_deg": float(angle.mean()),
    }
    return reported[frames, permutation], states[frames, permutation], stats
