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
:meth:`Reconstructor.reconstruct` runs a whole recording, both through the one run path
(:mod:`fpg_gym.reconstruct.streams`).

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

Temporal coherence and bone lengths
-----------------------------------
Beyond the papers, switchable (``config.temporal``, ``config.bones``; ``TemporalConfig.off()``
and ``BoneSettlingConfig(enabled=False)`` give the papers' pipeline): a smoothed root and
heading, latent axes that keep their signs, ``Em`` anchored on the previous output, a Kalman
output filter, bone lengths that settle after one second (:mod:`~fpg_gym.reconstruct.temporal`,
:mod:`~fpg_gym.reconstruct.bones`).

Ragdoll
-------
With ``ragdoll=`` (a factory ``lengths -> ragdoll`` such as
:class:`fpg_gym.physics.ragdoll.Ragdoll`, injected: this layer imports no physics), the ragdoll
tracks the camera-space target and its simulated pose is the output. It runs after
denormalisation (physics needs one consistent world frame), in camera space shifted down by the
floor height (the lowest joint of the targets so far), and is rebuilt when the user's reference
bone lengths move by more than ``ragdoll_rebuild_m``.

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

import math
import time
from dataclasses import fields, replace
from typing import Any, Literal

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.definitions import sensor_to_output_map
from fpg_gym.reconstruct.bones import BoneSettler, OutputLengths
from fpg_gym.reconstruct.config import RagdollFactory, RagdollLike, ReconstructorConfig
from fpg_gym.reconstruct.drivers import FrameDrivers
from fpg_gym.reconstruct.energy import EnergyModel
from fpg_gym.reconstruct.fusion import SensorFusion, SensorTrust
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.left_right import LABEL_PERMUTATIONS, LABELLINGS, best_labelling
from fpg_gym.reconstruct.output_calibration import OnlineDefinitionFit
from fpg_gym.reconstruct.output_correction import (
    CorrectionState,
    OutputCorrection,
    output_correction_of,
)
from fpg_gym.reconstruct.pending import Pending, frame_record, output_pose
from fpg_gym.reconstruct.problem import FrameContext, SearchProblem
from fpg_gym.reconstruct.ragdoll_stage import RagdollStage
from fpg_gym.reconstruct.records import STAGES, FrameRecord
from fpg_gym.reconstruct.reliability import ReliabilityEstimator, ReliabilityTerms
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
    align_basis,
    continuity,
)
from optimizers import Optimizer, SearchResult, make


class Reconstructor(FrameDrivers):
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
        self._ragdoll = RagdollStage(
            ragdoll if callable(ragdoll) else None, config.ragdoll_rebuild_m
        )
        self._placement_smoother = (
            PlacementSmoother(config.temporal) if config.temporal.placement else None
        )
        self._output_smoother = OutputSmoother(config.temporal) if config.temporal.output else None
        self.bones = BoneSettler(config.bones)
        self._correction = CorrectionState(config.bones)
        self._calibration = OnlineDefinitionFit() if config.calibrate_output else None
        mapped_output = config.output_map is not None or config.calibrate_output
        self._output_bones = (
            OutputLengths(config.bones)
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
        #: Whether ``_relabel`` maps the sensor into the output's definitions (the fusion's).
        self._maps_for_fusion = self._fusion is not None and self._sensor_output_map is not None
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
        return self._ragdoll.body

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
        self._pending: Pending | None = None
        self._index = 0
        self._last_timestamp: float | None = None
        # A new stream starts from scratch: the retargeted-database cache and the ragdoll's
        # physics (rebuilt at the first tracked frame) carry nothing over, so the output does
        # not depend on what was reconstructed before.
        self.database.clear_cache()
        self._ragdoll.restart()
        self.bones.reset()
        if self._trust is not None:
            self._trust.reset()
        if self._calibration is not None:
            self._calibration.reset()
        if self._output_bones is not None:
            self._output_bones.reset()
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
        self._ragdoll.close()

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
        t0 = time.perf_counter()
        positions = pose_utils.as_poses(positions, "positions", ndim=2)
        states = np.asarray(states)
        if states.shape != (skeleton.NUM_JOINTS,):
            raise ValueError(f"states: expected shape (20,), got {states.shape}")
        return self._prepare_checked(positions, states, timestamp, t0)

    def _prepare_checked(
        self,
        positions: np.ndarray,
        states: np.ndarray,
        timestamp: float | None = None,
        started: float | None = None,
        *,
        no_body: bool | None = None,
        positions64: np.ndarray | None = None,
    ) -> SearchProblem:
        """:meth:`prepare` of a frame whose input was checked before: ``positions`` ``(20, 3)``
        float32 and finite, ``states`` ``(20,)`` (a recording's frames, checked as a whole
        when its :class:`~fpg_gym.reconstruct.streams.Stream` starts); ``started`` is the
        frame's ``time.perf_counter()`` start; ``no_body``, when given, whether no state is
        above 0, and ``positions64``, when given, ``positions`` in float64 (found for a whole
        recording at once; read only).

        Raises
        ------
        RuntimeError
            If the previous problem was not finished.
        """
        if self._pending is not None:
            raise RuntimeError(
                "prepare: the previous frame's problem was not finished (call finish)"
            )
        t0 = time.perf_counter() if started is None else started
        cfg = self.config
        sensor, raw_states, mapped = positions, states, None
        # The stages below read the frame in float64 (float32 values, exact).
        if cfg.sensor_map is not None:  # the sensor's body points -> the database's
            mapped = cfg.sensor_map.apply(positions)
            positions = mapped.astype(np.float32).astype(np.float64)
        else:
            positions = positions.astype(np.float64) if positions64 is None else positions64
        if timestamp is None:
            timestamp = 0.0 if self._last_timestamp is None else self._last_timestamp + cfg.frame_dt
        timestamp = float(timestamp)
        if no_body is None:
            no_body = not skeleton.body_present(states)
        self._restart_after_gap(timestamp)
        first = not self._history
        dt = cfg.frame_dt if first else max(timestamp - self._history[-1][1], 1e-6)
        labelling, positions, states, compared = self._relabel(
            positions, states, sensor, mapped, dt, no_body
        )
        kinect, placement, output_placement = self._normalise(positions, timestamp, no_body)
        t1 = time.perf_counter()

        terms, trust, lengths = self._reliability_terms(positions, states, compared, timestamp)
        t2 = time.perf_counter()

        previous, prediction = continuity(
            self._history, placement.yaw, dt, no_body, cfg.temporal.velocity_damping
        )
        selection = self.selector.select(
            SelectionQuery(
                pose=kinect,
                reliability=terms.reliability,
                prediction=prediction,
                lengths=lengths if cfg.retarget_candidates else None,
            )
        )
        t3 = time.perf_counter()

        problem = self._frame_problem(
            kinect,
            terms,
            selection,
            lengths,
            previous,
            prediction,
            FrameContext(index=self._index, timestamp=timestamp, dt=dt, first=first),
        )
        t4 = time.perf_counter()
        ms = {
            "normalise": 1e3 * (t1 - t0),
            "reliability": 1e3 * (t2 - t1),
            "selection": 1e3 * (t3 - t2),
            "latent": 1e3 * (t4 - t3),
        }
        tracked = None
        if self._calibration is not None:  # the joints it fits: tracked (or trusted) ones
            tracked = ((states == skeleton.TRACKED) if trust is None else (trust > 0.9)) & (
                not no_body
            )
        self._pending = Pending(
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
            tracked,
            sensor_states=raw_states,
            trust=trust,
            labelling_index=labelling,
            # The fusion's sensor in the output's definitions: the relabelling's, when the
            # labels stay (a relabelled pose is mapped again: the map reads its labels).
            output_sensor=compared if labelling == 0 and self._maps_for_fusion else None,
        )
        return problem

    def _restart_after_gap(self, timestamp: float) -> None:
        """Stream (re)start: a long gap since the last reconstruction forgets the stream."""
        if self._history and (timestamp - self._history[-1][1] > self.config.max_gap_s):
            self._history.clear()
            self._fused_history.clear()
            self.selector.reset()
            self.reliability.forget_motion()
            self._ragdoll.needs_reset = True
            self._restart_temporal()

    def _relabel(
        self,
        positions: np.ndarray,
        states: np.ndarray,
        sensor: np.ndarray,
        mapped: np.ndarray | None,
        dt: float,
        no_body: bool,
    ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """Left/right confusions (a Kinect assumes the user faces it): keep the labelling that
        continues the previous outputs best (with the fusion, the fused outputs, compared with
        the sensor in their definitions: the database's own pose may be another activity's).
        ``mapped`` is the sensor map's pose of ``sensor`` (float64; None without a map).

        Returns the labelling's index in :data:`LABELLINGS`, the relabelled positions and
        states, and the relabelled pose the outputs were compared with.
        """
        cfg = self.config
        labelling = 0
        history, compared = self._history, positions
        if self._fusion is not None:
            history = self._fused_history
            output_map = self._sensor_output_map
            if output_map is not None and output_map is cfg.sensor_map and mapped is not None:
                compared = mapped  # the sensor's output definitions are the database's
            elif output_map is not None:
                compared = output_map.apply(sensor)
        if cfg.left_right_fix and history and not no_body:
            labelling = best_labelling(compared, states, history, dt, cfg.left_right_margin)
            if labelling:
                permutation = LABEL_PERMUTATIONS[labelling]
                positions, states = positions[permutation], states[permutation]
                compared = compared[permutation]
        return labelling, positions, states, compared

    def _normalise(
        self, positions: np.ndarray, timestamp: float, no_body: bool
    ) -> tuple[np.ndarray, pose_utils.Placement, pose_utils.Placement]:
        """Normalise (root to origin, facing +Z); without a body keep the last placement.

        Returns the normalised pose, the placement it was estimated in and the placement the
        output is put back with.
        """
        kinect, placement = pose_utils.normalise(positions)
        output_placement = placement
        if no_body and self._placement is not None:
            placement = output_placement = self._placement
            kinect = pose_utils.into_placement(positions, placement).astype(np.float32)
        elif self._placement_smoother is not None:
            # Temporal coherence (not in the papers): the output is put back at a smoothed root
            # (and heading, when smoothed; the pose is then estimated in that heading's frame;
            # else the smoothed placement keeps this one's).
            output_placement = self._placement_smoother.update(placement, timestamp)
            if self.config.temporal.smooth_heading:
                placement = pose_utils.Placement(root=placement.root, yaw=output_placement.yaw)
                kinect = pose_utils.into_placement(positions, placement).astype(np.float32)
        return kinect, placement, output_placement

    def _reliability_terms(
        self, positions: np.ndarray, states: np.ndarray, compared: np.ndarray, timestamp: float
    ) -> tuple[ReliabilityTerms, np.ndarray | None, np.ndarray]:
        """The frame's reliability terms (scaled by the fusion's trust, if any), the trust and
        the user's bone lengths after the settling rule."""
        trust = None
        if self._trust is not None:  # the fusion's trust scales R (not in the papers)
            # In the output's definitions, as the fusion sees the sensor (a database's own
            # definitions may make a bone short enough for its noise to look like a jump).
            trust = self._trust.update(compared, states, timestamp)
        terms = self.reliability.update(positions, states, trust)
        was_settled = self.bones.settled
        lengths = self.bones.update(terms.reference_lengths, timestamp)
        if self.bones.settled and not was_settled:
            self._ragdoll.settle = True
        return terms, trust, lengths

    def _frame_problem(
        self,
        kinect: np.ndarray,
        terms: ReliabilityTerms,
        selection: Selection,
        lengths: np.ndarray,
        previous: np.ndarray | None,
        prediction: np.ndarray | None,
        context: FrameContext,
    ) -> SearchProblem:
        """The natural posture space of the candidates (whitened PCA), the energy and x0."""
        cfg = self.config
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
        return SearchProblem(
            energy=energy,
            kinect_pose=kinect,
            reliability=terms,
            selection=selection,
            prediction=prediction,
            previous=previous,
            x0=x0,
            context=context,
        )

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
        x0 = problem.x0  # (d,), checked by the problem
        if z is None:
            z = x0 if pending.found is None else pending.found
        z = np.asarray(z, dtype=np.float64)
        if z.ndim != 1:
            z = z.reshape(-1)
        dim = len(x0)
        # z.z is finite only when every value is (NaN and inf stay); else the exact check
        if z.shape != (dim,) or (not math.isfinite(z @ z) and not np.isfinite(z).all()):
            raise ValueError(f"z: expected {dim} finite values, got shape {z.shape}")
        points = np.empty((2, dim))  # z and x0 (an encoded pose: finite)
        points[0] = z
        points[1] = x0
        chosen = problem.energy.terms_and_total(points)  # evaluate_terms's, checked, uncounted
        local = problem.decode(points[:1])[0]
        if self.config.sensor_blend > 0.0 and not pending.no_body:
            pull = self.config.sensor_blend * pending.terms.reliability[:, None]
            local = local + pull * (np.asarray(problem.kinect_pose, dtype=np.float64) - local)
        pose = output_pose(local, problem.lengths, pending.placement)
        t1 = t2 = time.perf_counter()
        ragdoll_info = None
        if self._ragdoll.factory is not None:
            pose, ragdoll_info = self._ragdoll.track(pose, problem.lengths)
            t2 = time.perf_counter()
        history_pose = np.asarray(pose, dtype=np.float64)  # the smoother's input too
        if self._output_smoother is not None:
            # Light output filter (not in the papers); the bone lengths stay the output's.
            out_lengths = (
                problem.lengths if self._ragdoll.lengths is None else self._ragdoll.lengths
            )
            pose = self._output_smoother.update(history_pose, out_lengths, pending.timestamp)
        t3 = time.perf_counter()

        self._history.append((history_pose, pending.timestamp))
        del self._history[:-2]
        self._placement = pending.placement
        self._last_timestamp = pending.timestamp
        ms = pending.ms  # the frame's own (prepare made it)
        ms["search"] = 1e3 * (t0 - pending.prepared_at)
        ms["finish"] = 1e3 * ((t1 - t0) + (t3 - t2))  # the output stage counts as finishing
        ms["ragdoll"] = 1e3 * (t2 - t1)
        ms["total"] = sum(map(ms.__getitem__, STAGES))
        terms = pending.terms
        record = frame_record(self._index, pending, chosen, ms, ragdoll_info)
        self._pending = None
        self._index += 1
        pose = self._output_stages(pose, pending, record)
        correction = pending.correction if correction is None else correction
        # A correction is learned from outputs without the fusion (train-sampler runs none):
        # on fused outputs it would redo what the fusion did (UI-PRMD s08 through the Kinect v2
        # preset: Eq. 13 +40 %, 0 of 100 episodes better), so the fusion's output stays as is.
        if correction is not None and pending.sensor is not None and self._fusion is None:
            t4 = time.perf_counter()
            pose = self._correction.correct(
                correction,
                np.asarray(pose, dtype=np.float64),
                np.asarray(pending.sensor, dtype=np.float64),
                np.asarray(pending.sensor_states),
                terms.reliability,
                pending.timestamp,
            )
            spent = 1e3 * (time.perf_counter() - t4)
            record.ms["finish"] += spent
            record.ms["total"] += spent
        # Every stage above returns a new array (or its input): no copy of a float32 pose.
        return np.asarray(pose, dtype=np.float32), record

    def _output_stages(self, pose: np.ndarray, pending: Pending, record: FrameRecord) -> np.ndarray:
        """The stages after the history's pose: the output map or the online calibration, the
        output's settled bone lengths, the fusion with the sensor (its time added to
        ``record.ms``)."""
        if self.config.output_map is not None:
            pose = self.config.output_map.apply(pose)
        if self._calibration is None and self._output_bones is None and self._fusion is None:
            return pose
        sensor = pending.sensor
        if sensor is not None:  # the labels the frame was reconstructed with
            sensor = sensor[LABEL_PERMUTATIONS[pending.labelling_index]]
        if self._calibration is not None and sensor is not None and pending.tracked is not None:
            target = sensor
            if pending.output_sensor is not None:  # the calibration map's (the fusion's too)
                target = pending.output_sensor
            elif self.config.calibration_map is not None:
                target = self.config.calibration_map.apply(target)
            pose = self._calibration.update(pose, target, pending.tracked)
        if self._output_bones is not None and not pending.no_body:
            pose = self._output_bones.settle(pose, pending.timestamp)
        if self._fusion is not None and sensor is not None and pending.trust is not None:
            # Fusion (not in the papers): the sensor where it is trusted, the reconstruction
            # where it is not.
            t5 = time.perf_counter()
            mapped = pending.output_sensor
            if mapped is None:
                mapped = (
                    sensor
                    if self._sensor_output_map is None
                    else self._sensor_output_map.apply(sensor)
                )
            pose = self._fusion.update(pose, mapped, pending.trust, pending.timestamp)
            self._fused_history.append((np.asarray(pose, dtype=np.float64), pending.timestamp))
            del self._fused_history[:-2]
            spent = 1e3 * (time.perf_counter() - t5)
            record.ms["finish"] += spent
            record.ms["total"] += spent
        return pose

    # ------------------------------------------------------------------ search

    def _prepared(self, caller: str) -> Pending:
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
