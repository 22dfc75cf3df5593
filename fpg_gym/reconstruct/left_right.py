"""Left/right confusions of a Kinect (not in the papers; used by the reconstructor).

A Kinect assumes that the user faces it: a user seen side-on gets arms or legs swapped for a
while, one seen from behind is reported mirrored (Shum §I). :func:`left_right_costs` scores each
labelling of :data:`LABELLINGS` (as reported, mirrored, arms swapped, legs swapped) against a
prediction; :class:`~fpg_gym.reconstruct.reconstructor.Reconstructor` uses another labelling when
it is clearly closer.
"""

from __future__ import annotations

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.reconstruct.energy import motion_target

__all__ = ["LABELLINGS", "LABEL_PERMUTATIONS", "best_labelling", "left_right_costs"]


def _side_joints(prefixes: tuple[str, ...]) -> np.ndarray:
    return np.array(
        [
            i
            for i, n in enumerate(skeleton.JOINT_NAMES)
            if n.startswith(prefixes) and (skeleton.is_left(i) or skeleton.is_right(i))
        ]
    )


def _swap(joints: np.ndarray) -> np.ndarray:
    permutation = np.arange(skeleton.NUM_JOINTS)
    permutation[joints] = skeleton.MIRROR_PERMUTATION[joints]
    return permutation


LABELLINGS: tuple[str, ...] = ("as-reported", "mirrored", "arms-swapped", "legs-swapped")
"""Left/right labellings the reconstructor considers (see ``left_right_fix``)."""

#: The joint permutation of each labelling of :data:`LABELLINGS` ``(4, 20)``, read-only.
LABEL_PERMUTATIONS = np.stack(
    [
        np.arange(skeleton.NUM_JOINTS),
        np.asarray(skeleton.MIRROR_PERMUTATION),
        _swap(_side_joints(("Shoulder", "Elbow", "Wrist", "Hand"))),
        _swap(_side_joints(("Hip", "Knee", "Ankle", "Foot"))),
    ]
)
LABEL_PERMUTATIONS.flags.writeable = False
_NO_POSE = np.zeros((0, 3))  # no second previous output


def left_right_costs(
    positions: np.ndarray, states: np.ndarray, prediction: np.ndarray
) -> np.ndarray:
    """How far each labelling of :data:`LABELLINGS` puts the sensor joints from a prediction.

    The mean, over joints weighted by tracking state (tracked 1, inferred 0.5, not tracked 0),
    of the distance between the relabelled, root-relative sensor pose and the root-relative
    prediction (camera space). Returns ``(4,)`` metres.
    """
    positions = np.asarray(positions, dtype=np.float64)
    compiled = compiled_module("fpg_gym.reconstruct.compiled_frame")
    if compiled is not None:  # one call; the same costs to rounding
        costs: np.ndarray = compiled.labelling_costs(
            np.ascontiguousarray(positions),
            np.ascontiguousarray(states),
            np.ascontiguousarray(prediction, dtype=np.float64),
            LABEL_PERMUTATIONS,
            skeleton.TRACKED,
            skeleton.INFERRED,
        )
        return costs
    local = positions - positions[skeleton.ROOT]
    target = np.asarray(prediction, dtype=np.float64)
    target = target - target[skeleton.ROOT]
    states = np.asarray(states)
    weights = np.where(
        states >= skeleton.TRACKED, 1.0, np.where(states == skeleton.INFERRED, 0.5, 0.0)
    )
    relabelled = local[LABEL_PERMUTATIONS]  # (H, 20, 3)
    w = weights[LABEL_PERMUTATIONS]  # (H, 20)
    dist = np.linalg.norm(relabelled - target, axis=-1)
    return np.asarray((w * dist).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-9))


def best_labelling(
    compared: np.ndarray,
    states: np.ndarray,
    history: list[tuple[np.ndarray, float]],
    dt: float,
    margin: float,
) -> int:
    """The labelling (an index in :data:`LABELLINGS`) of the sensor pose ``compared`` that
    continues the previous outputs ``history`` (camera-space poses and timestamps, newest
    last; at least one) best, ``dt`` s after the last: another than the reported one (0) only
    when its cost is under ``margin`` times the reported one's and 3 cm lower."""
    last = history[-1][0]
    compiled = compiled_module("fpg_gym.reconstruct.compiled_frame")
    if compiled is not None:  # one call, the same arithmetic
        before = _NO_POSE
        ratio = 1.0
        if len(history) >= 2:
            before = history[-2][0]
            dt_previous = history[-1][1] - history[-2][1]
            ratio = 1.0 if not dt_previous or dt_previous <= 0 else dt / dt_previous  # as
            # motion_target
        choice: int = compiled.best_labelling(
            np.asarray(compared, dtype=np.float64),
            states,
            np.ascontiguousarray(last, dtype=np.float64),
            np.ascontiguousarray(before, dtype=np.float64),
            ratio,
            float(margin),
            LABEL_PERMUTATIONS,
            skeleton.TRACKED,
            skeleton.INFERRED,
        )
        return choice
    guess = last
    if len(history) >= 2:
        before = history[-2][0]
        guess = motion_target(
            last - last[skeleton.ROOT],
            before - before[skeleton.ROOT],
            dt,
            history[-1][1] - history[-2][1],
        )
    costs = left_right_costs(compared, states, guess)
    best = int(np.argmin(costs))
    if best != 0 and costs[best] < margin * costs[0] and costs[0] - costs[best] > 0.03:
        return best
    return 0
