"""Parameters of the simulated Kinect's errors, each with where it comes from.

Two groups:

:class:`NoiseModel` — errors of joints the sensor sees:

* a static offset per joint and recording: the Kinect's joint centres are not the mocap joint
  centres (the skeleton is fitted to a depth silhouette; Shotton et al. 2011, "Real-time human
  pose recognition in parts from single depth images", CVPR, and the joint-centre differences
  against marker-based capture reported by Plantard et al. 2015, "Pose estimation with a Kinect
  for ergonomic studies", Sensors 15(1));
* a pose-dependent offset: the fitted joint centre shifts as the limb turns (Kinect joint
  errors depend on the posture, Plantard et al. 2015); modelled as a fixed random linear map
  of the direction of the bone ending at the joint, so it changes smoothly with the motion and
  makes bone lengths vary with the pose, as the real MSRC-12 arm bones do (2-3 cm std while
  the arms are raised and lowered);
* a slow wander per joint, independent between joints (every joint is estimated on its own from
  its body-part pixels, Shotton 2011), which makes bone lengths vary over time (Shum 2013 §IV
  builds its kinematic reliability on exactly this); it is low-pass (two first-order
  filters) because the SDK's joint filter smooths the stream (Kinect SDK
  ``NUI_TRANSFORM_SMOOTH_PARAMETERS`` / Holt double-exponential smoothing);
* white depth noise growing with the square of the distance along the optical axis: Khoshelham
  & Elberink 2012, "Accuracy and resolution of Kinect depth data for indoor mapping
  applications", Sensors 12(2): sigma_Z = (m / (f b)) Z^2 sigma_d, about 1.5 mm Z^2 per depth
  pixel (4 cm at 5 m); a joint averages many pixels, so its share is scaled down
  (``depth_coeff``);
* small white tracker noise, larger at the extremities (hands and feet are the least stable
  joints in the real MSRC-12 and Kinect v2 streams of ``../shared/data``);
* more jitter when a joint is partly hidden (fewer pixels vote for it).

:class:`OcclusionModel` — what the sensor reports for joints it does not see (Kinect SDK
``JointTrackingState``/``TrackingState``: *Inferred* "the joint data is inferred and confidence
in the position data is lower", *NotTracked* "the joint is not tracked"; the introductions of
Shum 2013 and FPG 2016 describe the failure modes under occlusion):

* hidden joints are reported inferred, placed by the tracker's body model: the bone to the
  parent freezes in its last seen direction, swings to a wrong direction or collapses towards
  the parent (shrinks), and drifts around that; inferred joints are calm most
  of the time but jump now and then (in the real ``joints.csv`` stream the inferred legs move
  1-2 mm in a median frame but 0.2-0.4 m in the worst 1 % of frames, and their mean
  acceleration is about 3.5 times that of the tracked joints); long occlusions may end as not
  tracked;
* false positives: a joint hidden by an object often snaps onto the object's surface and is
  still reported tracked (body parts are recognised from depth pixels, Shotton 2011, so an
  object's pixels next to a hidden part can be labelled as that part; FPG 2016 §1: "partial
  or total occlusion strongly affects the recognition rate");
* when too few joints are visible the skeleton is lost for the frame;
* left/right confusion: the tracker is made for a user facing the sensor (FPG 2016 §1: the
  Kinect "should be placed directly in front of the user"), so a user who turns side-on gets
  limbs swapped for a while, and a user who turns the back to it is reported mirrored. The
  real files of ``../shared/data`` are all frontal, so the rates here are not measured.

How the defaults were chosen: jitter, bone-length variation and the share of inferred joints
were matched to the real MSRC-12 and Kinect v2 streams (``scripts/realism.py`` prints both side
by side). The static and pose-dependent offsets and the size of the occlusion errors cannot be
measured without ground truth; they were set so that the raw error lands in the ranges the
papers measured against optical motion capture (Shum 2013: 9.6-12.4 cm; FPG 2016: 15 cm with
heavy occlusion). They were never tuned on reconstruction results.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from fpg_gym.core import skeleton

__all__ = ["JOINT_GROUP", "NoiseModel", "OcclusionModel"]

_GROUP_OF: dict[str, str] = {
    "HipCenter": "core",
    "Spine": "core",
    "ShoulderCenter": "core",
    "Head": "core",
    "ShoulderLeft": "core",
    "ShoulderRight": "core",
    "HipLeft": "core",
    "HipRight": "core",
    "ElbowLeft": "mid",
    "ElbowRight": "mid",
    "KneeLeft": "mid",
    "KneeRight": "mid",
    "WristLeft": "distal",
    "WristRight": "distal",
    "AnkleLeft": "distal",
    "AnkleRight": "distal",
    "HandLeft": "end",
    "HandRight": "end",
    "FootLeft": "end",
    "FootRight": "end",
}
#: Joint group of each Kinect-20 joint: core (torso, head, shoulders, hips), mid (elbows,
#: knees), distal (wrists, ankles), end (hands, feet).
JOINT_GROUP: tuple[str, ...] = tuple(_GROUP_OF[name] for name in skeleton.JOINT_NAMES)
_GROUPS = ("core", "mid", "distal", "end")


def _per_joint(values: dict[str, float]) -> np.ndarray:
    return np.array([values[group] for group in JOINT_GROUP], dtype=np.float64)


def _check_groups(name: str, values: dict[str, float]) -> None:
    if set(values) != set(_GROUPS):
        raise ValueError(f"{name}: expected the groups {_GROUPS}, got {sorted(values)}")
    if any(not (np.isfinite(v) and v >= 0) for v in values.values()):
        raise ValueError(f"{name}: expected non-negative numbers, got {values}")


@dataclass(frozen=True)
class NoiseModel:
    """Errors of seen joints, per joint group (metres unless stated).

    Attributes
    ----------
    bias_sigma : dict
        Std of the static per-joint offset drawn once per recording (per axis).
    pose_bias_sigma : dict
        Std of the entries of each joint's random 3x3 map from its bone direction (unit vector)
        to an offset, drawn once per recording.
    wander_sigma : dict
        Std of the slow, independent per-joint wander (per axis).
    wander_tau_s : float
        Time constant of each of the two low-pass stages of the wander, seconds.
    white_sigma : dict
        Std of the white tracker noise (per axis).
    depth_coeff : float
        White noise along the optical axis: ``depth_coeff * Z**2`` (Z in metres).
    partial_gain : float
        White noise is multiplied by ``1 + partial_gain * (1 - visible)`` where ``visible`` is
        the joint's visible share.
    """

    bias_sigma: dict[str, float] = field(
        default_factory=lambda: {"core": 0.02, "mid": 0.025, "distal": 0.025, "end": 0.03}
    )
    pose_bias_sigma: dict[str, float] = field(
        default_factory=lambda: {"core": 0.006, "mid": 0.012, "distal": 0.012, "end": 0.012}
    )
    wander_sigma: dict[str, float] = field(
        default_factory=lambda: {"core": 0.004, "mid": 0.008, "distal": 0.009, "end": 0.011}
    )
    wander_tau_s: float = 0.25
    white_sigma: dict[str, float] = field(
        default_factory=lambda: {"core": 0.0001, "mid": 0.0003, "distal": 0.001, "end": 0.0025}
    )
    depth_coeff: float = 0.4e-4
    partial_gain: float = 2.0

    def __post_init__(self) -> None:
        for name in ("bias_sigma", "pose_bias_sigma", "wander_sigma", "white_sigma"):
            _check_groups(name, getattr(self, name))
        if not self.wander_tau_s > 0:
            raise ValueError(f"wander_tau_s: expected a positive time, got {self.wander_tau_s}")
        if self.depth_coeff < 0 or self.partial_gain < 0:
            raise ValueError("depth_coeff and partial_gain must be non-negative")

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly parameters."""
        return asdict(self)

    def sample(
        self,
        rng: np.random.Generator,
        truth: np.ndarray,
        fps: float,
        visible: np.ndarray,
    ) -> np.ndarray:
        """Noise of every joint in every frame, camera space ``(T, 20, 3)``.

        Parameters
        ----------
        rng : numpy.random.Generator
        truth : ndarray, shape (T, 20, 3)
            True joint positions in camera space (metres); Z is the depth.
        fps : float
            Frame rate of the stream.
        visible : ndarray, shape (T, 20)
            Visible share of each joint in [0, 1] (1 when occlusion is off, and for hidden
            joints, whose errors come from :class:`OcclusionModel`).
        """
        joints = skeleton.NUM_JOINTS
        truth = np.asarray(truth, dtype=np.float64)
        count, depth = len(truth), truth[..., 2]
        bias = rng.normal(size=(joints, 3)) * _per_joint(self.bias_sigma)[:, None]
        pose_map = rng.normal(size=(joints, 3, 3)) * _per_joint(self.pose_bias_sigma)[:, None, None]
        a = float(np.exp(-1.0 / (self.wander_tau_s * fps)))
        burn = int(np.ceil(6 * self.wander_tau_s * fps))
        raw = rng.normal(size=(count + burn, joints, 3))
        wander = _low_pass2(raw, a)[burn:] * _per_joint(self.wander_sigma)[None, :, None]
        gain = 1.0 + self.partial_gain * (1.0 - np.clip(visible, 0.0, 1.0))
        white = rng.normal(size=(count, joints, 3)) * (
            _per_joint(self.white_sigma)[None, :, None] * gain[..., None]
        )
        depth_noise = rng.normal(size=(count, joints)) * self.depth_coeff * depth**2 * gain
        pose_bias = np.einsum("jab,tjb->tja", pose_map, _bone_directions(truth))
        noise = bias[None] + pose_bias + wander + white
        noise[..., 2] += depth_noise
        return noise


_SPINE = skeleton.joint_index("Spine")


def _bone_directions(positions: np.ndarray) -> np.ndarray:
    """Unit direction ``(T, 20, 3)`` of the bone ending at each joint (root: root -> Spine)."""
    parents = np.where(skeleton.PARENTS >= 0, skeleton.PARENTS, skeleton.ROOT)
    vectors = positions - positions[:, parents]
    vectors[:, skeleton.ROOT] = positions[:, _SPINE] - positions[:, skeleton.ROOT]
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return np.where(norms > 1e-9, vectors / np.maximum(norms, 1e-9), 0.0)


def _low_pass2(white: np.ndarray, a: float) -> np.ndarray:
    """Two cascaded first-order low-pass filters along axis 0, scaled to unit variance.

    For unit white input, ``y[t] = a y[t-1] + (1 - a) x[t]`` applied twice has the stationary
    variance ``(1 - a)^4 (1 + a^2) / (1 - a^2)^3``.
    """
    from scipy.signal import lfilter

    once = lfilter([1.0 - a], [1.0, -a], white, axis=0)
    twice = lfilter([1.0 - a], [1.0, -a], once, axis=0)
    variance = (1.0 - a) ** 4 * (1.0 + a * a) / (1.0 - a * a) ** 3
    return np.asarray(twice / np.sqrt(variance))


@dataclass(frozen=True)
class OcclusionModel:
    """What the sensor reports for hidden joints (see the module docstring for sources).

    A hidden joint is placed by the tracker's body model, not seen: its *bone* (the vector from
    its parent) keeps roughly its length but gets the wrong direction or shrinks. Per hidden
    episode one behaviour is drawn: the bone *freezes* (keeps the direction it had when last
    seen while the body moves on), *swings* to a wrong direction (rotated by an angle drawn in
    ``swing_deg``), or *collapses* towards the parent (shrinks to a share drawn in
    ``collapse_shrink``). The reported bone approaches that target at ``approach_rate`` per
    frame and drifts around it (a random walk pulled back to the target). A hidden joint whose
    parent is hidden too moves with its parent, so whole limbs swing. Separately, a joint hidden
    by a scene object close to it may snap onto the object (false positive, reported tracked).

    Attributes
    ----------
    hidden_below : float
        A joint whose visible share is below this is hidden.
    inferred_sigma : float
        Std (metres, per axis) of the white vibration of an inferred joint.
    glitch_probability : float
        Per-frame chance that an inferred limb joint (elbow, wrist, hand, knee, ankle, foot)
        jumps; torso, head, shoulders and hips are held by the body model and do not.
    glitch_deg : float
        Std of the angle (degrees) by which such a jump turns the joint's bone: the body model
        keeps bone lengths, so a glitch moves the joint (and its hidden children) sideways; it
        then relaxes back at ``approach_rate``.
    snap_probability : float
        Chance that a joint hidden by a scene object snaps onto the object (reported tracked).
    snap_max_distance : float
        Only objects whose hidden surface point lies within this distance (metres) of the joint
        can capture it (the depth pixels must be near the body part to be labelled as it).
    freeze_probability, swing_probability : float
        Chances of the freeze and swing behaviours; the rest of the episodes collapse.
    swing_deg : tuple of 2 floats
        Range of the wrong angle of a swinging bone, degrees.
    collapse_shrink : tuple of 2 floats
        Range of the share of the bone length kept by a collapsing joint.
    approach_rate : float
        Per-frame fraction of the way the reported bone moves towards its target.
    drift_sigma : float
        Std (metres per frame, per axis) of the random walk of a hidden joint's bone.
    recovery : float
        Per-frame factor of the remaining occlusion error once the joint is seen again.
    not_tracked_probability : float
        Chance that a hidden episode turns to *not tracked* after ``not_tracked_after`` frames.
    not_tracked_after : tuple of 2 ints
        Range of frames after which it does.
    min_visible_joints : int
        Below this many seen joints the skeleton is lost (every joint not tracked).
    swap_start_deg : float
        Side-on angle (between the body's heading and the direction to the camera) above which
        limbs may be swapped left/right.
    swap_rate : float
        Per-frame chance of a swap episode at 90° (linear from ``swap_start_deg``).
    swap_mean_frames : float
        Mean length of a swap episode, frames.
    mirror_beyond_deg : float
        Beyond this angle (back to the sensor) the whole skeleton is reported mirrored.
    flicker_rate : float
        Per-frame chance that a seen joint is reported inferred for a short run (the tracking
        state of a real Kinect v2 flickers: in ``kinect_v2_states/joints.csv`` half of the
        inferred runs last 4 frames or less). 0 in the papers' scenarios.
    flicker_mean_frames : float
        Mean length of such a run, frames (geometric).
    inferred_calm : float
        Share of the previous reported position an inferred joint keeps each frame (an
        exponential smoothing, 0 = off): the tracker's body model moves inferred joints more
        calmly than it reports seen ones (in ``joints.csv`` a joint's inferred frames have 0.6
        times the jitter of its tracked frames).
    """

    hidden_below: float = 0.3
    inferred_sigma: float = 0.002
    glitch_probability: float = 0.02
    glitch_deg: float = 12.0
    snap_probability: float = 0.5
    snap_max_distance: float = 0.25
    freeze_probability: float = 0.25
    swing_probability: float = 0.6
    swing_deg: tuple[float, float] = (25.0, 70.0)
    collapse_shrink: tuple[float, float] = (0.6, 0.9)
    approach_rate: float = 0.15
    drift_sigma: float = 0.002
    recovery: float = 0.6
    not_tracked_probability: float = 0.3
    not_tracked_after: tuple[int, int] = (10, 60)
    min_visible_joints: int = 4
    swap_start_deg: float = 50.0
    swap_rate: float = 0.05
    swap_mean_frames: float = 20.0
    mirror_beyond_deg: float = 110.0
    flicker_rate: float = 0.0
    flicker_mean_frames: float = 4.0
    inferred_calm: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "hidden_below",
            "glitch_probability",
            "snap_probability",
            "freeze_probability",
            "swing_probability",
            "approach_rate",
            "recovery",
            "not_tracked_probability",
            "swap_rate",
            "flicker_rate",
        ):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}: expected a value in [0, 1], got {value}")
        if self.freeze_probability + self.swing_probability > 1.0:
            raise ValueError("freeze_probability + swing_probability must not exceed 1")
        low, high = self.collapse_shrink
        if not 0.0 <= low <= high <= 1.0:
            raise ValueError(f"collapse_shrink: expected 0 <= low <= high <= 1, got {low}, {high}")
        low, high = self.swing_deg
        if not 0.0 <= low <= high <= 180.0:
            raise ValueError(f"swing_deg: expected 0 <= low <= high <= 180, got {low}, {high}")
        first, last = self.not_tracked_after
        if not 0 <= first <= last:
            raise ValueError(f"not_tracked_after: expected 0 <= first <= last, got {first}, {last}")
        if not 0.0 <= self.swap_start_deg <= 90.0 <= self.mirror_beyond_deg <= 180.0:
            raise ValueError("expected 0 <= swap_start_deg <= 90 <= mirror_beyond_deg <= 180")
        if self.swap_mean_frames < 1:
            raise ValueError(f"swap_mean_frames: expected >= 1, got {self.swap_mean_frames}")
        if self.flicker_mean_frames < 1:
            raise ValueError(f"flicker_mean_frames: expected >= 1, got {self.flicker_mean_frames}")
        if not 0.0 <= self.inferred_calm < 1.0:
            raise ValueError(f"inferred_calm: expected a value in [0, 1), got {self.inferred_calm}")
        for name in ("inferred_sigma", "glitch_deg", "drift_sigma", "snap_max_distance"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: expected >= 0, got {getattr(self, name)}")
        if self.min_visible_joints < 0:
            raise ValueError(f"min_visible_joints: expected >= 0, got {self.min_visible_joints}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly parameters."""
        return asdict(self)
