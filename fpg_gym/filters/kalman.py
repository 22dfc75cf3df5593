"""Constant-velocity Kalman filter per joint (the ``kalman`` reference method).

Each joint and axis has the state (position, velocity) with the continuous white-noise
acceleration model (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, 2001, §6.2.2): over a step dt,

    F = [[1, dt], [0, 1]],   Q = q [[dt³/3, dt²/2], [dt²/2, dt]],

where q (m²/s³) is the power spectral density of the acceleration. A Kinect frame measures the
position, H = [1, 0], with variance R = σ² that depends on the joint's tracking state: σ_tracked
for tracked joints, σ_inferred for inferred ones, and for not-tracked joints (or non-finite
positions) the update is skipped (R = ∞) unless ``not_tracked_std`` is given. The axes share
their dynamics and their measurement variance, so one 2×2 covariance per joint serves all three
axes: the step is vectorised over joints and axes, with the 2×2 algebra written out.

A joint starts at its first measurement with zero velocity (variance ``initial_velocity_std``²).
While a joint has no measurement the filter coasts on its velocity; after ``max_coast`` seconds
without one it holds the position (velocity set to 0), so a long occlusion cannot drift away.

Defaults (:data:`KALMAN_PRESETS`), all from real data in ``../shared/data`` with :func:`fit_noise`
(maximum innovation likelihood), then rounded:

=================== ========= ===========================================================
parameter           default   source (fitted value)
=================== ========= ===========================================================
``accel_psd`` q     0.5       MSRC-12 Kinect v1, 3 streams, 4,124 frames: 0.40 m²/s³;
                    m²/s³     Kinect v2 ``joints.csv``: 0.52; v2 ``Ges01..05``: 0.29. The clean
                              Bandai mocap agrees: median over 21 dataset-1 takes of
                              mean(Δv²)/dt = 0.54 (90th percentile 8.2: run/dash).
``tracked_std``     5 mm      MSRC-12 Kinect v1: 4.7 mm (Kinect v2: 2.4-2.9 mm)
``inferred_std``    5 cm      Kinect v2 ``joints.csv`` (32 % inferred joint-frames): 4.8 cm
``not_tracked_std`` None      skip the update: a not-tracked position carries no information
``initial_velocity  1 m/s     a walking limb's speed; only matters for the first frames
_std``
``max_coast``       0.3 s     9 frames at 30 Hz, then hold: an engineering choice (track
                              coasting limit), not fitted
=================== ========= ===========================================================

The ``"fast"`` preset raises q to 10 m²/s³ for sport-like motion (run, dash, kick), the 90th
percentile above. The sizes agree with the Kinect skeleton noise reported in the literature: a
few millimetres of jitter on tracked joints and errors of several centimetres on inferred
(occluded) joints (Azimi, "Skeletal Joint Smoothing White Paper", Microsoft; Wang, Kurillo, Ofli &
Bajcsy, "Evaluation of pose tracking accuracy in the first and second generations of Microsoft
Kinect", ICHI 2015). Simplification: the noise is isotropic, although Kinect's depth (Z) error is
larger than its X/Y error.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from fpg_gym.core.compiled import compiled_module
from fpg_gym.filters.base import (
    INFERRED,
    NOT_TRACKED,
    TRACKED,
    FloatArray,
    PresetFilter,
    _as_positions,
    _as_states,
    _as_timestamps,
)


@dataclass(frozen=True)
class KalmanParams:
    """Parameters of :class:`KalmanFilter` (SI units).

    Attributes
    ----------
    accel_psd
        q, power spectral density of the white-noise acceleration (m²/s³); higher follows fast
        motion more closely and smooths less.
    tracked_std
        σ of a tracked joint's measured position per axis (m).
    inferred_std
        σ of an inferred joint's measured position per axis (m).
    not_tracked_std
        σ for not-tracked joints (m), or ``None`` to skip their update (the default).
    initial_velocity_std
        σ of the velocity when a joint starts (m/s).
    max_coast
        Seconds a joint may go without a measurement before its velocity is zeroed (position held);
        ``None`` coasts for ever.
    """

    accel_psd: float = 0.5
    tracked_std: float = 0.005
    inferred_std: float = 0.05
    not_tracked_std: float | None = None
    initial_velocity_std: float = 1.0
    max_coast: float | None = 0.3

    def __post_init__(self) -> None:
        for name in ("accel_psd", "tracked_std", "inferred_std", "initial_velocity_std"):
            value = getattr(self, name)
            if not (value > 0.0 and np.isfinite(value)):
                raise ValueError(f"{name}: expected a finite value > 0, got {value!r}")
        for name in ("not_tracked_std", "max_coast"):
            value = getattr(self, name)
            if value is not None and not (value > 0.0):
                raise ValueError(f"{name}: expected a value > 0 or None, got {value!r}")


#: Default parameters (fitted with :func:`fit_noise` on the shared real Kinect data, rounded; see
#: the module docstring for the fitted values).
DEFAULT_KALMAN: Final[KalmanParams] = KalmanParams()

#: Named parameter sets: ``default`` (fitted on real Kinect streams) and ``fast`` (q for sport-like
#: motion).
KALMAN_PRESETS: Final[dict[str, KalmanParams]] = {
    "default": DEFAULT_KALMAN,
    "fast": KalmanParams(accel_psd=10.0),
}


class KalmanFilter(PresetFilter):
    """Constant-velocity Kalman filter per joint and axis (see the module docstring).

    Parameters
    ----------
    preset
        Starting parameter set, a key of :data:`KALMAN_PRESETS` (``"default"``, ``"fast"``).
    **params
        Any :class:`KalmanParams` field, replacing the preset's.

    Attributes
    ----------
    settings : KalmanParams
        The effective parameters.
    """

    settings: KalmanParams

    def __init__(self, preset: str = "default", **params: Any) -> None:
        key = preset.strip().lower()
        if key not in KALMAN_PRESETS:
            raise ValueError(
                f"preset: unknown Kalman preset {preset!r}; expected one of {list(KALMAN_PRESETS)}"
            )
        super().__init__(key, KALMAN_PRESETS[key], params)
        self._alloc(0)

    def _alloc(self, num_joints: int) -> None:
        self._pos = np.zeros((num_joints, 3))
        self._vel = np.zeros((num_joints, 3))
        # Covariance [[p00, p01], [p01, p11]] per joint, shared by the three axes.
        self._p00 = np.zeros(num_joints)
        self._p01 = np.zeros(num_joints)
        self._p11 = np.zeros(num_joints)
        self._started = np.zeros(num_joints, dtype=bool)
        self._unseen = np.zeros(num_joints)  # seconds since the last measurement
        self._innovation: tuple[npt.NDArray[np.bool_], FloatArray, FloatArray] = (
            np.zeros(num_joints, dtype=bool),
            np.ones(num_joints),
            np.zeros((num_joints, 3)),
        )

    def _start(self, num_joints: int) -> None:
        self._alloc(num_joints)

    @functools.cached_property
    def _by_state(self) -> FloatArray:
        """R by tracking state (indexed by the validated state 0, 1 or 2): not tracked
        (inf, skip the update, unless ``not_tracked_std``), inferred, tracked; from the
        settings, once."""
        p = self.settings
        not_tracked = np.inf if p.not_tracked_std is None else p.not_tracked_std**2
        by_state = np.empty(3)
        by_state[[NOT_TRACKED, INFERRED, TRACKED]] = (
            not_tracked,
            p.inferred_std**2,
            p.tracked_std**2,
        )
        return by_state

    def kernel_arguments(self, states: npt.NDArray[np.int8], dt: float) -> tuple[Any, ...]:
        """The arguments after the frame of the compiled step
        (:func:`fpg_gym.filters.compiled_filters.kalman_step`) of a frame with ``states`` ``dt``
        seconds after the last (:meth:`_advance`'s): the constants, then the state arrays it
        updates in place."""
        p = self.settings
        q = p.accel_psd
        upd, s, innov = self._innovation
        return (
            states,
            self._by_state,
            dt,
            q * dt**3 / 3.0,
            q * dt**2 / 2.0,
            q * dt,
            p.initial_velocity_std**2,
            -1.0 if p.max_coast is None else p.max_coast,
            self._pos,
            self._vel,
            self._p00,
            self._p01,
            self._p11,
            self._started,
            self._unseen,
            upd,
            s,
            innov,
        )

    def _measurement_var(self, frame: FloatArray, states: npt.NDArray[np.int8]) -> FloatArray:
        """R per joint (:meth:`_by_state`); inf (skip the update) when unmeasured."""
        return np.where(np.isfinite(frame).all(axis=1), self._by_state[states], np.inf)

    def _step(self, frame: FloatArray, states: npt.NDArray[np.int8], dt: float) -> FloatArray:
        p = self.settings
        compiled = compiled_module("fpg_gym.filters.compiled_filters")
        if compiled is not None:  # the same step as below, joint by joint in one call
            out: FloatArray = compiled.kalman_step(
                np.ascontiguousarray(frame, dtype=np.float64), *self.kernel_arguments(states, dt)
            )
            return out
        var = self._measurement_var(frame, states)
        measured = np.isfinite(var)
        z = np.where(measured[:, None], frame, 0.0)

        # Predict (constant velocity; Q of the white-noise acceleration model).
        if dt > 0.0:
            q = p.accel_psd
            self._pos = self._pos + dt * self._vel
            p00 = self._p00 + 2.0 * dt * self._p01 + dt * dt * self._p11 + q * dt**3 / 3.0
            p01 = self._p01 + dt * self._p11 + q * dt**2 / 2.0
            p11 = self._p11 + q * dt
            self._p00, self._p01, self._p11 = p00, p01, p11
            self._unseen = self._unseen + dt

        # Update joints that have a measurement and have started: K = P Hᵀ / (H P Hᵀ + R).
        upd = measured & self._started
        s = np.where(upd, self._p00 + np.where(upd, var, 1.0), 1.0)
        k0 = np.where(upd, self._p00 / s, 0.0)
        k1 = np.where(upd, self._p01 / s, 0.0)
        innov = np.where(upd[:, None], z - self._pos, 0.0)
        self._innovation = (upd, s, innov)  # read by fit_noise
        self._pos = self._pos + k0[:, None] * innov
        self._vel = self._vel + k1[:, None] * innov
        p00, p01, p11 = self._p00, self._p01, self._p11
        self._p00 = (1.0 - k0) * p00
        self._p01 = (1.0 - k0) * p01
        self._p11 = p11 - k1 * p01

        # Start joints at their first measurement: position measured, velocity 0.
        new = measured & ~self._started
        if new.any():
            self._pos[new] = z[new]
            self._vel[new] = 0.0
            self._p00[new] = var[new]
            self._p01[new] = 0.0
            self._p11[new] = p.initial_velocity_std**2
            self._started |= new

        self._unseen = np.where(measured, 0.0, self._unseen)
        if p.max_coast is not None:
            hold = self._unseen > p.max_coast
            self._vel = np.where(hold[:, None], 0.0, self._vel)
        # A joint never measured yet has no estimate: return the input.
        return np.where(self._started[:, None], self._pos, frame)


def fit_noise(
    positions: npt.ArrayLike | list[npt.ArrayLike],
    states: npt.ArrayLike | list[npt.ArrayLike | None] | None = None,
    timestamps: npt.ArrayLike | list[npt.ArrayLike | None] | None = None,
    *,
    fit_inferred: bool = False,
    initial: KalmanParams = DEFAULT_KALMAN,
) -> KalmanParams:
    """Maximum-likelihood ``accel_psd`` and ``tracked_std`` (and ``inferred_std``) for real data.

    Minimises the negative log-likelihood of the filter's innovations, Σ ½(log 2πS + ν²/S), over
    every measured joint, axis and frame (after each joint's first frame), with Nelder–Mead on the
    logarithms of the parameters. This is how the defaults were obtained (module docstring).

    Parameters
    ----------
    positions
        ``(T, J, 3)`` real Kinect positions in metres, or a list of such streams.
    states
        ``(T, J)`` tracking states per stream (``None``: all tracked).
    timestamps
        ``(T,)`` seconds per stream (``None``: 30 Hz).
    fit_inferred
        Also fit ``inferred_std`` (needs inferred joints in the data).
    initial
        Starting point; its other fields are kept.

    Returns
    -------
    KalmanParams
        ``initial`` with the fitted fields replaced (not rounded).
    """
    from scipy.optimize import minimize

    clips_in = positions if isinstance(positions, list) else [positions]
    count = len(clips_in)

    def per_stream(value: Any, name: str) -> list[Any]:
        if value is None:
            return [None] * count
        if not isinstance(value, list):
            value = [value]
        if len(value) != count:
            raise ValueError(f"{name}: expected {count} entries (one per stream), got {len(value)}")
        return value

    state_list = per_stream(states, "states")
    time_list = per_stream(timestamps, "timestamps")
    data = []
    for i, clip_in in enumerate(clips_in):
        clip = _as_positions(clip_in, f"positions[{i}]", 3)
        data.append(
            (
                clip,
                _as_states(state_list[i], clip.shape[:2], f"states[{i}]"),
                _as_timestamps(time_list[i], clip.shape[0], f"timestamps[{i}]"),
            )
        )
    names = ["accel_psd", "tracked_std"] + (["inferred_std"] if fit_inferred else [])
    base = asdict(initial)

    def nll(log_values: FloatArray) -> float:
        values = dict(zip(names, np.exp(log_values).tolist(), strict=True))
        kf = KalmanFilter(**{**base, **values, "max_coast": None})
        total = 0.0
        for clip, state, times in data:
            kf.reset()
            for t in range(clip.shape[0]):
                dt = kf._advance(clip.shape[1], float(times[t]))
                kf._step(clip[t], state[t], dt)
                upd, var, innov = kf._innovation
                terms = np.log(2.0 * np.pi * var)[:, None] + innov**2 / var[:, None]
                total += 0.5 * float(np.sum(terms[upd]))
        return total

    x0 = np.log([base[name] for name in names])
    result = minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-3})
    fitted = dict(zip(names, np.exp(result.x).tolist(), strict=True))
    return KalmanParams(**{**base, **fitted})


__all__ = ["DEFAULT_KALMAN", "KALMAN_PRESETS", "KalmanFilter", "KalmanParams", "fit_noise"]
