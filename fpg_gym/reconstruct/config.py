"""The reconstructor's settings (:class:`ReconstructorConfig`) and what it needs of a ragdoll
(:class:`RagdollLike`, made by an injected :data:`RagdollFactory`: this layer imports no physics).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.validation import check_choice, check_integer, check_number
from fpg_gym.definitions import PoseMap
from fpg_gym.reconstruct.bones import BoneSettlingConfig
from fpg_gym.reconstruct.energy import ENERGY_DTYPES, ENERGY_KERNELS, EnergyWeights
from fpg_gym.reconstruct.fusion import BoneModel, FusionConfig
from fpg_gym.reconstruct.reliability import ReliabilityConfig
from fpg_gym.reconstruct.temporal import TemporalConfig

__all__ = ["RagdollFactory", "RagdollLike", "ReconstructorConfig"]


class RagdollLike(Protocol):
    """What the reconstructor needs of a ragdoll (:class:`fpg_gym.physics.ragdoll.Ragdoll`,
    injected by a factory: this layer imports no physics)."""

    def reset(self, pose: np.ndarray) -> np.ndarray:
        """Place the body on ``pose``."""
        ...

    def track(self, target_pose: np.ndarray) -> np.ndarray:
        """Advance one frame toward ``target_pose``; return the simulated pose."""
        ...

    def close(self) -> None:
        """Release the simulation."""
        ...


RagdollFactory = Callable[[np.ndarray], RagdollLike]


@dataclass(frozen=True)
class ReconstructorConfig:
    """Settings of the pipeline (defaults from the papers where they give one).

    Attributes
    ----------
    k : int
        Candidates per frame (30, both papers).
    latent_dim : int
        Most latent dimensions; ``d = min(latent_dim, K - 1)`` (20).
    selector : {"graph", "brute-force", "auto"}
        FPG's graph search, Shum's brute force (Eq. 9), or "auto": the graph walk or a full
        search with FPG's score, whichever is estimated cheaper each frame
        (:class:`~fpg_gym.reconstruct.selection.GraphSelector`).
    brute_force_score : {"shum", "fpg"}
        Score of the brute-force selector (Eq. 9, or FPG's S over all nodes).
    weights : EnergyWeights
        ``Ec, Es, Ek, Em`` weights (1.0, 0.5, 1.5, 0.25).
    max_evaluations : int or None
        Evaluation budget per frame (2,000).
    time_budget_s : float or None
        Search time budget per frame, from its first evaluation (None).
    recovery_factor, recovery_min_score : float or None, float
        Graph selector's recovery rule (see :mod:`fpg_gym.reconstruct.selection`).
    reliability : ReliabilityConfig
    reference_lengths : tuple of 19 floats, optional
        The user's bone lengths, when known; estimated from the stream otherwise.
    retarget_candidates : bool
        Give the candidates the user's bone lengths before comparing (True).
    max_gap_s : float
        A longer gap between timestamps restarts the stream (0.5 s).
    frame_dt : float
        Frame interval assumed on a first frame or without timestamps (1/30 s).
    ragdoll_rebuild_m : float
        Rebuild the ragdoll when a reference bone length moved by more than this (0.02 m).
    energy_dtype : {"float32", "float64"}
        Arithmetic precision of the energy the search compares (float32; see
        :class:`EnergyModel`): the same accuracy as float64 on held-out UI-PRMD and simulated
        streams, a faster search (docs/performance.md).
    energy_kernel : {"auto", "numba", "numpy", "direct"}
        The search's energy kernel (:mod:`fpg_gym.reconstruct.kernels`; ``"auto"``: compiled
        when ``fpg-gym[fast]`` is installed); ``"direct"`` evaluates the terms' definitions on
        decoded poses (the slow reference, for benchmarks).
    length_prior : {"database", "default"}
        Proportions of the bone-length fallback before calibration: the database's median
        bone lengths or :data:`fpg_gym.core.poses.DEFAULT_BONE_LENGTHS` (see
        :mod:`fpg_gym.reconstruct.reliability`).
    left_right_fix : bool
        Undo the sensor's left/right label confusions by continuity (True; not in the papers,
        see the module docstring).
    left_right_margin : float
        A relabelling is used only when it brings the sensor at least this factor closer to
        the prediction than the reported labels (0.6), and by more than 3 cm.
    temporal : TemporalConfig
        Temporal coherence beyond the papers: smoothed placement, aligned latent basis,
        optional output filter (:mod:`fpg_gym.reconstruct.temporal`; ``TemporalConfig.off()``
        is the papers' pipeline).
    bones : BoneSettlingConfig
        Settling rule of the user's bone lengths (:mod:`fpg_gym.reconstruct.bones`).
    sensor_map : PoseMap, optional
        Maps the sensor's joint definitions onto the database's
        (:class:`fpg_gym.definitions.DefinitionMap`); applied to every input frame before
        anything else, so reliability, selection, energy and bone lengths all work in the
        database's definitions. None: the sensor's points are taken as the database's.
    output_map : PoseMap, optional
        Maps the database's definitions onto the definitions the output is wanted in (e.g.
        marker-based joint centres); applied to the returned pose only (the history that
        drives continuity stays in the database's definitions). A mapped output gets settled
        bone lengths of its own after the first ``bones.settle_s`` seconds.
    sensor_blend : float
        Beyond the papers (0 = off, the papers' pipeline): after the search, each joint of the
        back-projected pose moves this fraction of the way towards the (mapped) sensor joint,
        scaled by the joint's reliability ``R(j)`` — the minimiser of ``Ec`` without the
        posture-space constraint for a fully trusted joint — before retargeting to the user's
        bone lengths. The posture space of K database poses cannot represent a pose the
        database lacks; reliable sensor evidence can.
    calibrate_output : bool
        Beyond the papers (off by default): instead of a fixed ``output_map``, fit the map from
        the database's definitions to the sensor's while the stream runs, from this user's
        tracked joints
        (:class:`fpg_gym.reconstruct.output_calibration.OnlineDefinitionFit`: a running mean
        of the output-to-sensor residual in each joint's frame), and apply it to the returned
        pose. Needs no paired data; the output comes in the sensor's definitions, or in those
        of ``calibration_map``.
    calibration_map : PoseMap, optional
        With ``calibrate_output``: maps the raw sensor onto the definitions wanted in the
        output (e.g. Kinect v2 -> Vicon joint centres); None: the sensor's own.
    fusion : FusionConfig
        Beyond the papers (off by default): the output keeps the mapped, filtered sensor's
        joints where the sensor is trusted and the reconstruction where it is not
        (:mod:`fpg_gym.reconstruct.fusion`); the trust also scales ``R`` (selection, energy,
        sensor blend) and picks the joints the output calibration learns from.
    bone_model : BoneModel, optional
        With ``fusion``: the sensor's bone vectors in the output's definitions (e.g. a learned
        correction of the sensor's bias), in place of the mapped sensor's own.
    """

    k: int = 30
    latent_dim: int = 20
    selector: str = "graph"
    brute_force_score: str = "shum"
    weights: EnergyWeights = field(default_factory=EnergyWeights)
    max_evaluations: int | None = 2000
    time_budget_s: float | None = None
    recovery_factor: float | None = 3.0
    recovery_min_score: float = 0.05
    reliability: ReliabilityConfig = field(default_factory=ReliabilityConfig)
    reference_lengths: tuple[float, ...] | None = None
    retarget_candidates: bool = True
    max_gap_s: float = 0.5
    frame_dt: float = 1.0 / 30.0
    ragdoll_rebuild_m: float = 0.02
    energy_dtype: str = "float32"
    energy_kernel: str = "auto"
    left_right_fix: bool = True
    length_prior: str = "database"
    left_right_margin: float = 0.6
    temporal: TemporalConfig = field(default_factory=TemporalConfig)
    bones: BoneSettlingConfig = field(default_factory=BoneSettlingConfig)
    sensor_map: PoseMap | None = None
    output_map: PoseMap | None = None
    sensor_blend: float = 0.0
    calibrate_output: bool = False
    calibration_map: PoseMap | None = None
    fusion: FusionConfig = field(default_factory=FusionConfig)
    bone_model: BoneModel | None = None

    def __post_init__(self) -> None:
        check_integer(self.k, "k", low=1)
        check_integer(self.latent_dim, "latent_dim", low=0)
        check_number(self.sensor_blend, "sensor_blend", low=0.0, high=1.0)
        check_number(self.max_gap_s, "max_gap_s", low=0.0, low_open=True)
        check_number(self.frame_dt, "frame_dt", low=0.0, low_open=True)
        check_choice(self.selector, "selector", ("graph", "brute-force", "auto"))
        check_choice(self.length_prior, "length_prior", ("database", "default"))
        check_choice(self.energy_dtype, "energy_dtype", ENERGY_DTYPES)
        check_choice(self.energy_kernel, "energy_kernel", ENERGY_KERNELS)
        if self.calibrate_output and self.output_map is not None:
            raise ValueError(
                "calibrate_output and output_map: give one (the calibration fits the output map)"
            )
        if self.calibration_map is not None and not self.calibrate_output:
            raise ValueError("calibration_map: only used with calibrate_output=True")
        if self.bone_model is not None and not self.fusion.enabled:
            raise ValueError("bone_model: only used with fusion enabled")
        if self.reference_lengths is not None and len(self.reference_lengths) != skeleton.NUM_BONES:
            raise ValueError(
                f"reference_lengths: expected 19 lengths, got {len(self.reference_lengths)}"
            )
