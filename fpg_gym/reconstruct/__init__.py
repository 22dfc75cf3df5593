"""The online reconstruction core: reliability, candidate selection, natural posture space,
energy, the per-frame search problem and the :class:`Reconstructor` pipeline.

See :mod:`fpg_gym.reconstruct.reconstructor` for the data flow of one frame and
``../shared/DESIGN.md`` for the equations. Importing the package registers the optimiser
``closed-form`` (:class:`ClosedForm`, which reads the per-frame problem).
"""

from __future__ import annotations

from fpg_gym.reconstruct.bones import BoneSettler, BoneSettlingConfig
from fpg_gym.reconstruct.closed_form import ClosedForm
from fpg_gym.reconstruct.config import ReconstructorConfig
from fpg_gym.reconstruct.energy import (
    ENERGY_DTYPES,
    ENERGY_KERNELS,
    POSE_TERM_NAMES,
    TERM_NAMES,
    EnergyModel,
    EnergyWeights,
    control_energy,
    kinematic_energy,
    motion_energy,
    motion_target,
    pose_energy_terms,
    style_energy,
)
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.left_right import LABELLINGS, left_right_costs
from fpg_gym.reconstruct.problem import FrameContext, SearchProblem
from fpg_gym.reconstruct.reconstructor import Reconstructor
from fpg_gym.reconstruct.records import STAGES, FrameOutput, FrameRecord, ReconstructionResult
from fpg_gym.reconstruct.reliability import (
    ReliabilityConfig,
    ReliabilityEstimator,
    ReliabilityTerms,
    is_neutral_pose,
    reliability_of_sequence,
)
from fpg_gym.reconstruct.selection import (
    BruteForceSelector,
    CandidateSelector,
    GraphSelector,
    NodeDatabase,
    Selection,
    SelectionQuery,
    fpg_score,
    make_selector,
    shum_score,
)
from fpg_gym.reconstruct.temporal import (
    OutputSmoother,
    PlacementSmoother,
    TemporalConfig,
    align_basis,
)

__all__ = [
    "ENERGY_DTYPES",
    "ENERGY_KERNELS",
    "LABELLINGS",
    "POSE_TERM_NAMES",
    "STAGES",
    "TERM_NAMES",
    "BoneSettler",
    "BoneSettlingConfig",
    "BruteForceSelector",
    "CandidateSelector",
    "ClosedForm",
    "EnergyModel",
    "EnergyWeights",
    "FrameContext",
    "FrameOutput",
    "FrameRecord",
    "GraphSelector",
    "LatentSpace",
    "NodeDatabase",
    "OutputSmoother",
    "PlacementSmoother",
    "ReconstructionResult",
    "Reconstructor",
    "ReconstructorConfig",
    "ReliabilityConfig",
    "ReliabilityEstimator",
    "ReliabilityTerms",
    "SearchProblem",
    "Selection",
    "SelectionQuery",
    "TemporalConfig",
    "align_basis",
    "control_energy",
    "fpg_score",
    "is_neutral_pose",
    "kinematic_energy",
    "left_right_costs",
    "make_selector",
    "motion_energy",
    "motion_target",
    "pose_energy_terms",
    "reliability_of_sequence",
    "shum_score",
    "style_energy",
]
