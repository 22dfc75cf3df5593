"""The Kalman and One-Euro filters' per-frame steps compiled (numba); imported only when
``fpg-gym[fast]`` is installed.

Each kernel is its filter's ``_step`` (:mod:`fpg_gym.filters.kalman`,
:mod:`fpg_gym.filters.one_euro`) joint by joint, with the same operations in the same order, so
that its outputs and state equal the numpy step's; the tests compare them. The constants that
involve powers (``q dt^3 / 3`` ...) are computed by the caller, as the numpy step computes them;
the One-Euro smoothing factors by :func:`_alpha`, :func:`fpg_gym.filters.one_euro.alpha`'s
operations. The filter's state arrays are updated in place. Module-level
functions so that numba's disk cache (``cache=True``) finds them in a new process.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core.compiled import JIT_OPTIONS

__all__ = ["kalman_step", "one_euro_step"]


@numba.njit(**JIT_OPTIONS)
def kalman_step(
    frame,
    states,
    by_state,
    dt,
    q3,
    q2,
    q1,
    initial_p11,
    max_coast,
    pos,
    vel,
    p00,
    p01,
    p11,
    started,
    unseen,
    upd,
    s,
    innov,
):
    """One constant-velocity Kalman step (``KalmanFilter._step``): ``by_state`` the measurement
    variance of states 0, 1, 2; ``q3, q2, q1`` the process noise ``q dt^3 / 3``, ``q dt^2 / 2``,
    ``q dt``; ``max_coast < 0`` for none. Returns the filtered frame ``(J, 3)`` float64."""
    joints = frame.shape[0]
    out = np.empty((joints, 3))
    for j in range(joints):
        finite = np.isfinite(frame[j, 0]) and np.isfinite(frame[j, 1]) and np.isfinite(frame[j, 2])
        var = by_state[states[j]] if finite else np.inf
        measured = np.isfinite(var)
        if dt > 0.0:  # predict
            for c in range(3):
                pos[j, c] = pos[j, c] + dt * vel[j, c]
            a00 = p00[j] + 2.0 * dt * p01[j] + dt * dt * p11[j] + q3
            a01 = p01[j] + dt * p11[j] + q2
            a11 = p11[j] + q1
            p00[j], p01[j], p11[j] = a00, a01, a11
            unseen[j] = unseen[j] + dt
        update = measured and started[j]  # K = P H^T / (H P H^T + R)
        upd[j] = update
        if update:
            s[j] = p00[j] + var
            k0 = p00[j] / s[j]
            k1 = p01[j] / s[j]
        else:
            s[j] = 1.0
            k0 = 0.0
            k1 = 0.0
        for c in range(3):
            innov[j, c] = frame[j, c] - pos[j, c] if update else 0.0
            pos[j, c] = pos[j, c] + k0 * innov[j, c]
            vel[j, c] = vel[j, c] + k1 * innov[j, c]
        old01 = p01[j]
        p00[j] = (1.0 - k0) * p00[j]
        p01[j] = (1.0 - k0) * old01
        p11[j] = p11[j] - k1 * old01
        if measured and not started[j]:  # start: position measured, velocity 0
            for c in range(3):
                pos[j, c] = frame[j, c]
                vel[j, c] = 0.0
            p00[j] = var
            p01[j] = 0.0
            p11[j] = initial_p11
            started[j] = True
        if measured:
            unseen[j] = 0.0
        if max_coast >= 0.0 and unseen[j] > max_coast:
            for c in range(3):
                vel[j, c] = 0.0
        for c in range(3):
            out[j, c] = pos[j, c] if started[j] else frame[j, c]
    return out


@numba.njit(**JIT_OPTIONS)
def _alpha(cutoff, step):
    """:func:`fpg_gym.filters.one_euro.alpha` of one cutoff (the same operations)."""
    tau = 1.0 / (2.0 * np.pi * cutoff)
    return 1.0 / (1.0 + tau / step)


@numba.njit(**JIT_OPTIONS)
def one_euro_step(frame, states, step, d_cutoff, min_cutoff, beta, value, speed, started):
    """One One-Euro step (``OneEuroFilter._step``) at interval ``step`` > 0, the speed smoothed
    with cutoff ``d_cutoff``; a joint of state 0 (not tracked) or with a non-finite position has
    no measurement. Returns the filtered frame ``(J, 3)`` float64."""
    joints = frame.shape[0]
    out = np.empty((joints, 3))
    raw = np.empty(3)
    new_speed = np.empty(3)
    speed_alpha = _alpha(d_cutoff, step)
    for j in range(joints):
        valid = states[j] != 0 and (
            np.isfinite(frame[j, 0]) and np.isfinite(frame[j, 1]) and np.isfinite(frame[j, 2])
        )
        on = started[j] and valid
        norm = 0.0
        for c in range(3):
            raw[c] = frame[j, c] if valid else 0.0
            v = speed_alpha * (raw[c] - value[j, c]) / step
            new_speed[c] = v + (1.0 - speed_alpha) * speed[j, c]
            norm += new_speed[c] * new_speed[c]
        a = _alpha(min_cutoff + beta * np.sqrt(norm), step)
        for c in range(3):
            value[j, c] = a * raw[c] + (1.0 - a) * value[j, c] if on else raw[c]
            speed[j, c] = new_speed[c] if on else 0.0
            out[j, c] = value[j, c] if valid else frame[j, c]
        started[j] = valid
    return out
