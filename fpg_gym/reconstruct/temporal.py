"""Temporal coherence of the reconstruction: pieces beyond the papers, each switchable.

The papers' pipeline solves every frame on its own, in a frame of reference taken from that
frame's sensor pose, and relies on the motion term ``Em`` (Shum Eq. 14) and the ragdoll for
continuity. Measured on simulated and real streams that is not enough: the output shakes more
than its own input (issue 15). The causes, and the piece that answers each:

* **Placement** (:class:`PlacementSmoother`). Each frame is normalised with the sensor's root
  and a heading from the sensor's hip line (:func:`fpg_gym.core.poses.normalise`), and the
  reconstruction is put back in camera space with the same root and heading: the root's noise
  moves every joint, whatever the reconstruction does. A One-Euro filter on the root position
  (and optionally on the heading, as a unit vector) steadies the output's placement; the pose
  is still estimated around the sensor's root. A centimetre of noise on each hip joint also
  turns the heading by a few degrees, but smoothing it lags on fast turns (twists of a punch),
  so heading smoothing is opt-in (``smooth_heading``).
* **Latent basis** (:func:`align_basis`). The natural posture space is a PCA of a candidate set
  that changes every frame; an SVD returns each axis with an arbitrary sign. Each new axis is
  given the sign that points it the same way as the previous frame's axis of the same rank, so
  the same latent point means a similar pose from frame to frame. With the default sign rule
  (each axis's largest entry positive) about 28 % of the axes point against the previous
  frame's (measured on validation takes). Opt-in: the papers' search starts from the previous
  pose projected and samples isotropically, so it does not depend on the signs, and the learned
  samplers were trained without it.
* **Continuity prior** (``velocity_damping``, ``motion_scale``; applied by the
  reconstructor). ``Em`` (Shum Eq. 14) pulls toward the constant-velocity extrapolation
  ``2 p_{x-1} - p_{x-2}`` of the last two outputs, which carries their noise forward (and
  amplifies it), with a weight (0.25, a mean over joints) that is tiny next to ``Ec`` (a sum
  over joints). Anchoring the target on the previous reconstruction and raising the weight makes
  the search stay near the previous pose unless the evidence says otherwise.
* **Output** (:class:`OutputSmoother`). A per-joint filter on the output joints (root-relative;
  the root is the smoothed placement's): by default the constant-velocity Kalman filter of the
  reference filters (:class:`fpg_gym.filters.KalmanFilter`), which removes noise with almost no
  lag on steady motion. The user's bone lengths are restored after it
  (:func:`fpg_gym.core.poses.retarget`), so the filter never changes a bone's length.

Lag is the cost of any causal smoothing; :func:`fpg_gym.core.metrics.lag` measures it against the
ground truth, and the defaults were chosen on validation takes under a one-frame bound (README,
"Temporal coherence").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.filters import KalmanFilter, make_filter
from fpg_gym.filters.one_euro import OneEuroFilter
from fpg_gym.reconstruct.energy import motion_target
from fpg_gym.reconstruct.latent import LatentSpace

#: :func:`continuity`'s compiled call without a second previous output.
_NO_POSE = np.zeros((0, 3))

__all__ = [
    "OutputSmoother",
    "PlacementSmoother",
    "TemporalConfig",
    "align_basis",
    "continuity",
]


@dataclass(frozen=True)
class TemporalConfig:
    """Switches and parameters of the temporal pieces (see the module docstring).

    Attributes
    ----------
    placement : bool
        Smooth the root position the output is placed at (True).
    smooth_heading : bool
        Smooth the heading too, and estimate the pose in that smoothed frame (False: it steadies
        a static body but lags on fast turns; on the embedded punch clip it raised the error of
        an occluded arm by a fifth).
    root_min_cutoff, root_beta : float
        One-Euro parameters of the root position (Hz, s/m).
    heading_min_cutoff, heading_beta : float
        One-Euro parameters of the heading unit vector (Hz, s).
    align_basis : bool
        Keep the latent axes' signs aligned with the previous frame's (False: opt-in; no
        effect on the papers' search, and learned samplers are trained without it).
    output : str
        Filter of the output stage (a :func:`fpg_gym.filters.make_filter` name such as
        ``"kalman"`` (default), ``"one-euro"`` or ``"holt"``), applied to the output joints
        root-relative with the bone lengths restored; ``""``: no output stage.
    output_options : tuple of (str, float) pairs
        Parameters of that filter (e.g. ``(("tracked_std", 0.01),)`` for the Kalman filter).
    velocity_damping : float
        Factor on the velocity of the motion target of ``Em`` (Shum Eq. 14): 1 is the papers'
        constant-velocity target ``2 p_{x-1} - p_{x-2}``, 0 the previous pose (0: a continuity
        prior anchored on the previous reconstruction; extrapolating a noisy velocity feeds
        the noise back).
    motion_scale : float
        Factor on the configured weight of ``Em`` (8: the papers' 0.25 becomes 2.0; 1 is the
        papers'). A weight set to 0 stays 0.
    """

    placement: bool = True
    smooth_heading: bool = False
    root_min_cutoff: float = 1.0
    root_beta: float = 10.0
    heading_min_cutoff: float = 1.0
    heading_beta: float = 3.0
    align_basis: bool = False
    output: str = "kalman"
    output_options: tuple[tuple[str, float], ...] = ()
    velocity_damping: float = 0.0
    motion_scale: float = 8.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.velocity_damping) and 0.0 <= self.velocity_damping <= 1.0):
            raise ValueError(
                f"velocity_damping: expected a value in [0, 1], got {self.velocity_damping!r}"
            )
        for name in ("motion_scale", "root_beta", "heading_beta"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: expected a finite value >= 0, got {value!r}")
        for name in ("root_min_cutoff", "heading_min_cutoff"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name}: expected a finite value > 0 Hz, got {value!r}")

    @classmethod
    def off(cls) -> TemporalConfig:
        """Every piece off: the papers' pipeline."""
        return cls(
            placement=False, align_basis=False, output="", velocity_damping=1.0, motion_scale=1.0
        )


class PlacementSmoother:
    """One-Euro filters on a stream of placements: the root position, and the heading when the
    config smooths it (``smooth_heading``).

    The heading is filtered as the unit vector ``(sin yaw, 0, cos yaw)`` (no wrap-around at
    ±pi) and turned back into an angle.
    """

    def __init__(self, config: TemporalConfig) -> None:
        self._root = OneEuroFilter(min_cutoff=config.root_min_cutoff, beta=config.root_beta)
        self._heading = (
            OneEuroFilter(min_cutoff=config.heading_min_cutoff, beta=config.heading_beta)
            if config.smooth_heading
            else None
        )

    def reset(self) -> None:
        """Start a new stream."""
        self._root.reset()
        if self._heading is not None:
            self._heading.reset()

    def update(self, placement: pose_utils.Placement, timestamp: float) -> pose_utils.Placement:
        """The smoothed placement of the next frame (``timestamp`` in seconds); its yaw is
        ``placement``'s when the heading is not smoothed."""
        root = self._root.update_tracked(
            np.asarray(placement.root, dtype=np.float64)[None], timestamp
        )[0].astype(np.float64)
        if self._heading is None:
            return pose_utils.Placement(root=root, yaw=placement.yaw)
        yaw = float(np.asarray(placement.yaw))
        heading = np.array([[np.sin(yaw), 0.0, np.cos(yaw)]])
        smooth = self._heading.update_tracked(heading, timestamp)[0].astype(np.float64)
        if np.hypot(smooth[0], smooth[2]) < 1e-6:  # a half turn within one filter step
            smooth = heading[0]
        return pose_utils.Placement(root=root, yaw=np.asarray(np.arctan2(smooth[0], smooth[2])))


class OutputSmoother:
    """A per-joint filter on camera-space output poses, root-relative, bone lengths restored."""

    def __init__(self, config: TemporalConfig) -> None:

        self._filter = make_filter(config.output, **dict(config.output_options))

    def reset(self) -> None:
        """Start a new stream."""
        self._filter.reset()

    def update(self, pose: np.ndarray, lengths: np.ndarray, timestamp: float) -> np.ndarray:
        """Filter one pose ``(20, 3)`` (camera space) and give it ``lengths`` ``(19,)``."""
        pose = np.asarray(pose, dtype=np.float64)
        lengths = np.asarray(lengths, dtype=np.float64)
        compiled = compiled_module("fpg_gym.reconstruct.compiled_frame")
        one_pose = pose.shape == (skeleton.NUM_JOINTS, 3) and lengths.shape == (skeleton.NUM_BONES,)
        if compiled is not None and one_pose and isinstance(self._filter, KalmanFilter):
            # The Kalman filter's step and the lines below in one call.
            states, dt = self._filter.advance_tracked(skeleton.NUM_JOINTS, timestamp)
            smoothed: np.ndarray = compiled.smooth_output(
                pose,
                lengths,
                skeleton.ROOT,
                skeleton.BONES,
                pose_utils.REST_DIRECTIONS,
                self._filter.kernel_arguments(states, dt),
            )
            return smoothed
        root = pose[skeleton.ROOT]
        filtered = self._filter.update_tracked(pose - root, timestamp)
        if compiled is not None and one_pose:
            restored: np.ndarray = compiled.restore_output(  # the lines below in one call
                filtered,
                lengths,
                root,
                skeleton.ROOT,
                skeleton.BONES,
                pose_utils.REST_DIRECTIONS,
            )
            return restored
        local = filtered.astype(np.float64)
        local -= local[skeleton.ROOT]
        out = pose_utils.retarget(local, lengths).astype(np.float64) + root
        return out.astype(np.float32)


def align_basis(latent: LatentSpace, previous: LatentSpace | None) -> LatentSpace:
    """``latent`` with each axis's sign chosen to agree with ``previous``'s axis of the same rank.

    Axis ``i`` is flipped when ``basis[i] . previous.basis[i] < 0``. A flip changes no pose the
    space can express (``decode`` of the flipped coordinates is the same pose), only which
    latent point names it. Returns ``latent`` itself when nothing flips or there is no previous
    space.
    """
    if previous is None or latent.dim == 0 or previous.basis.shape[1] != latent.basis.shape[1]:
        return latent
    rank = min(latent.dim, previous.dim)
    dots = np.einsum("dc,dc->d", latent.basis[:rank], previous.basis[:rank])
    signs = np.ones(latent.dim)
    signs[:rank] = np.where(dots < 0.0, -1.0, 1.0)
    if np.all(signs > 0):
        return latent
    return LatentSpace(
        latent.mean,
        latent.basis * signs[:, None],
        latent.std,
        latent.degenerate,
        latent.explained_variance_ratio,
    )


def _rotate_into(pose: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """A camera-space pose, root-relative and turned by ``-yaw`` (the current frame's heading)."""
    pose = np.asarray(pose, dtype=np.float64)
    return pose_utils.into_placement(pose, pose_utils.Placement(root=pose[skeleton.ROOT], yaw=yaw))


def continuity(
    history: list[tuple[np.ndarray, float]],
    yaw: np.ndarray,
    dt: float,
    no_body: bool,
    damping: float,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The previous reconstruction (``history``: camera-space outputs and timestamps, newest
    last) in the frame of heading ``yaw``, and the continuity prediction ``dt`` s later (FPG
    Eq. 6), which is also the motion target of Em (Shum Eq. 14), its velocity scaled by
    ``damping`` (:attr:`TemporalConfig.velocity_damping`). Both None on a stream's first frame."""
    previous = prediction = None
    compiled = compiled_module("fpg_gym.reconstruct.compiled_frame")
    if history and compiled is not None:  # one compiled call, the same arithmetic
        last = np.ascontiguousarray(history[-1][0], dtype=np.float64)
        ratio = 1.0
        before = _NO_POSE
        if len(history) >= 2 and not no_body:
            before = np.ascontiguousarray(history[-2][0], dtype=np.float64)
            dt_prev = history[-1][1] - history[-2][1]
            ratio = 1.0 if not dt_prev or dt_prev <= 0 else dt / dt_prev  # as motion_target
        previous, prediction = compiled.continuity_poses(
            last, before, skeleton.ROOT, float(yaw), ratio, float(damping)
        )
        return previous, prediction
    if history:
        previous = _rotate_into(history[-1][0], yaw)
        if len(history) >= 2 and not no_body:
            before = _rotate_into(history[-2][0], yaw)
            dt_prev = history[-1][1] - history[-2][1]
            prediction = motion_target(previous, before, dt, dt_prev)
            if damping != 1.0:
                # Temporal coherence (not in the papers): a continuity prior anchored on the
                # previous reconstruction rather than on its noisy extrapolation.
                prediction = previous + damping * (prediction - previous)
        else:
            prediction = previous.copy()
    return previous, prediction
