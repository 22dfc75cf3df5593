"""The Kinect SDK joint filter: Holt double-exponential smoothing with jitter and deviation clamps.

This is the filter that the Kinect for Windows SDK v1 applies in ``NuiTransformSmooth`` /
``SkeletonStream.Enable(TransformSmoothParameters)``, implemented from the published description
(SDK v1.8 reference "NUI_TRANSFORM_SMOOTH_PARAMETERS Structure" and "Joint Filtering"; M. Azimi,
"Skeletal Joint Smoothing White Paper", Microsoft ATG) and the behaviour of Microsoft's public
re-implementations of it: ``KinectJointFilter.cpp`` (SDK 2.0 sample, "Holt Double Exponential
Smoothing filter for filtering Joints") and ``SkeletonJointsPositionDoubleExponentialFilter.cs``
(SDK 1.x Avateering sample). Per joint, with raw position r_n, previous filtered position f_{n-1}
and trend b_{n-1}:

1. **Jitter clamp**: d = ||r_n − f_{n−1}||; when d ≤ jitter_radius the raw sample is pulled back
   towards the previous filtered value, x_n = f_{n−1} + (d / jitter_radius)(r_n − f_{n−1}) (a move
   of d²/jitter_radius instead of d); otherwise x_n = r_n.
2. **Holt smoothing** (level): f_n = (1 − smoothing) x_n + smoothing (f_{n−1} + b_{n−1}).
3. **Holt trend**: b_n = correction (f_n − f_{n−1}) + (1 − correction) b_{n−1}.
4. **Prediction**: y_n = f_n + prediction · b_n (``prediction`` frames ahead, to cut latency).
5. **Max-deviation clamp**: when e = ||y_n − r_n|| > max_deviation_radius, y_n is pulled back to
   r_n + (max_deviation_radius / e)(y_n − r_n), i.e. onto the sphere of that radius about r_n.

Start-up (as the samples): the first frame of a joint gives f = r, b = 0; the second f = (r_n +
r_{n−1}) / 2, b = correction (f_n − f_{n−1}); the recursion above runs from the third frame on.

Tracking states (as the samples): an inferred joint uses ``inferred_scale`` (2) times the jitter and
max-deviation radii ("if inferred, we smooth a bit more by using a bigger jitter radius"); a joint
with no measurement (not tracked, or a non-finite position; the SDK tests for the all-zero position
that Kinect reports for not-tracked joints) restarts its filter: its output is the input as is and
its next valid frame is a first frame again (the samples instead count the invalid frame as the
first, averaging the next raw position with (0, 0, 0); that artefact is not reproduced).
Timestamps are ignored: the SDK filter counts frames.

Step response (smoothing s, correction c, prediction p; both clamps inactive): the z-transform of
steps 2–4 is Y/X = (1 − s)[(1 + pc) − (1 − c + pc) z⁻¹] / [1 − (1 + s − c + sc) z⁻¹ + s z⁻²]; unit
DC gain; the two poles multiply to s and are complex, of modulus √s, when (1 + s − c + sc)² < 4s,
real otherwise. Unit-step response with the clamps off (the test derives it with lfilter):

=============== ============= ========= ============================ ==========
preset          poles         overshoot first frames               within 2 %
=============== ============= ========= ============================ ==========
default         |z| = 0.707   27 %      0.625, 1.031, 1.227, 1.268   11 frames
smoothed        0.885, 0.565  10 %      0.525, 0.811, 0.964, 1.042   21 frames
very-smoothed   |z| = 0.837   33 %      0.390, 0.718, 0.973, 1.154   22 frames
sample          0.711, 0.352  9 %       0.797, 1.034, 1.087, 1.084   8 frames
=============== ============= ========= ============================ ==========

(complex pole pairs given by their modulus). With the clamps on, the max-deviation radius caps
the lag and the overshoot (the output stays within that radius of the raw data); once the
residual is inside the jitter radius the jitter clamp slows the approach further (it freezes
below 0.1 mm when that radius is at its floor). A ramp is followed with zero steady-state lag by
f and led by p frames in the output.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from fpg_gym.filters.base import INFERRED, FloatArray, PresetFilter, valid_joints

#: Smallest jitter radius (metres): "Check for divide by zero. Use an epsilon of a 10th of a
#: millimeter" in both Microsoft samples.
MIN_JITTER_RADIUS: Final[float] = 1e-4


@dataclass(frozen=True)
class HoltParams:
    """``TransformSmoothParameters`` of the Kinect SDK (v1 names in brackets).

    Attributes
    ----------
    smoothing
        [fSmoothing] in [0, 1]: weight of the previous forecast against the new sample; higher is
        smoother and laggier, 0 returns the raw data.
    correction
        [fCorrection] in [0, 1]: trend gain; higher corrects towards the raw data faster (can be
        "springy"), lower is smoother.
    prediction
        [fPrediction] >= 0: frames to predict into the future; above 0.5 overshoots on fast
        changes (damped by a small max_deviation_radius).
    jitter_radius
        [fJitterRadius] metres >= 0: changes within this radius of the previous filtered value are
        treated as jitter and damped (raised to 0.1 mm, as the samples do, to avoid dividing by 0).
    max_deviation_radius
        [fMaxDeviationRadius] metres >= 0: the output never lies further than this from the raw
        position.
    inferred_scale
        Factor on both radii for inferred joints: 2 in both Microsoft samples.
    """

    smoothing: float = 0.5
    correction: float = 0.5
    prediction: float = 0.5
    jitter_radius: float = 0.05
    max_deviation_radius: float = 0.04
    inferred_scale: float = 2.0

    def __post_init__(self) -> None:
        for name in ("smoothing", "correction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name}: expected a value in [0, 1], got {value!r}")
        for name in ("prediction", "jitter_radius", "max_deviation_radius", "inferred_scale"):
            value = getattr(self, name)
            if not (value >= 0.0):  # also rejects NaN
                raise ValueError(f"{name}: expected a value >= 0, got {value!r}")
        if self.inferred_scale == 0.0:
            raise ValueError("inferred_scale: expected a value > 0, got 0")


#: The SDK's documented parameter sets (SDK v1.8 reference, NUI_TRANSFORM_SMOOTH_PARAMETERS
#: remarks and "Joint Filtering"), plus the SDK 2.0 sample's own defaults and "none".
HOLT_PRESETS: Final[dict[str, HoltParams]] = {
    # "Some smoothing with little latency (defaults). Only filters out small jitters. Good for
    # gesture recognition." {0.5, 0.5, 0.5, 0.05, 0.04}. (The structure's member list gives 0.0 as
    # fPrediction's default; the SDK's own "defaults" example and every sample use 0.5.)
    "default": HoltParams(0.5, 0.5, 0.5, 0.05, 0.04),
    # "Smoothed with some latency. Filters out medium jitters. Good for a menu system that needs
    # to be smooth but doesn't need the reduced latency as much as gesture recognition does."
    "smoothed": HoltParams(0.5, 0.1, 0.5, 0.1, 0.1),
    # "Very smooth, but with a lot of latency. Filters out large jitters. Good for situations where
    # smooth data is absolutely required and latency is not an issue."
    "very-smoothed": HoltParams(0.7, 0.3, 1.0, 1.0, 1.0),
    # Init() defaults of KinectJointFilter.h (SDK 2.0 sample) and of the SDK 1.x Avateering
    # sample's SkeletonJointsPositionDoubleExponentialFilter.
    "sample": HoltParams(0.25, 0.25, 0.25, 0.03, 0.05),
    # All zero: the raw data (the SDK's "passing 0 causes the raw data to be returned").
    "none": HoltParams(0.0, 0.0, 0.0, 0.0, 0.0),
}

#: Other spellings accepted for the presets (the SDK samples' variable names).
HOLT_PRESET_ALIASES: Final[dict[str, str]] = {
    "defaults": "default",
    "gesture": "default",
    "some-smoothing": "smoothed",
    "somewhat-latent": "smoothed",
    "menu": "smoothed",
    "very-smooth": "very-smoothed",
}


def holt_preset(name: str) -> HoltParams:
    """The parameters of a named preset (see :data:`HOLT_PRESETS`; ``_`` and case are ignored)."""
    key = name.strip().lower().replace("_", "-").replace(" ", "-")
    key = HOLT_PRESET_ALIASES.get(key, key)
    if key not in HOLT_PRESETS:
        raise ValueError(
            f"preset: unknown Holt preset {name!r}; expected one of {sorted(HOLT_PRESETS)}"
        )
    return HOLT_PRESETS[key]


class HoltFilter(PresetFilter):
    """The Kinect SDK double-exponential joint filter (the ``holt`` reference method).

    Parameters
    ----------
    preset
        Starting parameter set, a key of :data:`HOLT_PRESETS` (``"default"``, ``"smoothed"``,
        ``"very-smoothed"``, ``"sample"``, ``"none"``).
    **overrides
        Any :class:`HoltParams` field (``smoothing``, ``correction``, ``prediction``,
        ``jitter_radius``, ``max_deviation_radius``, ``inferred_scale``) replacing the preset's.

    Examples
    --------
    >>> import numpy as np
    >>> f = HoltFilter("smoothed")
    >>> out = f.filter_sequence(np.zeros((5, 20, 3)) + 1.0)
    >>> out.shape
    (5, 20, 3)
    """

    settings: HoltParams

    def __init__(self, preset: str = "default", **overrides: float) -> None:
        super().__init__(preset, holt_preset(preset), overrides)
        self._raw = np.zeros((0, 3))
        self._level = np.zeros((0, 3))
        self._trend = np.zeros((0, 3))
        self._count = np.zeros(0, dtype=np.int64)

    def _start(self, num_joints: int) -> None:
        self._raw = np.zeros((num_joints, 3))
        self._level = np.zeros((num_joints, 3))
        self._trend = np.zeros((num_joints, 3))
        self._count = np.zeros(num_joints, dtype=np.int64)

    def _step(self, frame: FloatArray, states: npt.NDArray[np.int8], dt: float) -> FloatArray:
        p = self.settings
        s, c = p.smoothing, p.correction
        # A joint without a measurement restarts its filter (the samples' "if joint is invalid,
        # reset the filter"); its output is the input as is.
        valid = valid_joints(frame, states)
        count = np.where(valid, self._count, 0)
        raw = np.where(valid[:, None], frame, 0.0)  # no NaN arithmetic below
        # Bigger radii for inferred joints ("we smooth a bit more").
        scale = np.where(states == INFERRED, p.inferred_scale, 1.0)
        jitter = np.maximum(p.jitter_radius, MIN_JITTER_RADIUS) * scale
        max_dev = p.max_deviation_radius * scale

        prev_level, prev_trend = self._level, self._trend
        # Step 1, jitter clamp: a change d within the radius moves by d * (d / radius) only.
        delta = raw - prev_level
        dist = np.linalg.norm(delta, axis=1)
        weight = np.where(dist <= jitter, dist / jitter, 1.0)
        damped = prev_level + weight[:, None] * delta
        # Step 2, level: f = (1 - s) x + s (f_prev + b_prev).
        level = (1.0 - s) * damped + s * (prev_level + prev_trend)
        # Start-up: frame 1 f = r; frame 2 f = mean of the last two raw samples.
        level = np.where((count == 1)[:, None], 0.5 * (raw + self._raw), level)
        level = np.where((count == 0)[:, None], raw, level)
        # Step 3, trend: b = c (f - f_prev) + (1 - c) b_prev; zero on a first frame.
        trend = c * (level - prev_level) + (1.0 - c) * prev_trend
        trend = np.where((count == 0)[:, None], 0.0, trend)
        # Step 4, prediction.
        out = level + p.prediction * trend
        # Step 5, max-deviation clamp onto the sphere of radius max_dev about the raw position.
        error = out - raw
        err = np.linalg.norm(error, axis=1)
        over = err > max_dev
        shrink = np.divide(max_dev, err, out=np.ones_like(err), where=over)
        out = raw + shrink[:, None] * error

        self._raw = raw
        self._level = level
        self._trend = trend
        # An invalid frame leaves the count at 0: the next valid frame is a first frame. (The
        # samples count the invalid frame itself as the first, so their next frame averages the
        # raw position with (0, 0, 0), an artefact the max-deviation clamp then hides partly.)
        self._count = np.where(valid, np.minimum(count + 1, 2), 0)
        return np.where(valid[:, None], out, frame)


__all__ = [
    "HOLT_PRESETS",
    "HOLT_PRESET_ALIASES",
    "MIN_JITTER_RADIUS",
    "HoltFilter",
    "HoltParams",
    "holt_preset",
]
