"""The reference joint filters: raw, the Kinect SDK Holt filter and the constant-velocity Kalman.

Expected responses are derived independently of the implementation: the Holt step and ramp
responses from its z-transform (scipy.signal.lfilter), the Kalman noise gain from the discrete
Riccati and Lyapunov equations (scipy.linalg).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from fpg_gym.filters import (
    HOLT_PRESETS,
    INFERRED,
    KALMAN_PRESETS,
    NOT_TRACKED,
    TRACKED,
    HoltFilter,
    KalmanFilter,
    available_filters,
    available_presets,
    fit_noise,
    make_filter,
)

J = 20
DT = 1.0 / 30.0
BASE = np.array([0.3, 1.1, 2.2])  # a camera-space position, metres


def constant_clip(frames: int, point: np.ndarray = BASE) -> np.ndarray:
    return np.broadcast_to(point, (frames, J, 3)).copy()


def holt_linear(smoothing: float, correction: float, prediction: float) -> HoltFilter:
    """A Holt filter whose clamps are out of play (jitter radius at its 0.1 mm floor)."""
    return HoltFilter(
        smoothing=smoothing,
        correction=correction,
        prediction=prediction,
        jitter_radius=0.0,
        max_deviation_radius=1e9,
    )


def holt_transfer(s: float, c: float, p: float) -> tuple[np.ndarray, np.ndarray]:
    """Y/X of the Holt recursion: (1-s)[(1+pc) - (1-c+pc)z^-1] / [1 - (1+s-c+sc)z^-1 + s z^-2]."""
    num = (1.0 - s) * np.array([1.0 + p * c, -(1.0 - c + p * c)])
    den = np.array([1.0, -(1.0 + s - c + s * c), s])
    return num, den


# -- registry ---------------------------------------------------------------------------------


def test_registry_names_presets_and_errors() -> None:
    assert available_filters() == ("raw", "holt", "kalman", "one-euro")
    assert set(available_presets("holt")) >= {"default", "smoothed", "very-smoothed"}
    assert available_presets("kalman") == tuple(KALMAN_PRESETS)
    assert available_presets("raw") == ()
    assert make_filter("holt:very-smoothed").params["smoothing"] == 0.7
    assert make_filter("holt", preset="smoothed", prediction=0.0).params["prediction"] == 0.0
    assert make_filter("HOLT:Very_Smooth").params["jitter_radius"] == 1.0  # alias, case
    assert make_filter("kalman:fast").params["accel_psd"] == KALMAN_PRESETS["fast"].accel_psd
    assert make_filter("kalman", tracked_std=0.02).params["tracked_std"] == 0.02
    with pytest.raises(ValueError, match="unknown filter 'shum'"):
        make_filter("shum")
    with pytest.raises(ValueError, match="unknown Holt preset"):
        make_filter("holt:silky")
    with pytest.raises(ValueError, match="unknown Kalman preset"):
        make_filter("kalman:silky")
    with pytest.raises(ValueError, match="no presets"):
        make_filter("raw:default")
    with pytest.raises(TypeError, match="jitter"):
        make_filter("holt", jitter=0.1)
    for name in ("kalman", "one-euro"):  # every preset filter names its own fields
        with pytest.raises(TypeError, match=r"unknown parameter\(s\) \['speed'\]"):
            make_filter(name, speed=1.0)
    assert make_filter("kalman", not_tracked_std=None).params["not_tracked_std"] is None
    assert make_filter("one-euro", beta=2).params == {**make_filter("one-euro").params, "beta": 2.0}
    with pytest.raises(TypeError, match="takes no parameters"):
        make_filter("raw", smoothing=0.5)
    with pytest.raises(ValueError, match=r"smoothing: expected a value in \[0, 1\]"):
        make_filter("holt", smoothing=1.5)
    with pytest.raises(ValueError, match="tracked_std"):
        make_filter("kalman", tracked_std=0.0)


def test_holt_presets_are_the_sdk_documented_values() -> None:
    # NUI_TRANSFORM_SMOOTH_PARAMETERS remarks (Kinect for Windows SDK 1.8) and KinectJointFilter.h.
    expected = {
        "default": (0.5, 0.5, 0.5, 0.05, 0.04),
        "smoothed": (0.5, 0.1, 0.5, 0.1, 0.1),
        "very-smoothed": (0.7, 0.3, 1.0, 1.0, 1.0),
        "sample": (0.25, 0.25, 0.25, 0.03, 0.05),
    }
    for name, values in expected.items():
        p = HOLT_PRESETS[name]
        got = (p.smoothing, p.correction, p.prediction, p.jitter_radius, p.max_deviation_radius)
        assert got == values, name
        assert p.inferred_scale == 2.0


def test_input_validation() -> None:
    f = make_filter("holt")
    with pytest.raises(ValueError, match=r"positions: expected an array of shape \(J, 3\)"):
        f.update(np.zeros((20, 2)))
    with pytest.raises(ValueError, match=r"states: expected shape \(20,\)"):
        f.update(np.zeros((20, 3)), np.zeros(19, dtype=np.int8))
    with pytest.raises(ValueError, match="tracking states must be 0"):
        f.update(np.zeros((20, 3)), np.full(20, 3))
    f.update(np.ones((20, 3)), timestamp=1.0)
    with pytest.raises(ValueError, match="must not decrease"):
        f.update(np.ones((20, 3)), timestamp=0.5)
    with pytest.raises(ValueError, match="this stream has 20 joints"):
        f.update(np.ones((25, 3)), timestamp=2.0)
    with pytest.raises(ValueError, match="frame 2 goes back in time"):
        f.filter_sequence(np.ones((3, 20, 3)), timestamps=[0.0, 0.1, 0.05])
    with pytest.raises(ValueError, match=r"\(T, J, 3\)"):
        f.filter_sequence(np.ones((20, 3)))


# -- common contract --------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["raw", "holt", "holt:smoothed", "holt:very-smoothed", "kalman"])
def test_filter_sequence_equals_repeated_update_and_is_deterministic(
    name: str, rng: np.random.Generator
) -> None:
    frames = 80
    positions = BASE + np.cumsum(rng.normal(0.0, 0.02, (frames, J, 3)), axis=0)
    states = rng.choice([NOT_TRACKED, INFERRED, TRACKED], p=[0.1, 0.2, 0.7], size=(frames, J))
    positions[5, 3] = np.nan  # a missing measurement must stay local to its joint and frame
    times = np.cumsum(rng.uniform(0.030, 0.036, frames))
    f = make_filter(name)
    whole = f.filter_sequence(positions, states, times)
    again = f.filter_sequence(positions, states, times)
    g = make_filter(name)
    g.update(positions[0] + 1.0, states[0], 0.0)  # stale state that reset() must clear
    g.reset()
    stepwise = np.stack([g.update(positions[t], states[t], times[t]) for t in range(frames)])
    assert whole.dtype == np.float32 and whole.shape == (frames, J, 3)
    np.testing.assert_array_equal(whole, stepwise)
    np.testing.assert_array_equal(whole, again)
    finite = np.ones((frames, J), dtype=bool)
    finite[5, 3] = False
    assert np.isfinite(whole[finite]).all()
    # Continuing a stream: the second half filtered with reset=False equals the stepwise run.
    h = make_filter(name)
    h.filter_sequence(positions[:40], states[:40], times[:40])
    rest = h.filter_sequence(positions[40:], states[40:], times[40:], reset=False)
    np.testing.assert_array_equal(rest, stepwise[40:])


@pytest.mark.parametrize("name", ["raw", "holt", "kalman", "one-euro"])
def test_update_tracked_equals_update_of_tracked_frames(
    name: str, rng: np.random.Generator
) -> None:
    positions = BASE + np.cumsum(rng.normal(0.0, 0.02, (30, J, 3)), axis=0)
    times = np.cumsum(rng.uniform(0.030, 0.036, 30))
    f, g = make_filter(name), make_filter(name)
    for t in range(30):
        np.testing.assert_array_equal(
            f.update_tracked(positions[t], float(times[t])), g.update(positions[t], None, times[t])
        )
    with pytest.raises(ValueError, match="timestamp: expected finite seconds"):
        f.update_tracked(positions[0], float("nan"))


def test_raw_is_the_identity(rng: np.random.Generator) -> None:
    positions = rng.normal(size=(10, J, 3)).astype(np.float32)
    states = rng.integers(0, 3, size=(10, J))
    np.testing.assert_array_equal(make_filter("raw").filter_sequence(positions, states), positions)


# -- Holt (Kinect SDK) ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("s", "c", "p"), [(0.5, 0.5, 0.5), (0.5, 0.1, 0.5), (0.7, 0.3, 1.0), (0.25, 0.25, 0.25)]
)
def test_holt_step_response_is_the_derived_transfer_function(s: float, c: float, p: float) -> None:
    before, after, size = 10, 90, 0.5
    direction = np.array([0.6, 0.0, -0.8])
    clip = constant_clip(before + after)
    clip[before:] += size * direction
    out = holt_linear(s, c, p).filter_sequence(clip)
    # Start-up on a constant input leaves f = x, b = 0, so the step meets a zero initial state.
    np.testing.assert_allclose(out[:before], clip[:before], atol=1e-6)
    num, den = holt_transfer(s, c, p)
    expected = scipy.signal.lfilter(num, den, np.ones(after))  # unit step response
    response = (out[before:, 0] - BASE) @ direction / size
    np.testing.assert_allclose(out[before:], out[before:, :1].repeat(J, axis=1))  # same per joint
    # Exact while the residual exceeds the 0.1 mm jitter floor (the clamp's linear regime).
    linear = np.abs(size * (1.0 - expected)) > 1e-3
    linear[np.argmin(linear) :] = False
    assert linear[:8].all()
    np.testing.assert_allclose(response[linear], expected[linear], atol=2e-6)
    # Converged down to the jitter floor (0.1 mm), where the clamp freezes the residual.
    assert np.abs(size * (1.0 - response[-10:])).max() <= 1e-4 + 1e-6
    # Documented lag: the frames the derived response needs to settle within 2 % of the step.
    settle = int(np.nonzero(np.abs(1.0 - expected) > 0.02)[0].max()) + 1
    assert np.abs(1.0 - response[settle:]).max() <= 0.02 + 1e-6
    assert np.abs(1.0 - response[settle - 1]) > 0.02 - 1e-6


@pytest.mark.parametrize("prediction", [0.0, 0.5, 1.0])
def test_holt_follows_a_ramp_without_lag_and_leads_by_the_prediction(prediction: float) -> None:
    speed = 0.01  # metres per frame (0.3 m/s)
    frames = 120
    ramp = constant_clip(frames)
    ramp[:, :, 0] += speed * np.arange(frames)[:, None]
    out = holt_linear(0.5, 0.5, prediction).filter_sequence(ramp)
    lead = out[-30:, :, 0] - ramp[-30:, :, 0]
    # Holt's trend removes the steady-state lag on a ramp; the output leads by `prediction` frames.
    np.testing.assert_allclose(lead, prediction * speed, atol=1e-6)


def test_holt_max_deviation_clamp_bounds_the_output() -> None:
    clip = constant_clip(40)
    clip[10:, :, 1] += 0.5
    states = np.full((40, J), TRACKED, dtype=np.int8)
    states[:, 1] = INFERRED
    f = HoltFilter("default")
    out = f.filter_sequence(clip, states)
    dist = np.linalg.norm(out - clip, axis=2)
    md = HOLT_PRESETS["default"].max_deviation_radius
    assert dist[:, 0].max() <= md + 1e-6
    assert dist[10, 0] == pytest.approx(md, abs=1e-6)  # the clamp is active at the step
    assert dist[:, 1].max() <= 2 * md + 1e-6  # inferred: doubled radius
    assert dist[10, 1] == pytest.approx(2 * md, abs=1e-6)


def test_holt_jitter_clamp_damps_a_sub_radius_impulse_exactly() -> None:
    s, c, p, r = 0.5, 0.5, 0.5, 0.05
    for a in (0.01, 0.03):
        clip = constant_clip(11)
        clip[10, :, 2] += a
        out = HoltFilter("default").filter_sequence(clip)
        moved = out[10, 0, 2] - BASE[2]
        # The raw sample is pulled to prev + (a/r)*a; then level (1-s)x, trend c*level, + p*trend.
        assert moved == pytest.approx((1 - s) * (1 + p * c) * a * a / r, abs=1e-7)
        free = holt_linear(s, c, p).filter_sequence(clip)[10, 0, 2] - BASE[2]
        assert free == pytest.approx((1 - s) * (1 + p * c) * a, abs=1e-7)
        assert moved == pytest.approx(free * a / r, abs=1e-7)  # damped by the factor a / r


@pytest.mark.parametrize("fraction", [0.1, 0.2, 0.5])
def test_holt_jitter_clamp_holds_sub_radius_noise_near_the_previous_value(
    fraction: float, rng: np.random.Generator
) -> None:
    r = HOLT_PRESETS["default"].jitter_radius
    amplitude = fraction * r
    frames = 300
    direction = rng.normal(size=(frames, J, 3))
    direction /= np.linalg.norm(direction, axis=2, keepdims=True)
    noise = direction * rng.uniform(0.0, amplitude, (frames, J, 1))
    noise[:10] = 0.0
    clip = constant_clip(frames) + noise
    clamped = HoltFilter("default").filter_sequence(clip)[10:] - BASE
    free = holt_linear(0.5, 0.5, 0.5).filter_sequence(clip)[10:] - BASE

    def rms_motion(out: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum(np.diff(out, axis=0) ** 2, axis=2))))

    # Each frame's move towards the raw sample is scaled by d / r, d its distance from the
    # previous value (<= the noise amplitude near the held value), so the output's frame-to-frame
    # motion is at most amplitude / r of the unclamped filter's ...
    assert rms_motion(clamped) <= fraction * rms_motion(free)
    # ... and the output stays inside the noise ball around the held value.
    assert np.linalg.norm(clamped, axis=2).max() <= amplitude


def test_holt_inferred_joints_use_doubled_radii() -> None:
    s, c, p, r = 0.5, 0.5, 0.5, 0.05
    a = 0.07  # beyond the tracked jitter radius, within the inferred one
    clip = constant_clip(11)
    clip[10, :, 0] += a
    states = np.full((11, J), TRACKED, dtype=np.int8)
    states[10, 1] = INFERRED
    out = HoltFilter("default").filter_sequence(clip, states)
    assert out[10, 0, 0] - BASE[0] == pytest.approx((1 - s) * (1 + p * c) * a, abs=1e-7)
    assert out[10, 1, 0] - BASE[0] == pytest.approx(
        (1 - s) * (1 + p * c) * a * a / (2 * r), abs=1e-7
    )
    # inferred_scale=1 treats inferred joints like tracked ones.
    same = HoltFilter("default", inferred_scale=1.0).filter_sequence(clip, states)
    np.testing.assert_array_equal(same[10, 1], same[10, 0])


def test_holt_not_tracked_joint_passes_through_and_restarts(rng: np.random.Generator) -> None:
    frames = 30
    clip = BASE + np.cumsum(rng.normal(0.0, 0.03, (frames, J, 3)), axis=0)
    states = np.full((frames, J), TRACKED, dtype=np.int8)
    states[12, 4] = NOT_TRACKED
    clip[12, 4] = 0.0  # what Kinect v1 reports for a not-tracked joint
    clip[20, 5] = np.nan  # a non-finite position counts as not tracked
    f = HoltFilter("default")
    out = f.filter_sequence(clip, states)
    np.testing.assert_array_equal(out[12, 4], clip[12, 4].astype(np.float32))
    assert np.isnan(out[20, 5]).all()
    # The filter of that joint restarts: the SDK's first frame returns the raw position ...
    for joint, k in ((4, 12), (5, 20)):
        np.testing.assert_allclose(out[k + 1, joint], clip[k + 1, joint], atol=1e-6)
        p = HOLT_PRESETS["default"]
        # ... and its second frame the mean of the two raw positions plus the predicted trend.
        level = 0.5 * (clip[k + 1, joint] + clip[k + 2, joint])
        trend = p.correction * (level - clip[k + 1, joint])
        pred = level + p.prediction * trend
        err = np.linalg.norm(pred - clip[k + 2, joint])
        if err > p.max_deviation_radius:
            pred = clip[k + 2, joint] + (pred - clip[k + 2, joint]) * p.max_deviation_radius / err
        np.testing.assert_allclose(out[k + 2, joint], pred, atol=1e-6)
    # Other joints are unaffected: equal to a run without the dropouts.
    clean = HoltFilter("default").filter_sequence(np.where(np.isnan(clip), 0.0, clip))
    others = np.ones(J, dtype=bool)
    others[[4, 5]] = False
    np.testing.assert_array_equal(out[:, others], clean[:, others])


def test_holt_none_preset_returns_the_raw_data(rng: np.random.Generator) -> None:
    clip = rng.normal(size=(20, J, 3)).astype(np.float32)
    np.testing.assert_array_equal(make_filter("holt:none").filter_sequence(clip), clip)


# -- Kalman -----------------------------------------------------------------------------------


def steady_state_noise_gain(q: float, sigma: float, dt: float) -> tuple[float, float]:
    """(error variance of the position estimate for white measurement noise on a constant,
    steady-state prior position variance), from the Riccati and Lyapunov equations."""
    f = np.array([[1.0, dt], [0.0, 1.0]])
    qm = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    h = np.array([[1.0, 0.0]])
    prior = scipy.linalg.solve_discrete_are(f.T, h.T, qm, np.array([[sigma**2]]))
    gain = prior @ h.T / (prior[0, 0] + sigma**2)
    closed = (np.eye(2) - gain @ h) @ f  # x_n = closed x_{n-1} + gain z_n
    cov = scipy.linalg.solve_discrete_lyapunov(closed, gain @ gain.T * sigma**2)
    return float(cov[0, 0]), float(prior[0, 0])


@pytest.mark.parametrize("accel_psd", [KALMAN_PRESETS["default"].accel_psd, 0.05])
def test_kalman_reduces_the_variance_of_a_noisy_constant(
    accel_psd: float, rng: np.random.Generator
) -> None:
    sigma = KALMAN_PRESETS["default"].tracked_std
    frames, skip = 900, 90
    noisy = constant_clip(frames) + rng.normal(0.0, sigma, (frames, J, 3))
    out = KalmanFilter(accel_psd=accel_psd).filter_sequence(noisy)
    error_var = float(np.var(out[skip:] - BASE))
    expected, _ = steady_state_noise_gain(accel_psd, sigma, DT)
    assert expected < sigma**2
    # Within sampling error of the derived steady-state value (~54,000 correlated samples).
    assert error_var == pytest.approx(expected, rel=0.1)
    assert error_var < float(np.var(noisy[skip:] - BASE))


def test_kalman_follows_a_ramp_without_bias(rng: np.random.Generator) -> None:
    p = KALMAN_PRESETS["default"]
    frames, skip, speed = 600, 90, 0.5  # 0.5 m/s: 16.7 mm per frame
    # Irregular frame times (33/34 ms, as real Kinect v2 streams): the filter must use them.
    times = np.cumsum(np.where(np.arange(frames) % 3 == 0, 0.0341, 0.0329))
    truth = constant_clip(frames)
    truth[:, :, 0] += speed * times[:, None]
    truth[:, :, 1] -= 0.5 * speed * times[:, None]
    noisy = truth + rng.normal(0.0, p.tracked_std, truth.shape)
    out = KalmanFilter().filter_sequence(noisy, timestamps=times)
    error = out[skip:] - truth[skip:]
    bias = error.reshape(-1, 3).mean(axis=0)
    # Unbiased: |mean error| within 4 standard errors (frames correlated over ~10 frames) and
    # far below one frame of motion, which a lagging filter would show.
    standard_error = error.reshape(-1, 3).std(axis=0) / np.sqrt(error.shape[0] * J / 10)
    assert (np.abs(bias) <= 4 * standard_error).all()
    assert np.abs(bias).max() < 0.05 * speed * DT
    assert np.sqrt(np.mean(error**2)) < p.tracked_std
    # Dropped frames: a 0.3 s gap in the timestamps is bridged by the prediction. Its error after
    # the update has per-axis variance <= R (posterior <= measurement variance): mean norm about
    # sqrt(3) sigma; a filter that ignored the gap would be off by about speed * 0.27 s = 13 cm.
    gap_times = times.copy()
    gap_times[300:] += 0.3 - (times[300] - times[299])
    gap_truth = constant_clip(frames)
    gap_truth[:, :, 0] += speed * gap_times[:, None]
    noisy = gap_truth + rng.normal(0.0, p.tracked_std, truth.shape)
    out = KalmanFilter().filter_sequence(noisy, timestamps=gap_times)
    after_gap = np.linalg.norm(out[300] - gap_truth[300], axis=1).mean()
    assert after_gap < 2 * np.sqrt(3) * p.tracked_std


def test_kalman_inferred_measurements_weigh_less_and_not_tracked_are_ignored() -> None:
    p = KALMAN_PRESETS["default"]
    frames = 200
    clip = constant_clip(frames + 1)
    clip[frames, :, 2] += 0.1  # a 10 cm outlier on the last frame
    states = np.full((frames + 1, J), TRACKED, dtype=np.int8)
    states[frames, 1] = INFERRED
    states[frames, 2] = NOT_TRACKED
    out = KalmanFilter().filter_sequence(clip, states)
    _, prior = steady_state_noise_gain(p.accel_psd, p.tracked_std, DT)
    jump = out[frames, :, 2] - BASE[2]
    # The jump is the Kalman gain P/(P + R) times the innovation, with R from the state.
    assert jump[0] == pytest.approx(0.1 * prior / (prior + p.tracked_std**2), rel=1e-3)
    assert jump[1] == pytest.approx(0.1 * prior / (prior + p.inferred_std**2), rel=1e-3)
    assert jump[1] < 0.1 * jump[0]
    assert jump[2] == pytest.approx(0.0, abs=1e-6)  # update skipped
    # With not_tracked_std set, a not-tracked position pulls a little, less than an inferred one.
    weak = KalmanFilter(not_tracked_std=0.5).filter_sequence(clip, states)[frames, 2, 2] - BASE[2]
    assert 0.0 < weak < jump[1]


def test_kalman_coasts_through_short_gaps_then_holds(rng: np.random.Generator) -> None:
    frames, speed = 120, 0.6
    times = np.arange(frames) * DT
    truth = constant_clip(frames)
    truth[:, :, 0] += speed * times[:, None]
    states = np.full((frames, J), TRACKED, dtype=np.int8)
    states[60:65, 0] = NOT_TRACKED  # 5 frames: under max_coast (0.3 s = 9 frames)
    states[60:100, 1] = NOT_TRACKED  # 40 frames: longer
    reported = truth.copy()
    reported[states == NOT_TRACKED] = 0.0  # garbage positions must not be used
    out = KalmanFilter().filter_sequence(reported, states, times)
    # Short gap: the constant-velocity prediction keeps following the ramp.
    assert np.abs(out[60:65, 0] - truth[60:65, 0]).max() < 1e-3
    # Long gap: after max_coast (0.3 s, 9 frames after the last measurement at frame 59) the
    # joint holds its position instead of drifting.
    held = out[70:100, 1]
    np.testing.assert_allclose(held, held[:1].repeat(len(held), axis=0), atol=1e-6)
    assert truth[67, 1, 0] - 1e-3 <= held[0, 0] <= truth[69, 1, 0] + 1e-3
    # After the gap the joint re-acquires the measurements.
    assert np.abs(out[-1, 1] - truth[-1, 1]).max() < 5e-3
    # A joint never measured returns its input until its first measurement.
    states[:10, 3] = NOT_TRACKED
    out = KalmanFilter().filter_sequence(reported, states, times)
    np.testing.assert_array_equal(out[:10, 3], reported[:10, 3].astype(np.float32))
    np.testing.assert_allclose(out[10, 3], truth[10, 3], atol=1e-6)


def test_fit_noise_recovers_the_simulated_parameters(rng: np.random.Generator) -> None:
    q, sigma, frames = 2.0, 0.01, 300
    # Exact discretisation of the white-noise acceleration model.
    cov = q * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]])
    steps = rng.multivariate_normal(np.zeros(2), cov, size=(frames, J, 3))
    pos = np.zeros((frames, J, 3))
    vel = np.zeros((J, 3))
    for t in range(1, frames):
        pos[t] = pos[t - 1] + DT * vel + steps[t, ..., 0]
        vel = vel + steps[t, ..., 1]
    noisy = BASE + pos + rng.normal(0.0, sigma, pos.shape)
    fitted = fit_noise(noisy)
    assert fitted.accel_psd == pytest.approx(q, rel=0.25)
    assert fitted.tracked_std == pytest.approx(sigma, rel=0.1)
