"""A :class:`~fpg_gym.reconstruct.reconstructor.Reconstructor`'s prepared frame (the state between
``prepare`` and ``finish``) and the :class:`~fpg_gym.reconstruct.records.FrameRecord` it becomes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.reconstruct.energy import TERM_NAMES
from fpg_gym.reconstruct.output_correction import OutputCorrection
from fpg_gym.reconstruct.problem import SearchProblem
from fpg_gym.reconstruct.records import FrameRecord
from fpg_gym.reconstruct.reliability import ReliabilityTerms
from fpg_gym.reconstruct.selection import Selection

__all__ = ["Pending", "frame_record", "output_pose"]


@dataclass
class Pending:
    """A reconstructor's state between ``prepare()`` and ``finish()``."""

    problem: SearchProblem
    placement: pose_utils.Placement
    terms: ReliabilityTerms
    selection: Selection
    first: bool
    no_body: bool
    timestamp: float
    ms: dict[str, float]
    prepared_at: float
    labelling: str = "as-reported"
    lengths: np.ndarray | None = None
    sensor: np.ndarray | None = None  # the raw input frame, before the sensor map
    tracked: np.ndarray | None = None  # its tracked joints (for the online calibration)
    found: np.ndarray | None = None  # the best point of search(), if one ran
    sensor_states: np.ndarray | None = None  # the raw input's tracking states
    correction: OutputCorrection | None = None  # the searching optimiser's, if it has one
    trust: np.ndarray | None = None  # the fusion's trust in each (relabelled) sensor joint
    labelling_index: int = 0  # the labelling's index in LABELLINGS (LABEL_PERMUTATIONS')
    output_sensor: np.ndarray | None = None  # the sensor in the output's definitions, if mapped


def output_pose(
    local: np.ndarray, lengths: np.ndarray, placement: pose_utils.Placement
) -> np.ndarray:
    """A frame's output ``(20, 3)`` float32 in camera space from its normalised pose ``local``
    ``(20, 3)`` float64: given the bone ``lengths`` ``(19,)`` (:func:`~fpg_gym.core.poses.retarget`)
    and put back at ``placement`` (:func:`~fpg_gym.core.poses.denormalise`); one compiled call
    with numba (the same operations)."""
    compiled = compiled_module("fpg_gym.reconstruct.compiled_frame")
    root, yaw = placement.root, placement.yaw
    if compiled is not None and np.shape(root) == (3,) and not np.ndim(yaw):
        pose: np.ndarray = compiled.finish_pose(
            np.ascontiguousarray(local, dtype=np.float64),
            np.asarray(lengths, dtype=np.float64),
            np.asarray(root, dtype=np.float64),
            float(yaw),
            skeleton.BONES,
            pose_utils.REST_DIRECTIONS,
        )
        return pose
    return pose_utils.denormalise(pose_utils.retarget(local, lengths), placement)


def frame_record(
    index: int,
    pending: Pending,
    chosen: dict[str, np.ndarray],
    ms: dict[str, float],
    ragdoll_info: dict[str, Any] | None,
) -> FrameRecord:
    """What happened in the finished frame ``index`` (``chosen``: the terms of z and of x0)."""
    terms = pending.terms
    selection = pending.selection
    problem = pending.problem
    return FrameRecord(
        index=index,
        timestamp=pending.timestamp,
        reliability=terms.reliability,
        behaviour=terms.behaviour,
        kinematic=terms.kinematic,
        tracking=terms.tracking,
        reference_source=terms.reference_source,
        nodes=selection.nodes,
        node_scores=selection.scores,
        num_scored=selection.num_scored,
        full_search=selection.full_search,
        recovered=selection.recovered,
        first=pending.first,
        no_body=pending.no_body,
        energy=chosen["E"].item(0),
        energy_x0=chosen["E"].item(1),
        terms={name: chosen[name].item(0) for name in TERM_NAMES},
        evaluations=problem.evaluations,
        ms=ms,
        ragdoll=ragdoll_info,
        labelling=pending.labelling,
        bone_lengths=pending.lengths,
    )
