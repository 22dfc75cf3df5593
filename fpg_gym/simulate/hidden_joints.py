"""What an occlusion does to the joints it hides (the simulator's occlusion model).

:func:`occlusion_effects` turns which joints are hidden, by what, and where a snapping joint
lands into the reported stream and tracking states of :class:`~fpg_gym.simulate.models.
OcclusionModel`: frozen, swung or collapsed bones with drift and glitches, snapped joints,
flickering and calm inferred joints. The simulator runs it on the ray casts of its scenes;
:func:`fpg_gym.simulate.occlude.occlude` runs it on a real stream.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.rotations import axis_angle_matrix, cross_product
from fpg_gym.core.skeleton import INFERRED, NOT_TRACKED, TRACKED
from fpg_gym.simulate.models import JOINT_GROUP, OcclusionModel

__all__ = ["occlusion_effects"]

_FREEZE, _SWING, _COLLAPSE, _SNAP = 0, 1, 2, 3
_LIMB = np.array([group != "core" for group in JOINT_GROUP])

_LEVELS = skeleton.JOINT_LEVELS
#: Each joint's parent (the root its own).
_PARENT = np.where(skeleton.PARENTS >= 0, skeleton.PARENTS, np.arange(skeleton.NUM_JOINTS))


@dataclass(frozen=True)
class _OcclusionDraws:
    """The random draws of :func:`occlusion_effects`, all made up front, in one order (same
    seed, same stream; no per-frame generator calls)."""

    u_mode: np.ndarray
    u_snap: np.ndarray
    shrink_draw: np.ndarray
    angle_draw: np.ndarray
    axis_draw: np.ndarray
    u_not_tracked: np.ndarray
    after_draw: np.ndarray
    kicks: np.ndarray
    glitch: np.ndarray
    glitch_axis: np.ndarray
    glitch_angle: np.ndarray
    vibration: np.ndarray
    flicker: np.ndarray | None

    @classmethod
    def make(
        cls, model: OcclusionModel, rng: np.random.Generator, count: int, joints: int
    ) -> _OcclusionDraws:
        """Draw them for ``count`` frames of ``joints`` joints."""
        u_mode = rng.random((count, joints))
        u_snap = rng.random((count, joints))
        shrink_draw = rng.uniform(*model.collapse_shrink, size=(count, joints))
        angle_draw = np.radians(rng.uniform(*model.swing_deg, size=(count, joints)))
        axis_draw = rng.normal(size=(count, joints, 3))
        u_not_tracked = rng.random((count, joints))
        after_draw = rng.integers(
            model.not_tracked_after[0], model.not_tracked_after[1] + 1, size=(count, joints)
        )
        kicks = rng.normal(size=(count, joints, 3)) * model.drift_sigma
        # Limb joints glitch (their bone turns); torso, head, shoulders and hips are held still.
        glitch = (rng.random((count, joints)) < model.glitch_probability) & _LIMB
        glitch_axis = rng.normal(size=(count, joints, 3))
        glitch_angle = np.radians(rng.normal(size=(count, joints)) * model.glitch_deg)
        vibration = rng.normal(size=(count, joints, 3)) * model.inferred_sigma
        flicker = _flicker(rng, model, count, joints) if model.flicker_rate > 0 else None
        return cls(
            u_mode=u_mode,
            u_snap=u_snap,
            shrink_draw=shrink_draw,
            angle_draw=angle_draw,
            axis_draw=axis_draw,
            u_not_tracked=u_not_tracked,
            after_draw=after_draw,
            kicks=kicks,
            glitch=glitch,
            glitch_axis=glitch_axis,
            glitch_angle=glitch_angle,
            vibration=vibration,
            flicker=flicker,
        )


#: A joint's not-tracked limit that never comes (frames).
_NEVER = np.iinfo(np.intp).max


def _hidden_episodes(hidden: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame and joint ``(T, J)``: whether a hidden episode begins, how many frames it has
    been hidden (0 when seen) and the frame its latest hidden episode began (-1 before any)."""
    frame = np.arange(len(hidden))[:, None]
    before = np.zeros_like(hidden)
    before[1:] = hidden[:-1]
    begin = hidden & ~before
    last_seen = np.maximum.accumulate(np.where(hidden, -1, frame), axis=0)
    run = np.where(hidden, frame - last_seen, 0)
    began = np.maximum.accumulate(np.where(begin, frame, -1), axis=0)
    return begin, run, began


def _unit_axes(axes: np.ndarray) -> np.ndarray:
    """Rows of ``axes`` ``(N, 3)`` scaled to unit length (+Z for a zero row)."""
    norm = np.linalg.norm(axes, axis=-1, keepdims=True)
    return np.where(norm > 1e-9, axes / np.maximum(norm, 1e-9), (0.0, 0.0, 1.0))


def _glitch(bone_rep: np.ndarray, draws: _OcclusionDraws, t: int, jumps: np.ndarray) -> None:
    """Turn, in place, the reported bones of the hidden limb joints ``jumps`` that glitch at
    ``t``."""
    axis = _unit_axes(cross_product(bone_rep[jumps], draws.glitch_axis[t, jumps]))
    turned = np.einsum(
        "jab,jb->ja", axis_angle_matrix(axis, draws.glitch_angle[t, jumps]), bone_rep[jumps]
    )
    bone_rep[jumps] = turned


def _propagate(
    model: OcclusionModel,
    excess: np.ndarray,
    own: np.ndarray | None,
    h: np.ndarray,
    kick: np.ndarray,
    levels: list[np.ndarray],
) -> np.ndarray:
    """Each joint's occlusion error after this frame: a hidden joint's is its parent's plus its
    own bone error (``own``), a seen joint's decays; a hidden root drifts on its own.
    ``levels`` holds, for each level of the skeleton with a hidden joint in root-to-leaf order,
    ``(20, 1)`` the hidden joints of that level (``own`` may be None without one). ``excess`` is
    updated in place and returned."""
    root = (1.0 - model.approach_rate) * excess[0] + kick if h[0] else None  # like a bone
    excess *= model.recovery  # decayed
    if root is not None:
        excess[0] = root
    for hidden_here in levels:  # a level's joints follow their parents, updated before them
        excess = np.where(hidden_here, excess[_PARENT] + own, excess)
    return excess


def occlusion_effects(
    model: OcclusionModel,
    rng: np.random.Generator,
    truth: np.ndarray,
    reported: np.ndarray,
    hidden: np.ndarray,
    blocker: np.ndarray,
    hits: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Apply :class:`OcclusionModel` to hidden joints (camera space throughout).

    Each hidden joint's reported bone (vector from its parent) follows a target drawn per
    hidden episode (frozen, swung or collapsed bone) with drift and glitches; its error is its
    parent's error plus its own bone error, so hidden chains move together while seen joints
    stay where the sensor sees them. What each hidden episode does (its mode, swing, collapse,
    when it turns not tracked) and the reported states are found for every frame at once; only
    the reported bones and errors, which follow the previous frame's, go frame by frame.

    Parameters
    ----------
    model : OcclusionModel
    rng : numpy.random.Generator
    truth : ndarray, shape (T, 20, 3)
        The body whose bones the hidden joints' reports start from (the true pose in the
        simulator; the sensor's own stream when occlusions are put into a real one).
    reported : ndarray, shape (T, 20, 3)
        What the sensor reports of seen joints.
    hidden : ndarray of bool, shape (T, 20)
    blocker : ndarray of int, shape (T, 20)
        The scene object hiding each joint (-1: none, -2: the body itself).
    hits : ndarray, shape (T, 20, 3)
        Where a snapping joint lands (the occluder's surface).
    """
    count, joints = hidden.shape
    draws = _OcclusionDraws.make(model, rng, count, joints)
    parent = np.where(skeleton.PARENTS >= 0, skeleton.PARENTS, np.arange(joints))
    bones = truth - truth[:, parent]  # (T, 20, 3): joint minus parent, zero for the root
    near = np.linalg.norm(hits - truth, axis=-1) < model.snap_max_distance
    can_snap = (blocker >= 0) & near
    lost = (~hidden).sum(axis=1) < model.min_visible_joints

    episodes = _HiddenEpisodes.draw(model, draws, bones, hidden, can_snap)
    states, calm = _reported_states(model, draws, hidden, episodes, lost)
    snap_here = hidden & episodes.snapped & (blocker >= 0)
    out = _follow_hidden(
        model, draws, truth, reported, bones, hidden, episodes, snap_here, calm, lost, hits
    )
    stats = {
        "hidden_share": float(hidden.mean()),
        "snapped_share": int(np.count_nonzero(snap_here)) / hidden.size,
        "lost_frames": int(lost.sum()),
    }
    return out, states, stats


@dataclass(frozen=True)
class _HiddenEpisodes:
    """What each hidden episode of each joint does, at every frame (T, 20) of the stream: where
    episodes begin, how long the current one has run, its mode and not-tracked limit, and the
    bone a hidden joint heads for (``aim``; a frozen one's is the bone it froze at)."""

    begin: np.ndarray
    run: np.ndarray
    mode: np.ndarray
    limit: np.ndarray
    aim: np.ndarray

    @property
    def freeze(self) -> np.ndarray:
        return self.mode == _FREEZE

    @property
    def snapped(self) -> np.ndarray:
        return self.mode == _SNAP

    @classmethod
    def draw(
        cls,
        model: OcclusionModel,
        draws: _OcclusionDraws,
        bones: np.ndarray,
        hidden: np.ndarray,
        can_snap: np.ndarray,
    ) -> _HiddenEpisodes:
        """Each hidden episode, drawn at the frame it begins and kept while it lasts."""
        count, joints = hidden.shape
        begin, run, began = _hidden_episodes(hidden)
        u = draws.u_mode
        modes = np.where(
            can_snap & (draws.u_snap < model.snap_probability),
            _SNAP,
            np.where(
                u < model.freeze_probability,
                _FREEZE,
                np.where(u < model.freeze_probability + model.swing_probability, _SWING, _COLLAPSE),
            ),
        )
        limits = np.where(
            draws.u_not_tracked < model.not_tracked_probability, draws.after_draw, _NEVER
        )
        turns = np.tile(np.eye(3), (count, joints, 1, 1))
        starts = np.nonzero(begin)
        axes = _unit_axes(cross_product(bones[starts], draws.axis_draw[starts]))
        turns[starts] = axis_angle_matrix(axes, draws.angle_draw[starts])
        episode = (np.maximum(began, 0), np.arange(joints))
        mode, limit = modes[episode], limits[episode]
        swung = np.einsum("tjab,tjb->tja", turns[episode], bones)
        aim = np.where(
            (mode == _SWING)[..., None], swung, draws.shrink_draw[episode][..., None] * bones
        )
        return cls(begin, run, mode, limit, aim)


def _reported_states(
    model: OcclusionModel,
    draws: _OcclusionDraws,
    hidden: np.ndarray,
    episodes: _HiddenEpisodes,
    lost: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The reported states (T, 20) of every frame, and which inferred joints move calmly."""
    count, joints = hidden.shape
    snapped = episodes.snapped
    states = np.where(
        hidden,
        np.where(snapped, TRACKED, np.where(episodes.run > episodes.limit, NOT_TRACKED, INFERRED)),
        TRACKED,
    ).astype(np.int8)
    if draws.flicker is not None:  # a seen joint reported inferred for a few frames
        states = np.where(draws.flicker & ~hidden, INFERRED, states).astype(np.int8)
    calm = np.zeros((count, joints), dtype=bool)
    if model.inferred_calm > 0:  # inferred joints move calmly (smoothed)
        calm[1:] = (states[1:] == INFERRED) & np.where(
            lost[:-1, None], False, states[:-1] == INFERRED
        )
    states[lost] = NOT_TRACKED
    return states, calm


def _follow_hidden(
    model: OcclusionModel,
    draws: _OcclusionDraws,
    truth: np.ndarray,
    reported: np.ndarray,
    bones: np.ndarray,
    hidden: np.ndarray,
    episodes: _HiddenEpisodes,
    snap_here: np.ndarray,
    calm: np.ndarray,
    lost: np.ndarray,
    hits: np.ndarray,
) -> np.ndarray:
    """The reported stream, frame by frame: each hidden joint's bone approaches its episode's
    aim from the previous frame's, and its error is its parent's error plus its own."""
    count, joints = hidden.shape
    parent = np.where(skeleton.PARENTS >= 0, skeleton.PARENTS, np.arange(joints))
    begin, freeze, aim = episodes.begin, episodes.freeze, episodes.aim
    shake = np.where((hidden & ~episodes.snapped)[..., None], draws.vibration, 0.0)
    glitches = draws.glitch & hidden
    out = np.empty_like(reported)
    excess = np.zeros((joints, 3))  # occlusion error on top of the sensor noise
    bone_rep = np.zeros((joints, 3))  # reported bones of hidden joints
    frozen = np.zeros((joints, 3))
    begins, glitching, calming, snapping = (
        np.asarray(m.any(axis=1)) for m in (begin, glitches, calm, snap_here)
    )
    # The hidden joints of each level of the skeleton that has one, every frame at once.
    level_joints = np.zeros((len(_LEVELS), joints, 1), dtype=bool)
    for index, level in enumerate(_LEVELS):
        level_joints[index, level] = True
    by_level = hidden[:, None, :, None] & level_joints  # (T, levels, 20, 1)
    active: list[list[bool]] = np.asarray(by_level.any(axis=(2, 3))).tolist()
    any_hidden: list[bool] = np.asarray(hidden.any(axis=1)).tolist()
    hidden_rows, begin_rows, freeze_rows = hidden[..., None], begin[..., None], freeze[..., None]
    for t in range(count):
        h = hidden[t]
        bone_t = bones[t]
        if not any_hidden[t]:  # every joint seen: the reported bones are the true ones
            bone_rep = bone_t
            excess = _propagate(model, excess, None, h, draws.kicks[t, 0], [])
        else:
            if begins[t]:
                previous = out[t - 1] - out[t - 1, parent] if t > 0 else bone_t
                bone_rep = np.where(begin_rows[t], previous, bone_rep)
                frozen = np.where(begin_rows[t], previous, frozen)
            target = np.where(freeze_rows[t], frozen, aim[t])
            bone_rep = np.where(
                hidden_rows[t],
                bone_rep + model.approach_rate * (target - bone_rep) + draws.kicks[t],
                bone_t,
            )
            if glitching[t]:
                _glitch(bone_rep, draws, t, glitches[t])
            levels = [by_level[t, i] for i, here in enumerate(active[t]) if here]
            excess = _propagate(model, excess, bone_rep - bone_t, h, draws.kicks[t, 0], levels)
        if snapping[t]:
            excess = np.where(snap_here[t, :, None], hits[t] - truth[t], excess)
        row = reported[t] + excess + shake[t]
        if calming[t]:
            row = np.where(
                calm[t, :, None],
                model.inferred_calm * out[t - 1] + (1.0 - model.inferred_calm) * row,
                row,
            )
        out[t] = out[t - 1] if lost[t] and t > 0 else row
    return out


def _flicker(
    rng: np.random.Generator, model: OcclusionModel, count: int, joints: int
) -> np.ndarray:
    """``(T, J)`` bool: runs of frames a seen joint is reported inferred (starts at
    ``flicker_rate`` per frame, geometric lengths of mean ``flicker_mean_frames``)."""
    starts = rng.random((count, joints)) < model.flicker_rate
    lengths = rng.geometric(1.0 / model.flicker_mean_frames, size=(count, joints))
    frame = np.arange(count)[:, None]
    ends = np.where(starts, frame + lengths, -1)  # first frame after each run
    return frame < np.maximum.accumulate(ends, axis=0)
