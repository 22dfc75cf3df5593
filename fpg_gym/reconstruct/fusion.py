"""Per-joint fusion of the sensor and the database reconstruction (beyond the papers).

A database reconstruction cannot reproduce a pose better than a good sensor reading of a
visible joint; it earns its place where the sensor is wrong. The fused output keeps the
(mapped, filtered) sensor's joints where the sensor is trusted and the database's
reconstruction, continued through time, where it is not:

Trust ``t(j)`` in ``[0, 1]`` (:class:`SensorTrust`), per joint and frame:

* *state*: tracked 1, not tracked 0; an inferred joint keeps full trust for a flicker
  (``flicker_s``: the tracking state of a real Kinect v2 flickers for a few frames) and in
  streams where it was never tracked (a joint the export always infers, such as UI-PRMD's
  hands, placed from tracked ones); after that its trust halves every
  ``inferred_half_life_s``: a Kinect that keeps inferring a joint it saw before has lost it,
  and its body model drifts (freezes, swings or folds the limb);
* *kinematic* (Shum 2013 §IV-B's term, on the stream's own lengths): a bone whose length
  leaves the running mean of its trusted lengths by more than ``length_tolerance`` (relative;
  0 trust at ``length_roof``) distrusts the joint at its end, which catches a tracked false
  positive that snaps onto a surface;
* an inferred joint is trusted no more than its parent (its reported position hangs off it).

Fusion (:class:`SensorFusion`): the output ``X`` minimises, per frame,

    sum_j t(j) ||X(j) - S(j)||^2 + mu sum_j (1 - t(j)) ||X(j) - D(j)||^2
        + lambda sum_bones ||(X(c) - X(p)) - V(b)||^2

with ``S`` the mapped, filtered sensor, ``D`` the database reconstruction (both in the output's
definitions), and bone vectors ``V(b) = t(b) V_s(b) + (1 - t(b)) V_u(b)``: the sensor's bone
(``t(b)`` the smaller trust of its two joints) or, for a bone the sensor has lost, ``V_u``, all
with the stream's settled length of the bone. A linear least-squares problem on the tree (a
20 x 20 system per frame): trusted joints stay where the sensor puts them (errors do not add up
along the chains, as they would if the pose were rebuilt from bone vectors), an occluded limb
hangs off its visible parent.

Where the sensor lost a bone, ``V_u(b) = a(b) V_d(b) + (1 - a(b)) V_h(b)`` mixes the
database's bone with the *held* one, its last trusted direction in its parent's frame
(:func:`fpg_gym.definitions.joint_frames`), so that it moves with the body. The held bone
comes first and fades out as the loss lasts: ``a(b) = g(b) (1 - exp(-l(b) / hold_s))`` with
``l(b)`` the time since the bone was last seen; ``g(b)`` is how well the database has been
reproducing this bone while the sensor saw it (the running mean, time constant
``agreement_s``, of the distance between the unit directions of the database's and the
sensor's bone: 1 below ``agreement_good``, 0 above ``agreement_bad``). Measured on UI-PRMD with
occlusions put in (``docs/real-data.md``): a lost forearm is best held for a second or two,
even with a database of the same exercises, while lost legs are best given by such a database;
one of other activities reproduces lost limbs worse than holding them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.validation import check_choice, check_number
from fpg_gym.definitions import joint_frames
from fpg_gym.filters import make_filter
from fpg_gym.reconstruct.bones import BoneSettler, BoneSettlingConfig

__all__ = ["BoneModel", "FusionConfig", "SensorFusion", "SensorTrust", "fuse_positions"]

_PARENT_BONE = skeleton.BONES[:, 0]
_CHILD_BONE = skeleton.BONES[:, 1]
_DEPTH_ORDER = np.concatenate(skeleton.JOINT_LEVELS)  # the joints below the root, by depth
#: Bone incidence ``(19, 20)``: +1 at a bone's child joint, -1 at its parent.
_INCIDENCE = np.zeros((skeleton.NUM_BONES, skeleton.NUM_JOINTS))
_INCIDENCE[np.arange(skeleton.NUM_BONES), _CHILD_BONE] = 1.0
_INCIDENCE[np.arange(skeleton.NUM_BONES), _PARENT_BONE] = -1.0
_INCIDENCE.flags.writeable = False
_LAPLACIAN = _INCIDENCE.T @ _INCIDENCE


class BoneModel(Protocol):
    """A model of the sensor's bone vectors (e.g. a learned correction of a sensor's bias)."""

    def bone_vectors(self, pose: np.ndarray) -> np.ndarray:
        """Bone vectors ``(19, 3)`` for one pose ``(20, 3)`` in the output's definitions."""
        ...


@dataclass(frozen=True)
class FusionConfig:
    """Settings of the fusion (see the module docstring).

    Attributes
    ----------
    enabled : bool
        Off by default (the papers' output); the sensor presets turn it on.
    bone_weight : float
        ``lambda``: weight of the bone-vector term against the trusted sensor positions (5).
    database_weight : float
        ``mu``: pull of an untrusted joint towards the database's position (0.1).
    flicker_s : float
        An inferred run this short keeps full trust (0.15 s).
    inferred_half_life_s : float
        After that, an inferred joint's trust halves every this many seconds (0.2 s).
    length_tolerance, length_roof : float
        Relative bone-length deviation where a joint's trust starts to fall and reaches 0
        (0.15, 0.4).
    sensor_filter : str
        Filter of the mapped sensor before the fusion (a :func:`fpg_gym.filters.make_filter`
        name, ``"raw"`` for none; ``"kalman"``).
    agreement_s : float
        Time constant of the database's running agreement with the sensor, seconds (1).
    agreement_good, agreement_bad : float
        Distances between unit bone directions (about radians) where the database's share of
        a lost bone is 1 and 0 (0.08 and 0.25).
    hold_s : float
        Time constant of the fade from the held bone to the database's, seconds (0.5).
    output_filter : str
        Filter of the fused output (a :func:`fpg_gym.filters.make_filter` name; ``"kalman"``).
    lengths : {"retarget", "solve", "none"}
        How the output keeps the user's bone lengths (the mean of the seen bones of the sensor,
        or of the bone model, under the settling rule of :mod:`fpg_gym.reconstruct.bones`):
        retargeted after the filter (``"retarget"``, :func:`fpg_gym.core.poses.retarget`, the
        default), a second solve on its own bone directions with a stiff bone term
        (``"solve"``), or not at all (``"none"``).
    """

    enabled: bool = False
    bone_weight: float = 5.0
    database_weight: float = 0.1
    flicker_s: float = 0.15
    inferred_half_life_s: float = 0.2
    length_tolerance: float = 0.15
    length_roof: float = 0.4
    sensor_filter: str = "kalman"
    agreement_s: float = 1.0
    agreement_good: float = 0.08
    agreement_bad: float = 0.25
    hold_s: float = 0.5
    output_filter: str = "kalman"
    lengths: str = "retarget"

    def __post_init__(self) -> None:
        check_number(self.bone_weight, "bone_weight", low=0.0)
        check_number(self.database_weight, "database_weight", low=0.0, low_open=True)
        check_number(self.flicker_s, "flicker_s", low=0.0)
        check_number(self.inferred_half_life_s, "inferred_half_life_s", low=0.0, low_open=True)
        check_number(self.length_tolerance, "length_tolerance", low=0.0)
        check_number(self.length_roof, "length_roof", low=self.length_tolerance, low_open=True)
        check_number(self.agreement_s, "agreement_s", low=0.0, low_open=True)
        check_number(self.agreement_good, "agreement_good", low=0.0)
        check_number(self.agreement_bad, "agreement_bad", low=self.agreement_good, low_open=True)
        check_number(self.hold_s, "hold_s", low=0.0)
        make_filter(self.sensor_filter)  # raises on an unknown name
        make_filter(self.output_filter)
        check_choice(self.lengths, "lengths", ("retarget", "solve", "none"))


class SensorTrust:
    """The trust of each sensor joint, frame by frame (see the module docstring)."""

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the stream."""
        self._run_start = np.full(skeleton.NUM_JOINTS, np.nan)
        self._ever_tracked = np.zeros(skeleton.NUM_JOINTS, dtype=bool)
        self._length_sum = np.zeros(skeleton.NUM_BONES)
        self._length_count = np.zeros(skeleton.NUM_BONES)

    @property
    def lengths(self) -> np.ndarray:
        """Running mean of each bone's length over its trusted frames (NaN before any)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self._length_sum / self._length_count

    def update(self, positions: np.ndarray, states: np.ndarray, timestamp: float) -> np.ndarray:
        """Trust ``(20,)`` of one frame's joints ``positions`` ``(20, 3)`` with ``states``."""
        cfg = self.config
        states = np.asarray(states)
        compiled = compiled_module("fpg_gym.reconstruct.compiled_fusion")
        if compiled is not None and states.shape == (skeleton.NUM_JOINTS,):
            # Two calls around numpy's power, the same arithmetic.
            exponents = compiled.trust_exponents(
                states,
                self._run_start,
                float(timestamp),
                cfg.flicker_s,
                cfg.inferred_half_life_s,
                skeleton.INFERRED,
            )
            trust: np.ndarray = compiled.sensor_trust(
                np.ascontiguousarray(positions, dtype=np.float64),
                states,
                0.5**exponents,
                self._ever_tracked,
                self._length_sum,
                self._length_count,
                cfg.length_tolerance,
                cfg.length_roof - cfg.length_tolerance,
                skeleton.TRACKED,
                skeleton.INFERRED,
                skeleton.BONES,
                _DEPTH_ORDER,
                skeleton.PARENTS,
            )
            return trust
        tracked = states == skeleton.TRACKED
        inferred = states == skeleton.INFERRED
        self._ever_tracked |= tracked
        self._run_start = np.where(
            inferred, np.where(np.isnan(self._run_start), timestamp, self._run_start), np.nan
        )
        lost_for = np.where(inferred, timestamp - self._run_start, 0.0) - cfg.flicker_s
        decay = 0.5 ** (np.maximum(lost_for, 0.0) / cfg.inferred_half_life_s)
        trust = np.where(
            tracked, 1.0, np.where(inferred, np.where(self._ever_tracked, decay, 1.0), 0.0)
        )
        # Kinematic term on the stream's own settled lengths: a bone that stretches or shrinks
        # distrusts the joint at its end.
        lengths = pose_utils.bone_lengths(np.asarray(positions, dtype=np.float64))
        reference = np.where(self._length_count > 0, self.lengths, lengths)
        deviation = np.abs(lengths - reference) / np.maximum(reference, 1e-3)
        span = cfg.length_roof - cfg.length_tolerance
        bone_trust = 1.0 - np.clip((deviation - cfg.length_tolerance) / span, 0.0, 1.0)
        trust[_CHILD_BONE] = np.minimum(trust[_CHILD_BONE], bone_trust)
        for level in skeleton.JOINT_LEVELS:  # an inferred joint hangs off its parent
            parents = skeleton.PARENTS[level]
            trust[level] = np.where(
                inferred[level], np.minimum(trust[level], trust[parents]), trust[level]
            )
        good = (trust[_PARENT_BONE] > 0.9) & (trust[_CHILD_BONE] > 0.9)
        self._length_sum += np.where(good, lengths, 0.0)
        self._length_count += good
        return trust


def fuse_positions(
    sensor: np.ndarray,
    trust: np.ndarray,
    database: np.ndarray,
    bones: np.ndarray,
    bone_weight: float,
    database_weight: float,
) -> np.ndarray:
    """The fused pose ``(20, 3)``: the least-squares solution of the module docstring.

    Parameters
    ----------
    sensor, database : ndarray, shape (20, 3)
        ``S`` and ``D`` in the output's definitions and space.
    trust : ndarray, shape (20,)
        ``t(j)``.
    bones : ndarray, shape (19, 3)
        ``V(b)``.
    bone_weight, database_weight : float
        ``lambda`` and ``mu``.
    """
    pull = database_weight * (1.0 - trust)
    system = bone_weight * _LAPLACIAN + np.diag(trust + pull)
    rhs = trust[:, None] * sensor + pull[:, None] * database + bone_weight * (_INCIDENCE.T @ bones)
    return np.asarray(np.linalg.solve(system, rhs))


class SensorFusion:
    """The fusion stage of one stream (see the module docstring).

    Parameters
    ----------
    config : FusionConfig
    bone_model : BoneModel, optional
        Gives the sensor's bone vectors (e.g. a learned correction of the sensor's bias) in
        place of the filtered sensor's own.
    """

    def __init__(
        self,
        config: FusionConfig | None = None,
        bone_model: BoneModel | None = None,
        bones: BoneSettlingConfig | None = None,
    ):
        self.config = config or FusionConfig()
        self.bone_model = bone_model
        self._settler = BoneSettler(bones)
        self._filter = make_filter(self.config.sensor_filter)
        self._output_filter = make_filter(self.config.output_filter)
        self.reset()

    def reset(self) -> None:
        """Forget the stream."""
        self._filter.reset()
        self._output_filter.reset()
        self._settler.reset()
        self._length_sum = np.zeros(skeleton.NUM_BONES)
        self._length_count = np.zeros(skeleton.NUM_BONES)
        self._held = np.full((skeleton.NUM_BONES, 3), np.nan)  # in the parent joint's frame
        self._disagreement = np.full(skeleton.NUM_BONES, np.nan)
        self._last_seen = np.full(skeleton.NUM_BONES, np.nan)
        self._last_timestamp: float | None = None

    def database_share(self, timestamp: float) -> np.ndarray:
        """``a(b)`` ``(19,)``: the database's share of each bone the sensor lost (``g`` is 0.5
        before the database has been compared with the sensor; a bone never seen is the
        database's)."""
        cfg = self.config
        span = cfg.agreement_bad - cfg.agreement_good
        # np.clip's rule, min(max(x, 0), 1), without its wrapper's cost.
        agreement = np.minimum(
            np.maximum((cfg.agreement_bad - self._disagreement) / span, 0.0), 1.0
        )
        agreement = np.where(np.isnan(self._disagreement), 0.5, agreement)
        lost_for = timestamp - self._last_seen  # NaN for a bone never seen (its share is 1)
        if cfg.hold_s == 0.0:
            fade = np.ones(skeleton.NUM_BONES)
        else:
            fade = 1.0 - np.exp(-np.maximum(lost_for, 0.0) / cfg.hold_s)
        return np.where(np.isnan(self._last_seen), 1.0, agreement * fade)

    def update(
        self, database: np.ndarray, sensor: np.ndarray, trust: np.ndarray, timestamp: float
    ) -> np.ndarray:
        """Fuse one frame.

        Parameters
        ----------
        database : ndarray, shape (20, 3)
            The database reconstruction in the output's definitions.
        sensor : ndarray, shape (20, 3)
            The sensor's joints in the output's definitions (labels already fixed).
        trust : ndarray, shape (20,)
            This frame's :class:`SensorTrust`.
        timestamp : float

        Returns
        -------
        ndarray, shape (20, 3), float64
        """
        cfg = self.config
        database = np.asarray(database, dtype=np.float64)
        trust = np.asarray(trust, dtype=np.float64)
        filtered = np.asarray(
            self._filter.update_tracked(np.asarray(sensor, dtype=np.float64), timestamp),
            dtype=np.float64,
        )
        provisional = np.where(trust[:, None] > 0.5, filtered, database)
        sensor_bones = np.ascontiguousarray(
            pose_utils.bone_vectors(filtered)
            if self.bone_model is None
            else self.bone_model.bone_vectors(provisional),
            dtype=np.float64,
        )
        step = 0.0 if self._last_timestamp is None else timestamp - self._last_timestamp
        self._last_timestamp = timestamp
        keep = np.exp(-max(step, 0.0) / cfg.agreement_s)
        compiled = compiled_module("fpg_gym.reconstruct.compiled_fusion")
        if compiled is not None:  # three calls around numpy's exp, frames and solve
            bone_trust, estimate, database_units, sensor_units = compiled.fusion_bone_terms(
                np.ascontiguousarray(trust),
                np.ascontiguousarray(database),
                sensor_bones,
                skeleton.BONES,
                self._length_sum,
                self._length_count,
                self._disagreement,
                keep,
            )
            seen = bone_trust > 0.9
            lengths = self._settler.update(estimate, timestamp)
            self._last_seen = np.where(seen, timestamp, self._last_seen)
            bones = compiled.fusion_bones(
                joint_frames(provisional)[_PARENT_BONE],
                self._held,
                database_units,
                sensor_units,
                self.database_share(timestamp),
                bone_trust,
                lengths,
            )
            pose = fuse_positions(
                filtered, trust, database, bones, cfg.bone_weight, cfg.database_weight
            )
            pose = np.ascontiguousarray(pose)
            compiled.held_directions(
                pose, joint_frames(pose)[_PARENT_BONE], skeleton.BONES, bone_trust, self._held
            )
        else:
            pose, lengths = self._fuse(
                database, filtered, trust, provisional, sensor_bones, keep, timestamp
            )
        pose = np.asarray(self._output_filter.update_tracked(pose, timestamp), dtype=np.float64)
        if cfg.lengths == "retarget":
            return np.asarray(pose_utils.retarget(pose, lengths), dtype=np.float64)
        if cfg.lengths == "solve":  # the same directions at the settled lengths, stiffly
            own = _with_lengths(pose_utils.bone_vectors(pose), lengths)
            return fuse_positions(pose, trust, database, own, 100.0, cfg.database_weight)
        return pose

    def _fuse(
        self,
        database: np.ndarray,
        filtered: np.ndarray,
        trust: np.ndarray,
        provisional: np.ndarray,
        sensor_bones: np.ndarray,
        keep: float,
        timestamp: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`update`'s fused pose before the output filter and the settled lengths, the
        state updated (the definition of its compiled calls)."""
        cfg = self.config
        bone_trust = np.minimum(trust[_PARENT_BONE], trust[_CHILD_BONE])
        seen = bone_trust > 0.9
        database_bones = pose_utils.bone_vectors(database)
        database_norms = np.linalg.norm(database_bones, axis=-1)
        sensor_norms = np.linalg.norm(sensor_bones, axis=-1)
        database_units = _unit(database_bones, database_norms)
        sensor_units = _unit(sensor_bones, sensor_norms)
        # The user's lengths: the mean of the seen (modelled) bones, then the settling rule.
        self._length_sum += np.where(seen, sensor_norms, 0.0)
        self._length_count += seen
        lengths = np.where(
            self._length_count > 0,
            self._length_sum / np.maximum(self._length_count, 1.0),
            database_norms,
        )
        lengths = self._settler.update(lengths, timestamp)
        # How well the database reproduces each bone while the sensor sees it.
        gap = np.linalg.norm(database_units - sensor_units, axis=-1)
        mixed = np.where(
            np.isnan(self._disagreement), gap, keep * self._disagreement + (1.0 - keep) * gap
        )
        self._disagreement = np.where(seen, mixed, self._disagreement)
        # A lost bone: the database's, or the held one turned with its parent's frame.
        parent_frames = joint_frames(provisional)[_PARENT_BONE]  # (19, 3, 3)
        held = np.einsum("bij,bj->bi", parent_frames, self._held)
        held = np.where(np.isnan(held), database_units, held)
        self._last_seen = np.where(seen, timestamp, self._last_seen)
        share = self.database_share(timestamp)[:, None]
        lost = share * database_units + (1.0 - share) * held
        weight = bone_trust[:, None]
        bones = weight * (sensor_units * lengths[:, None]) + (1.0 - weight) * _with_lengths(
            lost, lengths
        )
        pose = fuse_positions(
            filtered, trust, database, bones, cfg.bone_weight, cfg.database_weight
        )
        # Remember each seen bone's direction in its parent's frame, for when it is lost.
        local = np.einsum(
            "bji,bj->bi", joint_frames(pose)[_PARENT_BONE], _unit(pose_utils.bone_vectors(pose))
        )
        self._held = np.where(seen[:, None], local, self._held)
        return pose, lengths


def _unit(vectors: np.ndarray, norms: np.ndarray | None = None) -> np.ndarray:
    """``vectors / max(|vectors|, 1e-9)`` row by row (``norms``: their lengths, if known)."""
    if norms is None:
        norms = np.linalg.norm(vectors, axis=-1)
    return np.asarray(vectors / np.maximum(norms[..., None], 1e-9))


def _with_lengths(vectors: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    return _unit(vectors) * lengths[:, None]
