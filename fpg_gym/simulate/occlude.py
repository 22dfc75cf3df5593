"""Occlusions put into real sensor streams: the occlusion benchmark on real people.

A real stream with independent ground truth (UI-PRMD's Kinect v2 against Vicon) has no
occlusion; this module hides parts of the body in it. Joints that stay visible keep the real
sensor's report, noise and definitions untouched; hidden joints report what a Kinect reports
for joints it cannot see, by the simulator's :class:`~fpg_gym.simulate.models.OcclusionModel`
(:func:`~fpg_gym.simulate.hidden_joints.occlusion_effects`) run on the real stream: a hidden joint's
bone (from its parent) freezes, swings or collapses and drifts, the hidden joints of a chain move
together, a joint hidden by a nearby surface may snap onto it and stay *tracked*, long
occlusions may end as *not tracked*. The base parameters are those measured on the real
occluded Kinect v2 stream ``kinect_v2_states/joints.csv``
(:data:`~fpg_gym.simulate.scenarios.KINECT_V2_OCCLUSION`: hidden joints reported inferred and
calm, seen joints flickering to inferred now and then); each case changes only what defines it.

Cases (:data:`OCCLUSION_CASES`), one occluder per episode:

``forearm``
    One forearm behind an object (wrist and hand, the elbow in half the episodes) for 1-2 s
    from 0.5-1 s into the stream: inferred, drifting away from the real arm.
``legs``
    The lower legs (knees, ankles, feet) behind furniture from the first half second to the
    end: inferred, then *not tracked* after at most 10 frames.
``hand-on-surface``
    One hand and wrist hidden by a surface they touch for 1-2 s: they snap onto the surface
    where the hand was when it disappeared (5 cm towards the camera) and stay reported
    *tracked* there: a false positive.
``side-turn``
    The body turns side-on for 0.5-1.5 s and the sensor swaps the left and right arms or legs
    (tracked, wrong labels; Shum 2013 §I).

:func:`occlude` returns the stream with the case's errors, its ground truth unchanged and
:attr:`~fpg_gym.io.recording.Recording.occluded` marking the joints hidden (or mislabelled) in
each frame, so scores can split occluded and visible joints. Same seed, same occlusion.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.io.recording import Recording
from fpg_gym.simulate.hidden_joints import occlusion_effects
from fpg_gym.simulate.models import OcclusionModel
from fpg_gym.simulate.scenarios import KINECT_V2_OCCLUSION
from fpg_gym.simulate.simulator import ARM_JOINTS, LEG_JOINTS

__all__ = [
    "OCCLUSION_CASES",
    "OcclusionCase",
    "check_occlusion_cases",
    "occlude",
    "occlusion_case_names",
]

_J = skeleton.joint_index


@dataclass(frozen=True)
class OcclusionCase:
    """One kind of occlusion put into a real stream (see the module docstring).

    Attributes
    ----------
    name, description : str
    joints : tuple of str
        The hidden joints, ``{side}`` standing for ``Left`` or ``Right`` (drawn per episode).
    optional_joints : tuple of str
        Joints hidden too in half the episodes (same ``{side}``).
    start_s : tuple of 2 floats
        Range of the occlusion's start, seconds after the stream's first frame.
    duration_s : tuple of 2 floats, optional
        Range of its length, seconds; None: to the end of the stream.
    occlusion : OcclusionModel
        What hidden joints report.
    surface : bool
        Hidden joints snap onto a surface where they were when hidden (reported tracked).
    swap : bool
        Instead of hiding joints, swap the labels of the left and right arms or legs.
    """

    name: str
    description: str
    joints: tuple[str, ...] = ()
    optional_joints: tuple[str, ...] = ()
    start_s: tuple[float, float] = (0.5, 1.0)
    duration_s: tuple[float, float] | None = (1.0, 2.0)
    occlusion: OcclusionModel = field(default_factory=lambda: KINECT_V2_OCCLUSION)
    surface: bool = False
    swap: bool = False

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly description."""
        return {
            "name": self.name,
            "description": self.description,
            "joints": list(self.joints),
            "optional_joints": list(self.optional_joints),
            "start_s": list(self.start_s),
            "duration_s": None if self.duration_s is None else list(self.duration_s),
            "surface": self.surface,
            "swap": self.swap,
            "occlusion": self.occlusion.to_dict(),
        }


#: Every occlusion case, by name.
OCCLUSION_CASES: dict[str, OcclusionCase] = {
    case.name: case
    for case in (
        OcclusionCase(
            "forearm",
            "a forearm behind an object: inferred, drifting",
            joints=("Wrist{side}", "Hand{side}"),
            optional_joints=("Elbow{side}",),
        ),
        OcclusionCase(
            "legs",
            "the lower legs behind furniture: inferred, then not tracked",
            joints=(
                "KneeLeft",
                "AnkleLeft",
                "FootLeft",
                "KneeRight",
                "AnkleRight",
                "FootRight",
            ),
            start_s=(0.0, 0.5),
            duration_s=None,
            occlusion=replace(
                KINECT_V2_OCCLUSION, not_tracked_probability=1.0, not_tracked_after=(0, 10)
            ),
        ),
        OcclusionCase(
            "hand-on-surface",
            "a hand on a surface: snapped onto it, still reported tracked",
            joints=("Wrist{side}", "Hand{side}"),
            occlusion=replace(KINECT_V2_OCCLUSION, snap_probability=1.0),
            surface=True,
        ),
        OcclusionCase(
            "side-turn",
            "a side-on turn: the left and right arms or legs swapped",
            start_s=(0.5, 1.0),
            duration_s=(0.5, 1.5),
            swap=True,
        ),
    )
}

#: How far towards the camera (metres) a surface holds a snapped joint.
SURFACE_OFFSET_M = 0.05


def occlusion_case_names() -> tuple[str, ...]:
    """Names of :data:`OCCLUSION_CASES`."""
    return tuple(OCCLUSION_CASES)


def check_occlusion_cases(cases: Sequence[str]) -> None:
    """Refuse a name that is not one of :data:`OCCLUSION_CASES`.

    Raises
    ------
    ValueError
        Naming the unknown cases and the known ones.
    """
    unknown = sorted(set(cases) - set(OCCLUSION_CASES))
    if unknown:
        raise ValueError(
            f"occlusions: unknown case(s) {', '.join(unknown)}; expected some of "
            f"{', '.join(OCCLUSION_CASES)}"
        )


def _case(case: str | OcclusionCase) -> OcclusionCase:
    if isinstance(case, OcclusionCase):
        return case
    try:
        return OCCLUSION_CASES[case]
    except KeyError:
        raise ValueError(
            f"occlusion case: unknown {case!r}; expected one of {', '.join(OCCLUSION_CASES)}"
        ) from None


def _interval(case: OcclusionCase, rng: np.random.Generator, times: np.ndarray) -> tuple[int, int]:
    """First and one-past-last frame of the occlusion."""
    start = times[0] + rng.uniform(*case.start_s)
    end = np.inf if case.duration_s is None else start + rng.uniform(*case.duration_s)
    frames = np.flatnonzero((times >= start) & (times < end))
    if len(frames) == 0:  # a stream shorter than the start: occlude its last frame
        return len(times) - 1, len(times)
    return int(frames[0]), int(frames[-1]) + 1


def occlude(
    recording: Recording, case: str | OcclusionCase, seed: int | np.random.Generator = 0
) -> Recording:
    """The stream with one occlusion of ``case`` put into it.

    Parameters
    ----------
    recording : Recording
        A real stream (its ground truth, if any, is kept unchanged).
    case : str or OcclusionCase
        A name of :data:`OCCLUSION_CASES` or a case.
    seed : int or numpy.random.Generator
        Same seed, same occlusion.

    Returns
    -------
    Recording
        With the hidden joints' reports and states changed, ``occluded`` set and
        ``metadata["occlusion"]`` describing the episode.

    Raises
    ------
    ValueError
        On an unknown case name.
    """
    case = _case(case)
    rng = np.random.default_rng(seed)
    first, last = _interval(case, rng, recording.timestamps)
    side = "Left" if rng.random() < 0.5 else "Right"
    count = recording.num_frames
    sensor = recording.positions.astype(np.float64)
    positions, states = sensor.copy(), recording.states.copy()
    occluded = np.zeros((count, skeleton.NUM_JOINTS), dtype=bool)
    stats: dict[str, Any] = {}
    if case.swap:
        joints = LEG_JOINTS if rng.random() < 0.5 else ARM_JOINTS
        permutation = np.arange(skeleton.NUM_JOINTS)
        permutation[joints] = skeleton.MIRROR_PERMUTATION[joints]
        positions[first:last] = sensor[first:last, permutation]
        states[first:last] = recording.states[first:last, permutation]
        occluded[first:last, joints] = True
        names = [skeleton.JOINT_NAMES[j] for j in joints]
    else:
        names = [name.format(side=side) for name in case.joints]
        if case.optional_joints and rng.random() < 0.5:
            names += [name.format(side=side) for name in case.optional_joints]
        joints = np.array([_J(name) for name in names])
        occluded[first:last, joints] = True
        blocker = np.where(occluded, 0 if case.surface else -2, -1)
        hits = sensor.copy()
        if case.surface:  # the surface holds each joint where it disappeared
            held = sensor[first, joints]
            towards_camera = -held / np.linalg.norm(held, axis=-1, keepdims=True)
            hits[first:last, joints] = held + SURFACE_OFFSET_M * towards_camera
        # Seen joints keep the real report (the model's flicker of their state is the real
        # Kinect v2's; its recovery tail after an occlusion is left out so that the mask is exact).
        positions, model_states, stats = occlusion_effects(
            case.occlusion, rng, sensor, sensor, occluded, blocker, hits
        )
        positions = np.where(occluded[..., None], positions, sensor)
        states = np.where(
            occluded | (model_states == skeleton.INFERRED), model_states, recording.states
        ).astype(np.int8)
    metadata = {
        **recording.metadata,
        "occlusion": {
            "case": case.name,
            "joints": names,
            "start_s": float(recording.timestamps[first] - recording.timestamps[0]),
            "end_s": float(recording.timestamps[last - 1] - recording.timestamps[0]),
            "frames": int(last - first),
            "stats": stats,
        },
    }
    return Recording(
        positions=positions.astype(np.float32),
        states=states,
        timestamps=recording.timestamps,
        ground_truth=recording.ground_truth,
        metadata=metadata,
        occluded=occluded,
    )
