"""Per-joint reliability of a Kinect stream (Shum 2013 §IV, FPG 2016 §5).

Three terms per joint and frame, each in ``[0, 1]`` (1 = reliable):

* **behaviour** ``Rb``: a joint that vibrates reverses its direction of motion from frame to
  frame. With ``theta`` the angle between successive displacement vectors (0 when either is
  shorter than ``d_min`` = 3 cm), ``Rb = 1 - clamp(mean_{last f_b frames}(theta) - theta_floor,
  0, theta_roof - theta_floor) / (theta_roof - theta_floor)`` with ``f_b = 3``,
  ``theta_floor = 90 deg``, ``theta_roof = 135 deg``. Displacements are measured relative to the
  root (HipCenter), so that walking across the room does not hide a vibrating hand; the root
  itself uses its camera-space displacement.
* **kinematic** ``Rk``: ``1 - mean over the bones at the joint of min(|l - l_ref| / l_ref, 1)``,
  where ``l_ref`` are the user's reference bone lengths.
* **tracking** ``Rt``: 1 when the sensor reports the joint as tracked (state 2), else 0
  (inferred or not tracked).

The reliability is ``R = sum_{f=0..5} w(f) * min(Rb, Rk, Rt)(t - f)`` with Gaussian weights
``w(f) ~ exp(-f^2 / (2 sigma^2))`` over the last 6 frames, newest heaviest, normalised to sum to 1
over the frames available so far (``sigma = 2`` frames by default). A frame in which no joint is
tracked or inferred (no body in view) has ``R = 0`` everywhere and restarts the behaviour term.

Reference bone lengths
----------------------
Shum calibrates the bone lengths on frames where the user stands in a T-pose or a neutral pose
with every joint tracked, and keeps refining them while such frames occur. Here every frame whose
joints are all tracked (the hand tips may be only inferred: Kinects often infer them, and some
exports have none) and whose torso, arm and leg bones point within ``neutral_tolerance_deg`` of
the neutral standing pose (arms down) or of a T-pose (arms out) is a *calibration frame*; the
reference is the per-bone **median over the most recent
``max_reference_frames`` calibration frames** (robust to the odd spike). Until the first
calibration frame a documented fallback is used (``config.fallback``):

1. ``"scaled-prior"`` (default): the prior proportions (``prior_lengths``: the reconstructor
   passes its database's median bone lengths; :data:`fpg_gym.core.poses.DEFAULT_BONE_LENGTHS`
   otherwise) times one size factor, the median ratio of every recent tracked bone sample (both
   joints tracked) to its prior length. Kinect bone lengths of a moving, partly occluded user
   are biased and noisy per bone (2-3 cm on the simulator's ``*-many`` streams even after
   hundreds of frames); one pooled factor is far steadier.
2. ``"tracked-median"``: per bone, the median length over the recent frames in which both of
   its joints were tracked (bones never seen: the scaled prior).

Before any tracked bone, the prior is scaled by the current frame's height (vertical extent)
over the prior rest pose's height, clamped to ``[0.5, 1.5]`` (``"prior-height"``).
:attr:`ReliabilityEstimator.reference_source` says which one is in use (``"neutral"`` once
calibrated). Fixed lengths can be given instead (``reference_lengths=``, ``"given"``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.skeleton import TRACKED

# (20, 19) incidence matrix, rows normalised: Rk(j) = 1 - INCIDENCE @ deviation (mean over bones).
_INCIDENCE = np.zeros((skeleton.NUM_JOINTS, skeleton.NUM_BONES))
_INCIDENCE[skeleton.BONES[:, 0], np.arange(skeleton.NUM_BONES)] = 1.0
_INCIDENCE[skeleton.BONES[:, 1], np.arange(skeleton.NUM_BONES)] = 1.0
_INCIDENCE /= _INCIDENCE.sum(axis=1, keepdims=True)
_INCIDENCE.flags.writeable = False

_ARM_CHAIN_NAMES = {
    "left": ("ElbowLeft", "WristLeft"),
    "right": ("ElbowRight", "WristRight"),
}
# Bones checked against the rest pose whatever the arms do: spine, neck, head, shoulders, hips,
# thighs and shins (hands and feet are too noisy on a Kinect to be informative).
_BODY_CHECK_JOINTS = (
    "Spine",
    "ShoulderCenter",
    "Head",
    "ShoulderLeft",
    "ShoulderRight",
    "HipLeft",
    "HipRight",
    "KneeLeft",
    "AnkleLeft",
    "KneeRight",
    "AnkleRight",
)
_BODY_BONES = np.array(
    [skeleton.BONE_OF_JOINT[skeleton.joint_index(n)] for n in _BODY_CHECK_JOINTS]
)
_LEFT_ARM_BONES = np.array(
    [skeleton.BONE_OF_JOINT[skeleton.joint_index(n)] for n in _ARM_CHAIN_NAMES["left"]]
)
_RIGHT_ARM_BONES = np.array(
    [skeleton.BONE_OF_JOINT[skeleton.joint_index(n)] for n in _ARM_CHAIN_NAMES["right"]]
)
# T-pose: the arm bones point sideways (the body's left is +X when facing +Z).
_T_LEFT = np.array([1.0, 0.0, 0.0])
_T_RIGHT = np.array([-1.0, 0.0, 0.0])


@dataclass(frozen=True)
class ReliabilityConfig:
    """Parameters of the reliability estimate (defaults from Shum §IV and FPG §5).

    Attributes
    ----------
    behaviour_frames : int
        ``f_b``: frames over which the direction-change angle is averaged (3).
    min_displacement_m : float
        ``d_min``: displacements shorter than this give ``theta = 0`` (0.03 m).
    theta_floor_deg, theta_roof_deg : float
        Angles where ``Rb`` starts to fall and reaches 0 (90 and 135 degrees).
    smoothing_frames : int
        Frames of the Gaussian temporal filter on ``min(Rb, Rk, Rt)`` (6).
    smoothing_sigma : float
        Standard deviation of the Gaussian weights, in frames (2).
    neutral_tolerance_deg : float
        Largest angle between a bone and its neutral / T-pose direction in a calibration frame.
    max_reference_frames : int
        How many recent calibration (or tracked) frames the reference median uses.
    fallback : {"scaled-prior", "tracked-median"}
        Reference lengths before the first calibration frame (see the module docstring).
    """

    behaviour_frames: int = 3
    min_displacement_m: float = 0.03
    theta_floor_deg: float = 90.0
    theta_roof_deg: float = 135.0
    smoothing_frames: int = 6
    smoothing_sigma: float = 2.0
    neutral_tolerance_deg: float = 30.0
    max_reference_frames: int = 300
    fallback: str = "scaled-prior"

    def __post_init__(self) -> None:
        if self.fallback not in ("scaled-prior", "tracked-median"):
            raise ValueError(
                f"fallback: expected 'scaled-prior' or 'tracked-median', got {self.fallback!r}"
            )
        if self.behaviour_frames < 1:
            raise ValueError(f"behaviour_frames: expected >= 1, got {self.behaviour_frames}")
        if self.smoothing_frames < 1:
            raise ValueError(f"smoothing_frames: expected >= 1, got {self.smoothing_frames}")
        if not 0.0 <= self.theta_floor_deg < self.theta_roof_deg <= 180.0:
            raise ValueError(
                "theta_floor_deg/theta_roof_deg: expected 0 <= floor < roof <= 180, got "
                f"{self.theta_floor_deg}, {self.theta_roof_deg}"
            )
        if self.smoothing_sigma <= 0:
            raise ValueError(f"smoothing_sigma: expected > 0, got {self.smoothing_sigma}")
        if self.max_reference_frames < 1:
            raise ValueError(
                f"max_reference_frames: expected >= 1, got {self.max_reference_frames}"
            )

    def weights(self) -> np.ndarray:
        """Gaussian weights ``w(f)``, ``f = 0`` (newest) first, summing to 1."""
        f = np.arange(self.smoothing_frames, dtype=np.float64)
        w = np.exp(-(f**2) / (2.0 * self.smoothing_sigma**2))
        return w / w.sum()


@dataclass(frozen=True)
class ReliabilityTerms:
    """The reliability of one frame and each of its terms, all ``(20,)`` in ``[0, 1]``.

    Attributes
    ----------
    reliability : ndarray
        ``R``: the temporally smoothed minimum of the three terms (what the pipeline uses).
    behaviour, kinematic, tracking : ndarray
        ``Rb``, ``Rk`` and ``Rt`` of this frame.
    minimum : ndarray
        ``min(Rb, Rk, Rt)`` of this frame, before smoothing.
    reference_lengths : ndarray, shape (19,)
        The reference bone lengths ``Rk`` was computed with.
    reference_source : str
        ``"given"``, ``"neutral"``, ``"scaled-prior"``, ``"tracked-median"`` or
        ``"prior-height"``.
    calibration_frame : bool
        Whether this frame was used as a calibration frame.
    """

    reliability: np.ndarray
    behaviour: np.ndarray
    kinematic: np.ndarray
    tracking: np.ndarray
    minimum: np.ndarray
    reference_lengths: np.ndarray
    reference_source: str
    calibration_frame: bool = False


def behaviour_angles(
    displacement: np.ndarray, previous: np.ndarray, min_length: float
) -> np.ndarray:
    """Angle in radians between two displacement vectors per joint, 0 when either is short.

    Parameters
    ----------
    displacement, previous : ndarray, shape (..., 3)
        ``p(t) - p(t-1)`` and ``p(t-1) - p(t-2)``.
    min_length : float
        ``d_min``: vectors shorter than this give an angle of 0.
    """
    a = np.asarray(displacement, dtype=np.float64)
    b = np.asarray(previous, dtype=np.float64)
    if a.ndim == 2 and a.shape == b.shape and a.shape[1] == 3:
        compiled = compiled_module("fpg_gym.core.compiled_poses")
        if compiled is not None:  # one frame: one compiled call
            angles: np.ndarray = compiled.vector_angles(
                np.ascontiguousarray(a), np.ascontiguousarray(b), float(min_length)
            )
            return angles
    na = np.linalg.norm(a, axis=-1)
    nb = np.linalg.norm(b, axis=-1)
    ok = (na >= min_length) & (nb >= min_length)
    cos = np.einsum("...c,...c->...", a, b) / np.where(ok, na * nb, 1.0)
    return np.where(ok, np.arccos(np.clip(cos, -1.0, 1.0)), 0.0)


def behaviour_reliability(mean_angle: np.ndarray, config: ReliabilityConfig) -> np.ndarray:
    """``Rb`` from the mean direction-change angle (radians) over the last ``f_b`` frames."""
    floor, span = _theta_bounds(config)
    return 1.0 - np.minimum(np.maximum(np.asarray(mean_angle) - floor, 0.0), span) / span


@functools.lru_cache(maxsize=16)
def _theta_bounds(config: ReliabilityConfig) -> tuple[float, float]:
    """``Rb``'s floor angle and span, in radians."""
    floor = float(np.deg2rad(config.theta_floor_deg))
    return floor, float(np.deg2rad(config.theta_roof_deg)) - floor


def length_deviation(lengths: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Each bone's relative length error ``min(|l - l_ref| / l_ref, 1)`` (Shum §IV-B).

    Parameters
    ----------
    lengths : ndarray, shape (..., 19)
        Bone lengths of the frame(s).
    reference : ndarray, shape (19,)
        Reference bone lengths (positive).
    """
    reference = np.asarray(reference, dtype=np.float64)
    return np.minimum(np.abs(np.asarray(lengths) - reference) / np.maximum(reference, 1e-6), 1.0)


def kinematic_reliability(lengths: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``Rk`` per joint: 1 minus the mean relative length error of the bones at the joint
    (:func:`length_deviation`; shapes as there, ``(..., 20)`` out)."""
    return 1.0 - joint_means(length_deviation(lengths, reference))


def joint_means(values: np.ndarray) -> np.ndarray:
    """The mean over the bones at each joint of per-bone ``values`` ``(..., 19) -> (..., 20)``
    (a product with the skeleton's normalised incidence matrix)."""
    mean: np.ndarray = values @ _INCIDENCE.T
    return mean


def tracking_reliability(states: np.ndarray) -> np.ndarray:
    """``Rt``: 1 for tracked joints (state 2), 0 for inferred or not-tracked ones."""
    return (np.asarray(states) >= TRACKED).astype(np.float64)


#: Joints that must be tracked in a calibration frame: all but the hand tips.
_CALIBRATION_JOINTS = np.array(
    [j for j, name in enumerate(skeleton.JOINT_NAMES) if not name.startswith("Hand")]
)


def is_neutral_pose(pose: np.ndarray, tolerance_deg: float = 30.0) -> bool:
    """Whether a pose is near the neutral standing pose (arms down) or a T-pose.

    Torso, shoulder, hip and leg bones must point within ``tolerance_deg`` of
    :data:`fpg_gym.core.poses.REST_DIRECTIONS` (after normalisation); each arm's upper arm and
    forearm must point within the tolerance either straight down (neutral) or sideways (T-pose).
    """
    normalised, _ = pose_utils.normalise(np.asarray(pose, dtype=np.float64))
    vectors = pose_utils.bone_vectors(normalised.astype(np.float64))
    norms = np.linalg.norm(vectors, axis=-1)
    if np.any(norms < 1e-6):
        return False
    directions = vectors / norms[:, None]
    cos_tol = np.cos(np.deg2rad(tolerance_deg))  # as ReliabilityEstimator's
    rest = pose_utils.REST_DIRECTIONS
    if np.any(np.einsum("bc,bc->b", directions[_BODY_BONES], rest[_BODY_BONES]) < cos_tol):
        return False
    for bones, sideways in ((_LEFT_ARM_BONES, _T_LEFT), (_RIGHT_ARM_BONES, _T_RIGHT)):
        down = np.einsum("bc,bc->b", directions[bones], rest[bones]) >= cos_tol
        out = directions[bones] @ sideways >= cos_tol
        if not (np.all(down) or np.all(out)):
            return False
    return True


#: :attr:`ReliabilityEstimator.reference_source` by the code the compiled frame keeps.
_SOURCES = ("given", "neutral", "scaled-prior", "tracked-median", "prior-height")
_FACING = np.array(pose_utils.FACING_JOINTS)
_ARM_BONES = np.stack([_LEFT_ARM_BONES, _RIGHT_ARM_BONES])
_SIDEWAYS = np.stack([_T_LEFT, _T_RIGHT])


class SortedWindow:
    """The finite values of a window of rows, kept sorted, for the window's median each frame.

    :meth:`median` equals ``np.nanmedian`` of the rows added and not removed, to the last bit
    (the middle value, or the mean of the two middle values); adding or removing a row costs a
    search and a copy instead of a partition of the whole window.
    """

    def __init__(self) -> None:
        self.values = np.empty(0)

    def __len__(self) -> int:
        return len(self.values)

    def add(self, row: np.ndarray) -> None:
        """Add the finite values of ``row``."""
        new = np.sort(row[np.isfinite(row)])
        compiled = compiled_module("fpg_gym.reconstruct.compiled_reliability")
        if compiled is not None:  # one merge instead of np.insert's index bookkeeping
            self.values = compiled.merge_sorted(self.values, new)
            return
        self.values = np.insert(self.values, np.searchsorted(self.values, new), new)

    def remove(self, row: np.ndarray) -> None:
        """Remove the finite values of ``row``, added before (each value once per occurrence)."""
        old = np.sort(row[np.isfinite(row)])
        compiled = compiled_module("fpg_gym.reconstruct.compiled_reliability")
        if compiled is not None:
            self.values = compiled.remove_sorted(self.values, old)
            return
        # Equal values of the row take consecutive places: the k-th copy the k-th one found.
        rank = np.arange(len(old)) - np.searchsorted(old, old)
        self.values = np.delete(self.values, np.searchsorted(self.values, old) + rank)

    def median(self) -> float:
        """The median of the values (NaN when there are none)."""
        n = len(self.values)
        if n == 0:
            return float("nan")
        middle = n // 2
        if n % 2:
            return float(self.values[middle])
        return float((self.values[middle - 1] + self.values[middle]) / 2.0)


class ReliabilityEstimator:
    """Online per-joint reliability of a Kinect stream, one frame at a time.

    Parameters
    ----------
    config : ReliabilityConfig, optional
    reference_lengths : array_like, shape (19,), optional
        Fixed reference bone lengths; when omitted they are estimated from the stream (see the
        module docstring).
    prior_lengths : array_like, shape (19,), optional
        Body proportions of the fallback (:data:`fpg_gym.core.poses.DEFAULT_BONE_LENGTHS` by
        default; the reconstructor passes its database's median bone lengths).

    Examples
    --------
    >>> import numpy as np
    >>> from fpg_gym.core import poses
    >>> est = ReliabilityEstimator()
    >>> terms = est.update(poses.rest_pose(), np.full(20, 2))  # one frame, every joint tracked
    >>> terms.reliability.shape
    (20,)
    """

    def __init__(
        self,
        config: ReliabilityConfig | None = None,
        reference_lengths: np.ndarray | None = None,
        prior_lengths: np.ndarray | None = None,
    ) -> None:
        self.config = config or ReliabilityConfig()
        prior = pose_utils.DEFAULT_BONE_LENGTHS if prior_lengths is None else prior_lengths
        self._prior = np.asarray(prior, dtype=np.float64).copy()
        if self._prior.shape != (skeleton.NUM_BONES,) or not np.all(self._prior > 0):
            raise ValueError(
                f"prior_lengths: expected 19 positive lengths, got shape {self._prior.shape}"
            )
        self._prior_height = float(pose_utils.height(pose_utils.rest_pose(self._prior)))
        self._cos_tolerance = float(np.cos(np.deg2rad(self.config.neutral_tolerance_deg)))
        weights = self.config.weights()
        # The filter's weights over the first n frames of a stream, normalised to sum to 1.
        self._filters = [weights[:n] / weights[:n].sum() for n in range(1, len(weights) + 1)]
        if reference_lengths is not None:
            fixed = np.array(reference_lengths, dtype=np.float64)  # a writable copy
            if fixed.shape != (skeleton.NUM_BONES,) or not np.all(fixed > 0):
                raise ValueError(
                    f"reference_lengths: expected 19 positive lengths, got shape {fixed.shape}"
                )
            self._fixed: np.ndarray | None = fixed
        else:
            self._fixed = None
        # reliability_frame's arguments after the stream's state (the same every frame)
        floor, span = _theta_bounds(self.config)
        self._frame_constants = (
            self._prior,
            self._fixed is not None,
            self.config.fallback == "tracked-median",
            float(self.config.min_displacement_m),
            floor,
            span,
            self._cos_tolerance,
            self._prior_height,
            TRACKED,
            skeleton.ROOT,
            _CALIBRATION_JOINTS,
            _FACING,
            pose_utils.DEGENERATE_LINE_M,
            skeleton.BONES,
            pose_utils.REST_DIRECTIONS,
            _BODY_BONES,
            _ARM_BONES,
            _SIDEWAYS,
        )
        self.reset()

    # ------------------------------------------------------------------ state

    def reset(self, *, keep_reference: bool = False) -> None:
        """Forget the stream; with ``keep_reference`` keep the calibrated bone lengths."""
        cfg = self.config
        # The motion history: the last two root-relative frames and the last f_b angle vectors
        # (oldest first), the last smoothing_frames minima (newest first) and how many of each
        # are kept (with the calibration and tracked frames and the reference's source code, the
        # counts the compiled frame updates in place).
        self._recent = np.zeros((2, skeleton.NUM_JOINTS, 3))
        self._angles = np.zeros((cfg.behaviour_frames, skeleton.NUM_JOINTS))
        self._minima = np.zeros((cfg.smoothing_frames, skeleton.NUM_JOINTS))
        self._minima_count = 0
        counts = np.zeros(5, dtype=np.int64)
        if keep_reference:
            counts[2:] = self._counts[2:]
        else:
            cap = cfg.max_reference_frames
            self._neutral = np.empty((cap, skeleton.NUM_BONES))
            self._tracked = np.full((cap, skeleton.NUM_BONES), np.nan)
            self._ratios = SortedWindow()  # the finite values of _tracked / _prior
            self._reference: np.ndarray | None = None
            counts[4] = _SOURCES.index("given" if self._fixed is not None else "prior-height")
        self._counts: np.ndarray = counts

    def forget_motion(self) -> None:
        """Drop the motion history (after a gap in the stream) but keep the bone lengths."""
        self.reset(keep_reference=True)

    @property
    def reference_lengths(self) -> np.ndarray | None:
        """Current reference bone lengths ``(19,)`` (None before the first frame)."""
        if self._fixed is not None:
            return self._fixed.copy()
        return None if self._reference is None else self._reference.copy()

    @property
    def reference_source(self) -> str:
        """Where the reference lengths come from: see the module docstring."""
        return _SOURCES[self._counts[4]]

    @property
    def calibration_frames(self) -> int:
        """Calibration frames seen so far (capped at ``max_reference_frames``)."""
        return min(int(self._counts[2]), self.config.max_reference_frames)

    # ------------------------------------------------------------------ update

    def _update_reference(
        self, positions: np.ndarray, states: np.ndarray, lengths: np.ndarray
    ) -> bool:
        """The reference bone lengths after this frame (module docstring); whether the frame
        was a calibration frame."""
        counts = self._counts
        if self._fixed is not None:
            self._reference = self._fixed
            return False
        cap = self.config.max_reference_frames
        tracked = states >= TRACKED
        # Hand tips are often only inferred (and some exports have none): not required.
        calibration = bool(tracked[_CALIBRATION_JOINTS].all()) and is_neutral_pose(
            positions, self.config.neutral_tolerance_deg
        )
        if calibration:
            self._neutral[counts[2] % cap] = lengths
            counts[2] += 1
        both = tracked[skeleton.BONES[:, 0]] & tracked[skeleton.BONES[:, 1]] & (lengths > 1e-6)
        # The tracked samples serve until the first calibration frame (then the reference is
        # the calibration frames' median for good, until a reset forgets it).
        if both.any() and not counts[2]:
            slot = counts[3] % cap
            if counts[3] >= cap:  # the ring's oldest row leaves the window
                self._ratios.remove(self._tracked[slot] / self._prior)
            self._tracked[slot] = np.where(both, lengths, np.nan)
            self._ratios.add(self._tracked[slot] / self._prior)
            counts[3] += 1
        if counts[2]:
            if calibration or self.reference_source != "neutral":  # else the same median
                self._reference = np.median(self._neutral[: min(counts[2], cap)], axis=0)
            counts[4] = _SOURCES.index("neutral")
            return calibration
        prior = self._prior
        if counts[3]:
            # One size factor for the whole body: the median ratio of every tracked bone sample
            # to the prior (robust to a minority of wrong samples, needs no bone seen often).
            scale = self._ratios.median()
            if self.config.fallback == "tracked-median":
                rows = self._tracked[: min(counts[3], cap)]
                seen = np.any(np.isfinite(rows), axis=0)
                median = np.full(skeleton.NUM_BONES, np.nan)
                median[seen] = np.nanmedian(rows[:, seen], axis=0)
                self._reference = np.where(seen, median, prior * scale)
                counts[4] = _SOURCES.index("tracked-median")
            else:
                self._reference = prior * scale
                counts[4] = _SOURCES.index("scaled-prior")
        else:
            scale = float(pose_utils.height(positions)) / self._prior_height
            scale = float(np.clip(scale, 0.5, 1.5)) if scale > 1e-3 else 1.0
            self._reference = prior * scale
            counts[4] = _SOURCES.index("prior-height")
        return False

    def _behaviour(self, positions: np.ndarray) -> np.ndarray:
        """``Rb`` of the frame (Shum §IV-A), the motion history updated: root-relative
        displacements, the root's own in camera space."""
        counts, recent, angles = self._counts, self._recent, self._angles
        local = positions - positions[skeleton.ROOT]
        local[skeleton.ROOT] = positions[skeleton.ROOT]
        if counts[0] == 2:
            angle = behaviour_angles(
                local - recent[1], recent[1] - recent[0], self.config.min_displacement_m
            )
            if counts[1] == len(angles):  # the oldest leaves
                angles[:-1] = angles[1:]
                angles[-1] = angle
            else:
                angles[counts[1]] = angle
                counts[1] += 1
            recent[0] = recent[1]
            recent[1] = local
        else:
            recent[counts[0]] = local
            counts[0] += 1
        kept = int(counts[1])
        # The mean over the last f_b frames: the rows' sum in order, as np.mean sums them.
        mean_angle = (
            sum(angles[1:kept], angles[0]) / kept if kept else np.zeros(skeleton.NUM_JOINTS)
        )
        return behaviour_reliability(mean_angle, self.config)

    def update(
        self, positions: np.ndarray, states: np.ndarray, scale: np.ndarray | None = None
    ) -> ReliabilityTerms:
        """Reliability of the next frame.

        Parameters
        ----------
        positions : array_like, shape (20, 3)
            The frame's joint positions in camera space (metres).
        states : array_like, shape (20,)
            Tracking states: 2 tracked, 1 inferred, 0 not tracked.
        scale : ndarray, shape (20,), optional
            A factor of ``R`` after its filter (the fusion's trust; the other terms as they
            are).

        Returns
        -------
        ReliabilityTerms
        """
        positions = np.asarray(positions, dtype=np.float64)
        states = np.asarray(states)
        if positions.shape != (skeleton.NUM_JOINTS, 3):
            raise ValueError(f"positions: expected shape (20, 3), got {positions.shape}")
        if states.shape != (skeleton.NUM_JOINTS,):
            raise ValueError(f"states: expected shape (20,), got {states.shape}")
        cfg = self.config
        compiled = compiled_module("fpg_gym.reconstruct.compiled_reliability")
        if compiled is not None:  # one call up to the two matrix products, the same arithmetic
            behaviour, deviation, tracking, calibration, body = self._compiled_terms(
                compiled, positions, states
            )
        else:
            lengths = pose_utils.bone_lengths(positions)
            calibration = self._update_reference(positions, states, lengths)
            assert self._reference is not None
            behaviour = self._behaviour(positions)
            tracking = tracking_reliability(states)
            body = bool(skeleton.body_present(states))
        assert self._reference is not None

        # Kinematic (Shum §IV-B) and tracking state (FPG §5), the minimum entering the filter.
        kept = self._minima_count = min(self._minima_count + 1, cfg.smoothing_frames)
        minima = self._minima
        if compiled is not None:
            kinematic, minimum = compiled.newest_minimum(
                behaviour, joint_means(deviation), tracking, minima, kept
            )
        else:
            kinematic = kinematic_reliability(lengths, self._reference)
            minimum = np.minimum(np.minimum(behaviour, kinematic), tracking)
            minima[1:kept] = minima[: kept - 1]
            minima[0] = minimum

        # Gaussian temporal filter over the last 6 frames, newest heaviest.
        reliability = self._filters[kept - 1] @ minima[:kept]
        if not body:
            # No body in view: nothing the sensor says is reliable, whatever the filter holds,
            # and the positions must not enter the motion history.
            reliability = np.zeros(skeleton.NUM_JOINTS)
            self._counts[:2] = 0
        if scale is not None:
            reliability = reliability * scale
        return ReliabilityTerms(
            reliability=reliability,
            behaviour=behaviour,
            kinematic=kinematic,
            tracking=tracking,
            minimum=minimum,
            reference_lengths=self._reference.copy(),
            reference_source=self.reference_source,
            calibration_frame=calibration,
        )

    def _compiled_terms(
        self, compiled: Any, positions: np.ndarray, states: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, bool]:
        """:func:`fpg_gym.reconstruct.compiled_reliability.reliability_frame` on this stream's
        state: ``Rb``, the bones' deviations, ``Rt``, whether the frame calibrated, whether a
        body was in view."""
        if self._reference is None:
            self._reference = (
                self._fixed if self._fixed is not None else np.zeros(skeleton.NUM_BONES)
            )
        behaviour, deviation, tracking, window, calibration, body = compiled.reliability_frame(
            np.ascontiguousarray(positions),
            states,
            self._recent,
            self._angles,
            self._counts,
            self._neutral,
            self._tracked,
            self._ratios.values,
            self._reference,
            *self._frame_constants,
        )
        self._ratios.values = window
        return behaviour, deviation, tracking, calibration, body


def reliability_of_sequence(
    positions: np.ndarray,
    states: np.ndarray,
    config: ReliabilityConfig | None = None,
    reference_lengths: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Run :class:`ReliabilityEstimator` over a whole stream.

    Returns
    -------
    dict
        ``reliability``, ``behaviour``, ``kinematic``, ``tracking``, ``minimum`` as ``(T, 20)``
        arrays and ``reference_lengths`` as ``(T, 19)``.
    """
    positions = pose_utils.as_poses(positions, "positions", ndim=3)
    states = np.asarray(states)
    if states.shape != positions.shape[:2]:
        raise ValueError(f"states: expected shape {positions.shape[:2]}, got {states.shape}")
    estimator = ReliabilityEstimator(config, reference_lengths)
    frames = [estimator.update(p, s) for p, s in zip(positions, states, strict=True)]
    keys = ("reliability", "behaviour", "kinematic", "tracking", "minimum", "reference_lengths")
    return {k: np.stack([getattr(f, k) for f in frames]) for k in keys}
