"""The per-frame reconstruction pipeline (Shum 2013, FPG 2016) as one object.

One frame::

    prepare(positions, states, timestamp) -> SearchProblem
        normalise (root to origin, facing +Z)       poses.normalise
        reliability R and its terms                  ReliabilityEstimator
        K candidates (graph or brute force)          selection
        natural posture space (whitened PCA)         LatentSpace
        energy, x0                                   EnergyModel, SearchProblem
    <an optimiser, a policy or the env's action picks z>
    finish(z) -> (pose in camera space, FrameRecord)
        back-project, retarget to the user's bone lengths, back to camera space,
        optional ragdoll

:meth:`Reconstructor.reconstruct_frame` runs both with an optimiser in between and
:meth:`Reconstructor.reconstruct` runs a whole recording.

Frames of reference
-------------------
The sensor pose is normalised with its own root and hip-line heading. Previous reconstructions
(camera space) enter the current frame *root-relative* (each minus its own root) and rotated by
the current frame's heading: the continuity prediction ``p_l + v_l dt`` (FPG Eq. 6) and the
motion target of ``Em`` (Shum Eq. 14) are then in the same frame as the candidates, whose roots
are at the origin. A heading error of the sensor is thus partly absorbed by the reconstruction.

The output is denormalised with the sensor frame's root and heading. A frame where no joint is
tracked or inferred (no body) keeps the previous output's root and heading and a zero-velocity
prediction; a stream restarts (full search, no continuity) on its first frame and after a gap of
more than ``max_gap_s`` seconds.

Left/right confusions
---------------------
A Kinect assumes that the user faces it: a user seen side-on gets arms or legs swapped for a
while, one seen from behind is reported mirrored (Shum §I). Not in the papers: with
``left_right_fix`` (default on) each frame's sensor pose is compared, root-relative, with the
constant-velocity prediction of the previous outputs under four labellings
(:data:`LABELLINGS`: as reported, mirrored, arms swapped, legs swapped); another labelling is
used when it is clearly closer (``left_right_margin``) and the frame's record says which.

Temporal coherence and bone lengths (issue 15)
----------------------------------------------
Beyond the papers, switchable (``config.temporal``, ``config.bones``): the output is placed with a
smoothed root and heading, the latent axes keep their signs from frame to frame, ``Em`` is
anchored on the previous reconstruction with a larger weight, a Kalman stage filters the output
(bone lengths restored), and the user's bone lengths settle after one second
(:mod:`fpg_gym.reconstruct.temporal`, :mod:`fpg_gym.reconstruct.bones`).
``TemporalConfig.off()`` and ``BoneSettlingConfig(enabled=False)`` give the papers' pipeline.

Ragdoll
-------
With ``ragdoll=`` (a factory ``lengths -> ragdoll``, such as :class:`fpg_gym.physics.ragdoll.
Ragdoll` itself: the ragdoll is injected, this layer imports no physics; the layers above turn a
flag into the factory with :func:`fpg_gym.methods.ragdoll_factory`), the camera-space target is
tracked by the ragdoll and its simulated pose is the output.
The ragdoll runs in camera space shifted down by the floor height, estimated as the lowest joint
of the targets so far (camera space has no floor); it is rebuilt when the user's reference bone
lengths move by more than ``ragdoll_rebuild_m``. It runs after denormalisation, not in the
normalised frame: physics needs one consistent world frame, and the normalised frame jumps with
the sensor's root and heading every frame.

Learned output correction (issue 19)
------------------------------------
When the optimiser that searched a frame brings a correction model (its ``output_correction``:
``learned:`` with a linear sampler trained with one), the output is corrected last, after every
stage above, by the model's smoothed offsets (:mod:`fpg_gym.reconstruct.output_correction`);
the stream's history keeps the uncorrected pose, so the correction never feeds back.
:meth:`Reconstructor.finish` also takes one directly (``correction=``); the env's agent brings
none.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal, Protocol

import numpy as np
from tqdm import tqdm

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.poses import FloorShift, RecordingLike
from fpg_gym.core.seeding import as_generator
from fpg_gym.core.validation import check_choice, check_integer, check_number
from fpg_gym.definitions import OnlineDefinitionFit, PoseMap, sensor_to_output_map
from fpg_gym.reconstruct.bones import BoneSettler, BoneSettlingConfig
from fpg_gym.reconstruct.energy import (
    ENERGY_KERNELS,
    TERM_NAMES,
    EnergyModel,
    EnergyWeights,
    motion_target,
)
from fpg_gym.reconstruct.fusion import BoneModel, FusionConfig, SensorFusion, SensorTrust
from fpg_gym.reconstruct.kernels import compile_kernels
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.output_correction import (
    CorrectionState,
    OutputCorrection,
    output_correction_of,
)
from fpg_gym.reconstruct.problem import FrameContext, SearchProblem
from fpg_gym.reconstruct.reliability import (
    ReliabilityConfig,
    ReliabilityEstimator,
    ReliabilityTerms,
)
from fpg_gym.reconstruct.search import run_search
from fpg_gym.reconstruct.selection import (
    CandidateSelector,
    NodeDatabase,
    Selection,
    SelectionQuery,
    make_selector,
)
from fpg_gym.reconstruct.temporal import (
    OutputSmoother,
    PlacementSmoother,
    TemporalConfig,
    align_basis,
)
from optimizers import Optimizer, SearchResult, make

STAGES: tuple[str, ...] = (
    "normalise",
    "reliability",
    "selection",
    "latent",
    "search",
    "finish",
    "ragdoll",
)
"""Stages timed in :attr:`FrameRecord.ms` (milliseconds)."""


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

_LABEL_PERMUTATIONS = np.stack(
    [
        np.arange(skeleton.NUM_JOINTS),
        np.asarray(skeleton.MIRROR_PERMUTATION),
        _swap(_side_joints(("Shoulder", "Elbow", "Wrist", "Hand"))),
        _swap(_side_joints(("Hip", "Knee", "Ankle", "Foot"))),
    ]
)
_LABEL_PERMUTATIONS.flags.writeable = False


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
            _LABEL_PERMUTATIONS,
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
    relabelled = local[_LABEL_PERMUTATIONS]  # (H, 20, 3)
    w = weights[_LABEL_PERMUTATIONS]  # (H, 20)
    dist = np.linalg.norm(relabelled - target, axis=-1)
    return np.asarray((w * dist).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-9))


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
    energy_dtype : {"float64", "float32"}
        Arithmetic precision of the energy (see :class:`EnergyModel`).
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
        tracked joints (:class:`fpg_gym.definitions.OnlineDefinitionFit`: a running mean of
        the output-to-sensor residual in each joint's frame), and apply it to the returned
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
    energy_dtype: str = "float64"
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
        check_choice(self.energy_dtype, "energy_dtype", ("float64", "float32"))
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


@dataclass(frozen=True)
class FrameRecord:
    """What happened in one frame.

    Attributes
    ----------
    index, timestamp : int, float
    reliability, behaviour, kinematic, tracking : ndarray, shape (20,)
    reference_source : str
        Where the bone lengths came from (see :mod:`fpg_gym.reconstruct.reliability`).
    nodes, node_scores : ndarray, shape (K,)
        Selected nodes (best first) and their selection scores.
    num_scored : int
        Nodes scored by the selector.
    full_search, recovered : bool
        Whether every node was scored; whether the recovery rule triggered it.
    first, no_body : bool
        Stream (re)start; no joint tracked or inferred.
    energy, energy_x0 : float
        ``E`` of the chosen point and of ``x0``.
    terms : dict of str to float
        ``Ec``, ``Es``, ``Ek``, ``Em`` of the chosen point (unweighted).
    evaluations : int
        Energy evaluations spent by the search.
    ms : dict of str to float
        Milliseconds per stage (:data:`STAGES`) and ``total``.
    ragdoll : dict or None
        The ragdoll's ``info`` after the frame (None without a ragdoll).
    labelling : str
        The left/right labelling used (:data:`LABELLINGS`; ``"as-reported"`` unless fixed).
    bone_lengths : ndarray, shape (19,) or None
        The user's bone lengths used in this frame (after the settling rule).
    """

    index: int
    timestamp: float
    reliability: np.ndarray
    behaviour: np.ndarray
    kinematic: np.ndarray
    tracking: np.ndarray
    reference_source: str
    nodes: np.ndarray
    node_scores: np.ndarray
    num_scored: int
    full_search: bool
    recovered: bool
    first: bool
    no_body: bool
    energy: float
    energy_x0: float
    terms: dict[str, float]
    evaluations: int
    ms: dict[str, float]
    ragdoll: dict[str, Any] | None = None
    labelling: str = "as-reported"
    bone_lengths: np.ndarray | None = None


@dataclass
class ReconstructionResult:
    """A reconstructed stream: poses and per-frame records.

    Attributes
    ----------
    poses : ndarray, shape (T, 20, 3), float32
        Reconstructed poses in the input's camera space, frame for frame.
    records : list of FrameRecord
    interrupted : bool
        True when the run stopped early (Ctrl-C); ``poses`` then holds the frames done.
    bones : dict
        When the bone lengths settled and how much they changed afterwards
        (:meth:`fpg_gym.reconstruct.bones.BoneSettler.report`).
    """

    poses: np.ndarray
    records: list[FrameRecord]
    interrupted: bool = False
    bones: dict[str, Any] = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        """Frames reconstructed."""
        return len(self.records)

    @property
    def ms_per_frame(self) -> np.ndarray:
        """Total milliseconds per frame ``(T,)``."""
        return np.array([r.ms["total"] for r in self.records])

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything as arrays (the ``reconstruct`` command's ``.npz`` keys).

        ``poses`` (T,20,3), ``timestamps`` (T,), ``reliability``/``behaviour``/``kinematic``/
        ``tracking`` (T,20), ``nodes``/``node_scores`` (T,K) (−1 / NaN padded), ``num_scored``,
        ``evaluations`` (T,), ``energy``, ``energy_x0`` (T,), ``energy_terms`` (T,5) in
        ``energy_term_names`` order, ``full_search``/``recovered``/``first``/``no_body`` (T,)
        bool, ``ms_per_frame`` (T,), ``ms_stages`` (T,S) in ``stage_names`` order.
        """
        records = self.records
        t = len(records)
        k = max((len(r.nodes) for r in records), default=0)
        nodes = np.full((t, k), -1, dtype=np.int64)
        scores = np.full((t, k), np.nan)
        for i, r in enumerate(records):
            nodes[i, : len(r.nodes)] = r.nodes
            scores[i, : len(r.nodes)] = r.node_scores

        def stack(name: str, dtype: Any = np.float64) -> np.ndarray:
            return np.array([getattr(r, name) for r in records], dtype=dtype).reshape(t, -1)

        out: dict[str, np.ndarray] = {
            "poses": np.asarray(self.poses[:t], dtype=np.float32),
            "timestamps": np.array([r.timestamp for r in records], dtype=np.float64),
            "reliability": stack("reliability").astype(np.float32),
            "behaviour": stack("behaviour").astype(np.float32),
            "kinematic": stack("kinematic").astype(np.float32),
            "tracking": stack("tracking").astype(np.float32),
            "nodes": nodes,
            "node_scores": scores,
            "num_scored": np.array([r.num_scored for r in records], dtype=np.int64),
            "evaluations": np.array([r.evaluations for r in records], dtype=np.int64),
            "energy": np.array([r.energy for r in records]),
            "energy_x0": np.array([r.energy_x0 for r in records]),
            "energy_terms": np.array([[r.terms[n] for n in TERM_NAMES] for r in records]).reshape(
                t, len(TERM_NAMES)
            ),
            "energy_term_names": np.array(TERM_NAMES),
            "full_search": np.array([r.full_search for r in records], dtype=bool),
            "recovered": np.array([r.recovered for r in records], dtype=bool),
            "first": np.array([r.first for r in records], dtype=bool),
            "no_body": np.array([r.no_body for r in records], dtype=bool),
            "labelling": np.array([LABELLINGS.index(r.labelling) for r in records], dtype=np.int8),
            "labelling_names": np.array(LABELLINGS),
            "ms_per_frame": self.ms_per_frame,
            "ms_stages": np.array([[r.ms[s] for s in STAGES] for r in records]).reshape(
                t, len(STAGES)
            ),
            "stage_names": np.array(STAGES),
        }
        if t and all(r.bone_lengths is not None for r in records):
            out["bone_lengths"] = np.stack([np.asarray(r.bone_lengths) for r in records])
        return out


@dataclass
class _Pending:
    """State between prepare() and finish()."""

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
    tracked: np.ndarray | None = None  # its tracked joints
    found: np.ndarray | None = None  # the best point of search(), if one ran
    sensor_states: np.ndarray | None = None  # the raw input's tracking states
    correction: OutputCorrection | None = None  # the searching optimiser's, if it has one
    trust: np.ndarray | None = None  # the fusion's trust in each (relabelled) sensor joint
    permutation: np.ndarray | None = None  # the labelling's joint permutation


def _rotate_into(pose: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """A camera-space pose, root-relative and turned by ``-yaw`` (the current frame's heading)."""
    pose = np.asarray(pose, dtype=np.float64)
    return pose_utils.into_placement(pose, pose_utils.Placement(root=pose[skeleton.ROOT], yaw=yaw))


class Reconstructor:
    """Reconstructs Kinect frames against a pose graph, one frame at a time.

    Parameters
    ----------
    graph : FilteredPoseGraph-like
        ``poses`` (N, 20, 3) normalised and the CSR adjacency (``neighbors_of``).
    config : ReconstructorConfig, optional
    ragdoll : callable, optional
        A factory ``lengths -> ragdoll`` of any object with ``reset(pose)``,
        ``track(target) -> pose`` and ``close()`` (:class:`RagdollLike`), e.g.
        :class:`fpg_gym.physics.ragdoll.Ragdoll`; None/False: no ragdoll. ``True`` is refused
        (this layer does not import physics): :func:`fpg_gym.methods.ragdoll_factory` turns a
        flag into the factory.
    **overrides
        Fields of :class:`ReconstructorConfig` (e.g. ``selector="brute-force"``).

    Examples
    --------
    >>> rec = Reconstructor(graph, selector="graph")                       # doctest: +SKIP
    >>> result = rec.reconstruct(recording, "local-search", rng=0)         # doctest: +SKIP
    >>> problem = rec.prepare(positions, states, timestamp)                # doctest: +SKIP
    >>> pose, record = rec.finish(problem.x0)                              # doctest: +SKIP
    """

    def __init__(
        self,
        graph: Any,
        config: ReconstructorConfig | None = None,
        *,
        ragdoll: RagdollFactory | Literal[False] | None = None,
        **overrides: Any,
    ) -> None:
        config = config or ReconstructorConfig()
        if overrides:
            names = {f.name for f in fields(ReconstructorConfig)}
            unknown = sorted(set(overrides) - names)
            if unknown:
                raise TypeError(
                    f"Reconstructor: unknown setting(s) {unknown}; expected fields of "
                    "ReconstructorConfig: " + ", ".join(sorted(names))
                )
            config = replace(config, **overrides)
        self.config = config
        self.graph = graph
        self.database = NodeDatabase(np.asarray(graph.poses))
        # The energy weights of every frame: the motion term scaled by the temporal stage.
        scale = config.temporal.motion_scale
        self._weights = (
            config.weights
            if scale == 1.0
            else replace(config.weights, motion=config.weights.motion * scale)
        )
        kwargs: dict[str, Any] = (
            {
                "recovery_factor": config.recovery_factor,
                "recovery_min_score": config.recovery_min_score,
            }
            if config.selector in ("graph", "auto")
            else {"score": config.brute_force_score}
        )
        self.selector: CandidateSelector = make_selector(
            config.selector, graph, config.k, database=self.database, **kwargs
        )
        self.reliability = ReliabilityEstimator(
            config.reliability,
            None if config.reference_lengths is None else np.asarray(config.reference_lengths),
            prior_lengths=(
                np.median(pose_utils.bone_lengths(self.database.poses), axis=0)
                if config.length_prior == "database"
                else None
            ),
        )
        if ragdoll is True:  # this layer does not import physics: the layer above resolves it
            raise TypeError(
                "ragdoll: expected a factory lengths -> ragdoll (fpg_gym.physics.ragdoll.Ragdoll, "
                "or fpg_gym.methods.ragdoll_factory(True)), None or False; got True"
            )
        self._ragdoll_factory: RagdollFactory | None = ragdoll if callable(ragdoll) else None
        self._ragdoll: RagdollLike | None = None
        self._ragdoll_lengths: np.ndarray | None = None
        self.ragdoll_rebuilds = 0
        self._placement_smoother = (
            PlacementSmoother(config.temporal) if config.temporal.placement else None
        )
        self._output_smoother = OutputSmoother(config.temporal) if config.temporal.output else None
        self.bones = BoneSettler(config.bones)
        self._correction = CorrectionState()
        self._calibration = OnlineDefinitionFit() if config.calibrate_output else None
        mapped_output = config.output_map is not None or config.calibrate_output
        self._output_bones = (  # settles at once on the mean gathered before it is used
            BoneSettler(replace(config.bones, settle_s=0.0))
            if mapped_output and config.bones.enabled and not config.fusion.enabled
            else None
        )
        self._trust = SensorTrust(config.fusion) if config.fusion.enabled else None
        self._fusion = (
            SensorFusion(config.fusion, config.bone_model, config.bones)
            if config.fusion.enabled
            else None
        )
        self._sensor_output_map = sensor_to_output_map(config)
        self.reset()

    # ------------------------------------------------------------------ state

    @property
    def k(self) -> int:
        """Candidates per frame: ``min(config.k, number of nodes)``."""
        return min(self.config.k, len(self.database))

    @property
    def latent_dim(self) -> int:
        """Latent dimension of every problem: ``min(config.latent_dim, K - 1)``."""
        return max(0, min(self.config.latent_dim, self.k - 1))

    @property
    def ragdoll(self) -> RagdollLike | None:
        """The current ragdoll (None before the first frame or without one)."""
        return self._ragdoll

    @property
    def problem(self) -> SearchProblem | None:
        """The prepared problem waiting for :meth:`finish` (None otherwise)."""
        return None if self._pending is None else self._pending.problem

    @property
    def placement(self) -> pose_utils.Placement | None:
        """Where the prepared frame's problem lives (None when no frame is prepared).

        The problem's poses are normalised by this placement's heading, and :meth:`finish`
        puts the chosen pose back with it. It is *not* always the raw input's own placement:
        the sensor map moves the hip line, a left/right relabelling turns it by about 180
        degrees, a frame without a body keeps the last placement, and the temporal stage may
        smooth the heading. A reference pose (the ground truth) seen in the problem's frame is
        ``into_placement(truth, Placement(truth[ROOT], placement.yaw))``.
        """
        return None if self._pending is None else self._pending.placement

    def reset(self) -> None:
        """Start a new stream: forget the history, bone lengths and previous nodes."""
        self.reliability.reset()
        self.selector.reset()
        self._history: list[tuple[np.ndarray, float]] = []  # camera-space outputs, newest last
        self._fused_history: list[tuple[np.ndarray, float]] = []  # the fusion's outputs
        self._placement: pose_utils.Placement | None = None
        self._pending: _Pending | None = None
        self._index = 0
        self._last_timestamp: float | None = None
        self._floor = FloorShift()
        self._ragdoll_needs_reset = True
        self._ragdoll_settle = False
        # A new stream starts from scratch: the retargeted-database cache and the ragdoll's
        # physics (rebuilt at the first tracked frame) carry nothing over, so the output does
        # not depend on what was reconstructed before.
        self.database.clear_cache()
        self._ragdoll_lengths = None
        self.bones.reset()
        if self._trust is not None:
            self._trust.reset()
        if self._calibration is not None:
            self._calibration.reset()
        if self._output_bones is not None:
            self._output_bones.reset()
        self._output_length_sum = np.zeros(skeleton.NUM_BONES)
        self._output_length_count = 0
        self._output_start: float | None = None
        self._restart_temporal()

    def _restart_temporal(self) -> None:
        """Restart the temporal filters (a new stream or a gap; the bone lengths stay)."""
        if self._placement_smoother is not None:
            self._placement_smoother.reset()
        if self._output_smoother is not None:
            self._output_smoother.reset()
        if self._fusion is not None:
            self._fusion.reset()
        self._correction.reset()
        self._previous_latent: LatentSpace | None = None

    def close(self) -> None:
        """Release the ragdoll, if any."""
        if self._ragdoll is not None:
            self._ragdoll.close()
            self._ragdoll = None

    def __getstate__(self) -> dict[str, Any]:
        """Pickle support: the ragdoll (a pybullet client) is left out and rebuilt on use."""
        state = self.__dict__.copy()
        state["_ragdoll"] = None
        state["_ragdoll_needs_reset"] = True
        return state

    def __enter__(self) -> Reconstructor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ prepare

    def prepare(
        self, positions: np.ndarray, states: np.ndarray, timestamp: float | None = None
    ) -> SearchProblem:
        """Everything up to the search for one frame; returns the frame's problem.

        Parameters
        ----------
        positions : array_like, shape (20, 3)
            Sensor joint positions, camera space, metres.
        states : array_like, shape (20,)
            2 tracked, 1 inferred, 0 not tracked.
        timestamp : float, optional
            Seconds; the previous timestamp plus ``frame_dt`` when omitted.

        Raises
        ------
        RuntimeError
            If the previous problem was not finished.
        ValueError
            On a wrong shape or a non-finite position.
        """
        if self._pending is not None:
            raise RuntimeError(
                "prepare: the previous frame's problem was not finished (call finish)"
            )
        t0 = time.perf_counter()
        positions = pose_utils.as_poses(positions, "positions", ndim=2)
        states = np.asarray(states)
        if states.shape != (skeleton.NUM_JOINTS,):
            raise ValueError(f"states: expected shape (20,), got {states.shape}")
        cfg = self.config
        sensor, raw_states = positions, states
        if cfg.sensor_map is not None:  # the sensor's body points -> the database's
            positions = cfg.sensor_map.apply(positions).astype(np.float32)
        if timestamp is None:
            timestamp = 0.0 if self._last_timestamp is None else self._last_timestamp + cfg.frame_dt
        timestamp = float(timestamp)
        no_body = not bool(np.any(states > 0))

        # Stream (re)start: first frame, or a long gap since the last reconstruction.
        if self._history and (timestamp - self._history[-1][1] > cfg.max_gap_s):
            self._history.clear()
            self._fused_history.clear()
            self.selector.reset()
            self.reliability.forget_motion()
            self._ragdoll_needs_reset = True
            self._restart_temporal()
        first = not self._history
        dt = cfg.frame_dt if first else max(timestamp - self._history[-1][1], 1e-6)

        # Left/right confusions (a Kinect assumes the user faces it): keep the labelling that
        # continues the previous outputs best (with the fusion, the fused outputs, compared with
        # the sensor in their definitions: the database's own pose may be another activity's).
        labelling = 0
        history, compared = self._history, positions
        if self._fusion is not None:
            history = self._fused_history
            if self._sensor_output_map is not None:
                compared = self._sensor_output_map.apply(sensor)
        if cfg.left_right_fix and history and not no_body:
            last = history[-1][0]
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
            if (
                best != 0
                and costs[best] < cfg.left_right_margin * costs[0]
                and costs[0] - costs[best] > 0.03
            ):
                labelling = best
                positions = positions[_LABEL_PERMUTATIONS[best]]
                states = states[_LABEL_PERMUTATIONS[best]]
                compared = compared[_LABEL_PERMUTATIONS[best]]

        # Normalise (root to origin, facing +Z); without a body keep the last placement.
        kinect, placement = pose_utils.normalise(positions)
        output_placement = placement
        if no_body and self._placement is not None:
            placement = output_placement = self._placement
            kinect = pose_utils.into_placement(positions, placement).astype(np.float32)
        elif self._placement_smoother is not None:
            # Temporal coherence (not in the papers): the output is put back at a smoothed root
            # (and heading, when smoothed; the pose is then estimated in that heading's frame).
            smoothed = self._placement_smoother.update(placement, timestamp)
            if cfg.temporal.smooth_heading:
                output_placement = smoothed
                placement = pose_utils.Placement(root=placement.root, yaw=smoothed.yaw)
                kinect = pose_utils.into_placement(positions, placement).astype(np.float32)
            else:
                output_placement = pose_utils.Placement(root=smoothed.root, yaw=placement.yaw)
        t1 = time.perf_counter()

        terms = self.reliability.update(positions, states)
        trust = None
        if self._trust is not None:  # the fusion's trust scales R (not in the papers)
            # In the output's definitions, as the fusion sees the sensor (a database's own
            # definitions may make a bone short enough for its noise to look like a jump).
            trust = self._trust.update(compared, states, timestamp)
            terms = replace(terms, reliability=terms.reliability * trust)
        was_settled = self.bones.settled
        lengths = self.bones.update(terms.reference_lengths, timestamp)
        if self.bones.settled and not was_settled:
            self._ragdoll_settle = True
        t2 = time.perf_counter()

        # Previous reconstructions in this frame; continuity prediction (FPG Eq. 6) which is also
        # the motion target of Em (Shum Eq. 14).
        previous = prediction = None
        if self._history:
            previous = _rotate_into(self._history[-1][0], placement.yaw)
            if len(self._history) >= 2 and not no_body:
                before = _rotate_into(self._history[-2][0], placement.yaw)
                dt_prev = self._history[-1][1] - self._history[-2][1]
                prediction = motion_target(previous, before, dt, dt_prev)
                damping = cfg.temporal.velocity_damping
                if damping != 1.0:
                    # Temporal coherence (not in the papers): a continuity prior anchored on the
                    # previous reconstruction rather than on its noisy extrapolation.
                    prediction = previous + damping * (prediction - previous)
            else:
                prediction = previous.copy()
        selection = self.selector.select(
            SelectionQuery(
                pose=kinect,
                reliability=terms.reliability,
                prediction=prediction,
                lengths=lengths if cfg.retarget_candidates else None,
            )
        )
        t3 = time.perf_counter()

        latent = LatentSpace.fit(
            selection.poses,
            max_dim=cfg.latent_dim,
            kernel="numpy" if cfg.energy_kernel == "direct" else cfg.energy_kernel,
        )
        if cfg.temporal.align_basis:
            latent = align_basis(latent, self._previous_latent)
        self._previous_latent = latent
        energy = EnergyModel(
            latent,
            kinect,
            terms.reliability,
            selection.poses,
            lengths,
            prediction,
            self._weights,
            dtype=cfg.energy_dtype,
            kernel=cfg.energy_kernel,
        )
        x0 = latent.encode(previous if previous is not None else selection.poses[0])
        problem = SearchProblem(
            energy=energy,
            kinect_pose=kinect,
            reliability=terms,
            selection=selection,
            prediction=prediction,
            previous=previous,
            x0=x0,
            context=FrameContext(index=self._index, timestamp=timestamp, dt=dt, first=first),
        )
        t4 = time.perf_counter()
        ms = {
            "normalise": 1e3 * (t1 - t0),
            "reliability": 1e3 * (t2 - t1),
            "selection": 1e3 * (t3 - t2),
            "latent": 1e3 * (t4 - t3),
        }
        self._pending = _Pending(
            problem,
            output_placement,
            terms,
            selection,
            first,
            no_body,
            timestamp,
            ms,
            t4,
            LABELLINGS[labelling],
            np.asarray(lengths, dtype=np.float64),
            sensor,
            ((states == skeleton.TRACKED) if trust is None else (trust > 0.9)) & (not no_body),
            sensor_states=raw_states,
            trust=trust,
            permutation=_LABEL_PERMUTATIONS[labelling],
        )
        return problem

    # ------------------------------------------------------------------ finish

    def finish(
        self, z: np.ndarray | None = None, *, correction: OutputCorrection | None = None
    ) -> tuple[np.ndarray, FrameRecord]:
        """Reconstruct the prepared frame from latent point ``z``.

        Parameters
        ----------
        z : array_like, shape (d,), optional
            The chosen latent point; when omitted, the best point of :meth:`search` on this
            frame, else ``problem.x0``.
        correction : OutputCorrection, optional
            A learned correction of the output
            (:mod:`fpg_gym.reconstruct.output_correction`), applied last, smoothed over the
            stream; when omitted, that of the optimiser :meth:`search` ran on this frame, if it
            has one (``learned:`` with a linear sampler trained with a correction).

        Returns
        -------
        pose : ndarray, shape (20, 3), float32
            The reconstruction in camera space.
        record : FrameRecord

        Raises
        ------
        RuntimeError
            If no frame was prepared.
        """
        pending = self._prepared("finish")
        t0 = time.perf_counter()
        problem = pending.problem
        if z is None:
            z = problem.x0 if pending.found is None else pending.found
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        if z.shape != (problem.dim,) or not np.all(np.isfinite(z)):
            raise ValueError(f"z: expected {problem.dim} finite values, got shape {z.shape}")
        chosen = problem.evaluate_terms(np.stack([z, problem.x0]), count=False)
        local = problem.decode(z[None])[0]
        if self.config.sensor_blend > 0.0 and not pending.no_body:
            pull = self.config.sensor_blend * pending.terms.reliability[:, None]
            local = local + pull * (np.asarray(problem.kinect_pose, dtype=np.float64) - local)
        local = pose_utils.retarget(local, problem.lengths)
        pose = pose_utils.denormalise(local, pending.placement)
        t1 = time.perf_counter()
        ragdoll_info = None
        if self._ragdoll_factory is not None:
            pose, ragdoll_info = self._track(pose, problem.lengths)
        history_pose = pose
        t2 = time.perf_counter()
        if self._output_smoother is not None:
            # Light output filter (not in the papers); the bone lengths stay the output's.
            out_lengths = (
                problem.lengths if self._ragdoll_lengths is None else self._ragdoll_lengths
            )
            pose = self._output_smoother.update(pose, out_lengths, pending.timestamp)
        t3 = time.perf_counter()

        self._history.append((np.asarray(history_pose, dtype=np.float64), pending.timestamp))
        del self._history[:-2]
        self._placement = pending.placement
        self._last_timestamp = pending.timestamp
        ms = dict(pending.ms)
        ms["search"] = 1e3 * (t0 - pending.prepared_at)
        ms["finish"] = 1e3 * ((t1 - t0) + (t3 - t2))  # the output stage counts as finishing
        ms["ragdoll"] = 1e3 * (t2 - t1)
        ms["total"] = sum(ms[s] for s in STAGES)
        terms = pending.terms
        selection = pending.selection
        record = FrameRecord(
            index=self._index,
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
            energy=float(chosen["E"][0]),
            energy_x0=float(chosen["E"][1]),
            terms={name: float(chosen[name][0]) for name in TERM_NAMES},
            evaluations=problem.evaluations,
            ms=ms,
            ragdoll=ragdoll_info,
            labelling=pending.labelling,
            bone_lengths=pending.lengths,
        )
        self._pending = None
        self._index += 1
        if self.config.output_map is not None:
            pose = self.config.output_map.apply(pose)
        sensor = pending.sensor
        if sensor is not None and pending.permutation is not None:
            sensor = sensor[pending.permutation]  # the labels the frame was reconstructed with
        if self._calibration is not None and sensor is not None and pending.tracked is not None:
            target = sensor
            if self.config.calibration_map is not None:
                target = self.config.calibration_map.apply(target)
            pose = self._calibration.update(pose, target, pending.tracked)
        if self._output_bones is not None and not pending.no_body:
            pose = self._settle_output_bones(pose, pending.timestamp)
        if self._fusion is not None and sensor is not None and pending.trust is not None:
            # Fusion (not in the papers): the sensor where it is trusted, the reconstruction
            # where it is not.
            t5 = time.perf_counter()
            mapped = (
                sensor
                if self._sensor_output_map is None
                else (self._sensor_output_map.apply(sensor))
            )
            pose = self._fusion.update(pose, mapped, pending.trust, pending.timestamp)
            self._fused_history.append((np.asarray(pose, dtype=np.float64), pending.timestamp))
            del self._fused_history[:-2]
            spent = 1e3 * (time.perf_counter() - t5)
            record.ms["finish"] += spent
            record.ms["total"] += spent
        correction = pending.correction if correction is None else correction
        if correction is not None and pending.sensor is not None:
            t4 = time.perf_counter()
            pose = self._correction.correct(
                correction,
                np.asarray(pose, dtype=np.float64),
                np.asarray(pending.sensor, dtype=np.float64),
                np.asarray(pending.sensor_states),
                terms.reliability,
            )
            spent = 1e3 * (time.perf_counter() - t4)
            record.ms["finish"] += spent
            record.ms["total"] += spent
        return pose.astype(np.float32), record

    def _settle_output_bones(self, pose: np.ndarray, timestamp: float) -> np.ndarray:
        """The mapped output with settled bone lengths.

        A definition map moves each joint in the frame of its own body part, which stretches
        the bones between parts as the body turns. For the first ``bones.settle_s`` seconds the
        output passes unchanged while the mean of its bone lengths is gathered; then it is
        retargeted to lengths that start at that mean and follow the running mean within the
        bounds of :class:`BoneSettler` (the rule the database-side lengths obey).
        """
        assert self._output_bones is not None
        self._output_length_sum += pose_utils.bone_lengths(pose)
        self._output_length_count += 1
        if self._output_start is None:
            self._output_start = timestamp
        if timestamp - self._output_start < self.config.bones.settle_s:
            return pose
        mean = self._output_length_sum / self._output_length_count
        return pose_utils.retarget(pose, self._output_bones.update(mean, timestamp))

    def _track(self, target: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """Send a camera-space target through the ragdoll (floor shifted to y = 0)."""
        assert self._ragdoll_factory is not None
        new_stream = self._ragdoll_lengths is None
        settle, self._ragdoll_settle = self._ragdoll_settle, False
        if (
            self._ragdoll is None
            or new_stream
            or np.max(np.abs(self._ragdoll_lengths - lengths)) > self.config.ragdoll_rebuild_m
            or (settle and np.max(np.abs(self._ragdoll_lengths - lengths)) > 1e-3)
        ):
            lengths64 = np.asarray(lengths, dtype=np.float64)
            rebuild = getattr(self._ragdoll, "rebuild", None)
            if self._ragdoll is not None and callable(rebuild):
                rebuild(lengths64)  # same client, fresh physics: cheaper than a new ragdoll
            else:
                if self._ragdoll is not None:
                    self._ragdoll.close()
                self._ragdoll = self._ragdoll_factory(lengths64)
            if not new_stream:
                self.ragdoll_rebuilds += 1
            self._ragdoll_lengths = lengths64.copy()
            self._ragdoll_needs_reset = True
        before = int((getattr(self._ragdoll, "info", {}) or {}).get("divergences", 0))
        world = self._floor.down(target)
        if self._ragdoll_needs_reset:
            out = self._ragdoll.reset(world)
            self._ragdoll_needs_reset = False
        else:
            out = self._ragdoll.track(world)
        info = dict(getattr(self._ragdoll, "info", {}) or {})
        info["rebuilds"] = self.ragdoll_rebuilds
        info["floor_y"] = self._floor.floor_y
        # The ragdoll's counter is cumulative and restarts with a rebuild: report this frame's.
        info["new_divergences"] = int(info.get("divergences", 0)) - before
        return self._floor.up(out), info

    # ------------------------------------------------------------------ drivers

    def reconstruct_frame(
        self,
        positions: np.ndarray,
        states: np.ndarray,
        timestamp: float | None = None,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> tuple[np.ndarray, FrameRecord]:
        """``prepare``, :meth:`search` with ``optimizer`` (a registered name or an object),
        ``finish``."""
        opt = make(optimizer)
        generator = as_generator(rng)
        self.prepare(positions, states, timestamp)
        try:
            found = self.search(opt, generator)
        except BaseException:
            self._pending = None
            raise
        return self.finish(found.x)

    def warm_up(self, optimizer: Optimizer | str = "local-search") -> None:
        """Load what a stream's first frames would otherwise load, then start a new stream.

        Compiles (or loads from numba's disk cache) the energy and selection kernels and runs
        two frames of a still database pose standing 2.5 m in front of the sensor, a full search
        then a graph walk, with ``optimizer`` (which loads the compiled local search when it is
        local search) and the ragdoll, when configured; then
        :meth:`reset`, after which the output does not depend on these frames. For a live
        stream, whose first frames would stall for tens of milliseconds otherwise.
        """
        compile_kernels()
        pose = np.asarray(self.graph.poses[0], dtype=np.float64) + np.array([0.0, 1.0, 2.5])
        states = np.full(skeleton.NUM_JOINTS, skeleton.TRACKED)
        try:
            for timestamp in (0.0, self.config.frame_dt):
                self.reconstruct_frame(pose, states, timestamp, optimizer, 0)
        finally:
            self.reset()

    def _prepared(self, caller: str) -> _Pending:
        """The prepared frame, or a RuntimeError naming ``caller``."""
        if self._pending is None:
            raise RuntimeError(f"{caller}: no prepared frame (call prepare first)")
        return self._pending

    def search(
        self,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> SearchResult:
        """Run ``optimizer`` on the prepared frame's problem within the configured budget.

        The budget is the config's ``max_evaluations`` and ``time_budget_s``
        (:func:`optimizers.run_optimizer` enforces it; local search runs compiled where it
        can, :func:`fpg_gym.reconstruct.search.run_search`); :meth:`finish` without a point
        then uses the best point found.

        Raises
        ------
        RuntimeError
            If no frame was prepared.
        """
        pending = self._prepared("search")
        opt = make(optimizer)
        found = run_search(
            pending.problem,
            opt,
            rng,
            max_evaluations=self.config.max_evaluations,
            time_budget_s=self.config.time_budget_s,
        )
        pending.found = found.x
        pending.correction = output_correction_of(opt)
        return found

    def iter_frames(
        self,
        recording: RecordingLike,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> Iterator[tuple[np.ndarray, FrameRecord]]:
        """Reconstruct a recording frame by frame (a generator; starts with :meth:`reset`).

        ``recording`` needs ``positions`` (T,20,3), ``states`` (T,20) and optionally
        ``timestamps`` (T,).
        """
        positions = pose_utils.as_poses(recording.positions, "recording.positions", ndim=3)
        states = np.asarray(recording.states)
        if states.shape != positions.shape[:2]:
            raise ValueError(
                f"recording.states: expected shape {positions.shape[:2]}, got {states.shape}"
            )
        stamps = getattr(recording, "timestamps", None)
        timestamps = (
            np.arange(len(positions)) * self.config.frame_dt
            if stamps is None
            else np.asarray(stamps, dtype=np.float64)
        )
        opt = make(optimizer)
        generator = as_generator(rng)
        self.reset()
        for i in range(len(positions)):
            yield self.reconstruct_frame(positions[i], states[i], timestamps[i], opt, generator)

    def reconstruct(
        self,
        recording: RecordingLike,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
        *,
        progress: bool = False,
        stop_on_interrupt: bool = False,
        checkpoint: Callable[[ReconstructionResult], None] | None = None,
        checkpoint_s: float = 30.0,
    ) -> ReconstructionResult:
        """Reconstruct a whole recording.

        Parameters
        ----------
        recording : Recording-like
            ``positions`` (T,20,3), ``states`` (T,20), optional ``timestamps`` (T,).
        optimizer : str or Optimizer
            A registered name (``optimizers.available()``) or an optimiser object.
        rng : numpy.random.Generator or int, optional
            Seed or generator for the optimiser (same seed, same output); None: unseeded.
        progress : bool
            Show a tqdm progress bar on stderr.
        stop_on_interrupt : bool
            On Ctrl-C return the frames done (``interrupted=True``) instead of raising.
        checkpoint : callable, optional
            Called every ``checkpoint_s`` seconds (0: never) with the frames done so far (a
            :class:`ReconstructionResult` with ``interrupted=True``), e.g. to write them so that
            a killed run keeps them.
        checkpoint_s : float
            Seconds between checkpoints (30).
        """
        total = len(recording.positions)
        last_checkpoint = time.monotonic()
        poses = np.zeros((total, skeleton.NUM_JOINTS, 3), dtype=np.float32)
        records: list[FrameRecord] = []
        bar = None
        if progress:
            bar = tqdm(total=total, unit="frame", desc="reconstruct", leave=False)
        interrupted = False
        try:
            for i, (pose, record) in enumerate(self.iter_frames(recording, optimizer, rng)):
                poses[i] = pose
                records.append(record)
                if bar is not None:
                    bar.update(1)
                now = time.monotonic()
                if checkpoint is not None and 0 < checkpoint_s <= now - last_checkpoint:
                    done = len(records)
                    checkpoint(
                        ReconstructionResult(
                            poses[:done].copy(), list(records), True, bones=self.bones.report()
                        )
                    )
                    last_checkpoint = time.monotonic()
        except KeyboardInterrupt:
            if not stop_on_interrupt:
                raise
            interrupted = True
        finally:
            if bar is not None:
                bar.close()
        return ReconstructionResult(
            poses[: len(records)], records, interrupted, bones=self.bones.report()
        )
