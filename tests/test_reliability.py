"""Reliability terms (Shum §IV, FPG §5) on hand-made trajectories."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.core.compiled import numpy_only
from fpg_gym.reconstruct.reliability import (
    ReliabilityConfig,
    ReliabilityEstimator,
    SortedWindow,
    behaviour_angles,
    is_neutral_pose,
    kinematic_reliability,
    reliability_of_sequence,
)

HAND = skeleton.joint_index("HandLeft")
ELBOW = skeleton.joint_index("ElbowLeft")
WRIST = skeleton.joint_index("WristLeft")
KNEE = skeleton.joint_index("KneeRight")


def standing(frames: int, speed: float = 0.0) -> np.ndarray:
    """A rest pose translated along +X by ``speed`` metres per frame, 1 m in front of a camera."""
    base = poses.rest_pose() + np.array([0.0, 1.0, 2.5], dtype=np.float32)
    steps = np.arange(frames, dtype=np.float32)[:, None, None] * np.array([speed, 0, 0], np.float32)
    return (base[None] + steps).astype(np.float32)


def tracked(frames: int) -> np.ndarray:
    return np.full((frames, skeleton.NUM_JOINTS), 2, dtype=np.int8)


def t_pose() -> np.ndarray:
    pose = poses.rest_pose().astype(np.float64)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        shoulder = skeleton.joint_index(f"Shoulder{side}")
        for j, dist in ((f"Elbow{side}", 0.28), (f"Wrist{side}", 0.53), (f"Hand{side}", 0.61)):
            pose[skeleton.joint_index(j)] = pose[shoulder] + [sign * dist, 0.0, 0.0]
    return pose.astype(np.float32)


# Gaussian weights over the last 6 frames, sigma = 2 frames, worked by hand:
# exp(-f^2 / 8) for f = 0..5 = 1, 0.8824969, 0.6065307, 0.3246525, 0.1353353, 0.0439369, which
# sum to 2.9929522; divided by the sum:
HAND_WEIGHTS = (0.3341183, 0.2948583, 0.2026530, 0.1084723, 0.0452180, 0.0146801)


def test_weights_are_gaussian_newest_heaviest() -> None:
    w = ReliabilityConfig().weights()
    assert w.shape == (6,)
    np.testing.assert_allclose(w, HAND_WEIGHTS, atol=1e-7)
    # sigma = 1: exp(-f^2 / 2) = 1, 0.6065307, 0.1353353, 0.0111090 over 4 frames, sum 1.7529750.
    w1 = ReliabilityConfig(smoothing_frames=4, smoothing_sigma=1.0).weights()
    np.testing.assert_allclose(w1, [0.5704588, 0.3460008, 0.0772032, 0.0063372], atol=1e-7)


def test_behaviour_window_is_the_last_three_angles_by_hand() -> None:
    """``Rb`` over f_b = 3 direction-change angles, the hand's path chosen to make them
    180, 180, 180, 90, 90, 0 degrees at frames 2..7 (frames 0 and 1 have no angle yet).

    Rb = 1 - clamp(mean - 90, 0, 45) / 45 with the mean over the last three angles:
    frame 2: [180] -> 0; 3: [180, 180] -> 0; 4: [180, 180, 180] -> 0;
    frame 5: [180, 180, 90] = 150 -> 0; frame 6: [180, 90, 90] = 120 -> 1 - 30/45 = 1/3;
    frame 7: [90, 90, 0] = 60 -> 1. (A window of 4 gives 135 -> 0 at frame 6; of 2, 90 -> 1.)
    """
    steps = 0.1 * np.array(  # the hand's displacement d(t) = p(t) - p(t-1), t = 1..7
        [[1, 0, 0], [-1, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [1, 0, 0], [1, 0, 0]]
    )
    clip = standing(8)  # the rest of the body stands still
    clip[1:, HAND] += np.cumsum(steps, axis=0).astype(np.float32)
    behaviour = reliability_of_sequence(clip, tracked(8))["behaviour"]
    expected = [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0 / 3.0, 1.0]
    np.testing.assert_allclose(behaviour[:, HAND], expected, atol=1e-5)
    assert np.all(np.delete(behaviour, HAND, axis=1) == 1.0)


def test_gaussian_filter_of_the_minimum_by_hand() -> None:
    """R = sum_f w(f) min(Rb, Rk, Rt)(t - f): the knee inferred (Rt = 0) from frame 2 on.

    With three frames seen (minima 0, 1, 1, newest first) the weights are the first three,
    renormalised: R = (0.8824969 + 0.6065307) / 2.4890276 = 0.5982367. Frame 5 (minima 0, 0, 0,
    0, 1, 1): R = w(4) + w(5) = 0.0452180 + 0.0146801 = 0.0598981. Frame 6: R = w(5) = 0.0146801;
    frame 7 and later: 0.
    """
    clip = standing(9)
    states = tracked(9)
    states[2:, KNEE] = 1
    r = reliability_of_sequence(clip, states)["reliability"][:, KNEE]
    np.testing.assert_allclose(r[:2], 1.0)
    assert r[2] == pytest.approx(0.5982367, abs=1e-6)
    assert r[5] == pytest.approx(0.0598981, abs=1e-6)
    assert r[6] == pytest.approx(0.0146801, abs=1e-6)
    assert np.all(r[7:] == 0.0)


def test_behaviour_angle_definition() -> None:
    a = np.array([[0.1, 0, 0], [0.1, 0, 0], [0.01, 0, 0]])
    b = np.array([[0.1, 0, 0], [-0.1, 0, 0], [-0.1, 0, 0]])
    angles = behaviour_angles(a, b, 0.03)
    assert np.allclose(angles, [0.0, np.pi, 0.0])  # the last is below d_min
    # Exactly d_min is not shorter than d_min: the angle counts (90 deg, then 180 deg).
    at_d_min = behaviour_angles(
        np.array([[0.03, 0.0, 0.0], [0.0, 0.0, 0.03]]), np.array([[0.0, 0.03, 0.0]] * 2), 0.03
    )
    assert np.allclose(at_d_min, [np.pi / 2, np.pi / 2])
    assert behaviour_angles(np.array([0.0, 0.0, -0.03]), np.array([0.0, 0.0, 0.03]), 0.03) == (
        pytest.approx(np.pi)
    )


@pytest.mark.parametrize("numpy_twin", [False, True])
def test_behaviour_angles_at_their_edges_in_each_twin(numpy_twin: bool) -> None:
    """Each twin (the compiled one when numba is installed, and the numpy one) gives 0 when
    either vector is shorter than d_min (the newer or the older), the exact angle of two
    nearly parallel vectors (the cosine is clipped at 1, not below), and 0, not NaN, for
    parallel vectors whose computed cosine rounds above 1."""
    parallel = np.array([0.328, -0.091, 0.05])  # cos(parallel, 2 parallel) rounds to 1 + 2e-16
    small = np.radians(1.0)
    with numpy_only() if numpy_twin else contextlib.nullcontext():
        angles = behaviour_angles(
            np.array([[0.1, 0.0, 0.0], [0.01, 0.0, 0.0], [0.1, 0.0, 0.0], parallel]),
            np.array(
                [
                    [0.0, 0.01, 0.0],
                    [-0.1, 0.0, 0.0],
                    [0.1 * np.cos(small), 0.1 * np.sin(small), 0.0],
                    2.0 * parallel,
                ]
            ),
            0.03,
        )
    assert angles[0] == 0.0 and angles[1] == 0.0  # the older, then the newer vector is short
    assert angles[2] == pytest.approx(small, abs=1e-9)
    assert angles[3] == 0.0


def test_vibrating_joint_loses_behaviour_reliability_while_walking() -> None:
    frames = 20
    clip = standing(frames, speed=0.05)  # walking sideways 1.5 m/s
    clip[:, HAND, 1] += 0.05 * (-1.0) ** np.arange(frames)  # +/- 5 cm every frame
    terms = reliability_of_sequence(clip, tracked(frames))
    late = slice(10, None)
    assert np.all(terms["behaviour"][late, HAND] == 0.0)  # 180 deg reversals -> 0
    others = np.delete(np.arange(skeleton.NUM_JOINTS), HAND)
    assert np.all(terms["behaviour"][late][:, others] == 1.0)
    assert np.all(terms["reliability"][late, HAND] < 0.05)
    # The wrist shares the vibrating hand's bone, so only its kinematic term drops.
    far = np.delete(np.arange(skeleton.NUM_JOINTS), [HAND, WRIST])
    assert np.all(terms["reliability"][late][:, far] > 0.99)


def test_root_vibration_is_measured_in_camera_space() -> None:
    """The whole body shaking +/- 5 cm along X every frame: in camera space the root reverses
    its direction each frame (180 deg, Rb = 0 from frame 2 on); every other joint is still
    relative to the root (Rb = 1)."""
    frames = 8
    clip = standing(frames)
    clip[:, :, 0] += (0.05 * (-1.0) ** np.arange(frames, dtype=np.float32))[:, None]
    behaviour = reliability_of_sequence(clip, tracked(frames))["behaviour"]
    root = skeleton.ROOT
    np.testing.assert_allclose(behaviour[:, root], [1, 1, 0, 0, 0, 0, 0, 0], atol=1e-6)
    assert np.all(np.delete(behaviour, root, axis=1) == 1.0)


def test_stretching_bone_lowers_kinematic_reliability_of_its_joints() -> None:
    frames = 30
    clip = standing(frames)
    stretch = np.linspace(0.0, 0.3, frames, dtype=np.float32)
    clip[:, HAND, 1] -= stretch  # the wrist-hand bone grows from 8 cm to 38 cm
    lengths = poses.DEFAULT_BONE_LENGTHS
    terms = reliability_of_sequence(clip, tracked(frames), reference_lengths=lengths)
    kin = terms["kinematic"]
    assert kin[0, HAND] == pytest.approx(1.0)
    assert kin[-1, HAND] == pytest.approx(0.0)  # relative error clamps at 1
    # The wrist has two bones; one is fully wrong, so Rk = 1 - (1 + 0) / 2.
    assert kin[-1, WRIST] == pytest.approx(0.5)
    assert np.all(np.diff(kin[:, HAND]) <= 1e-12)
    assert np.allclose(np.delete(kin[-1], [HAND, WRIST]), 1.0)
    # The hand moves in a straight line (Rb = 1) and is tracked (Rt = 1): min(Rb, Rk, Rt) = Rk.
    # The 8 cm bone is 100 % too long once the stretch passes 8 cm (frame 8 of 0.3 / 29 per
    # frame), so Rk = 0 on the last six frames and the smoothed R is 0 there too.
    np.testing.assert_array_equal(terms["minimum"][:, HAND], kin[:, HAND])
    assert np.all(kin[-6:, HAND] == 0.0) and np.all(terms["reliability"][-1, HAND] == 0.0)


def test_kinematic_reliability_matches_naive_loop(rng: np.random.Generator) -> None:
    lengths = rng.uniform(0.05, 0.5, skeleton.NUM_BONES)
    reference = rng.uniform(0.05, 0.5, skeleton.NUM_BONES)
    got = kinematic_reliability(lengths, reference)
    for j in range(skeleton.NUM_JOINTS):
        bones = [b for b, (p, c) in enumerate(skeleton.BONES) if j in (p, c)]
        dev = [min(abs(lengths[b] - reference[b]) / reference[b], 1.0) for b in bones]
        assert got[j] == pytest.approx(1.0 - np.mean(dev))


def test_inferred_joint_fades_out_with_the_gaussian_filter() -> None:
    frames = 14
    clip = standing(frames)
    states = tracked(frames)
    states[6:, KNEE] = 1  # inferred from frame 6 (the filter window is full by then)
    terms = reliability_of_sequence(clip, states)
    assert np.all(terms["tracking"][6:, KNEE] == 0.0)
    assert np.all(terms["tracking"][:6, KNEE] == 1.0)
    r = terms["reliability"][:, KNEE]
    w = np.array(HAND_WEIGHTS)  # worked by hand above, not computed by the code under test
    assert r[5] == pytest.approx(1.0)
    assert r[6] == pytest.approx(1.0 - w[0])  # the newest frame has weight w(0)
    assert r[7] == pytest.approx(1.0 - w[0] - w[1])
    assert np.all(r[11:] == 0.0)  # six inferred frames: nothing left
    assert np.all(np.diff(r[5:12]) < 0)
    # Before the window fills, the weights are renormalised over the frames seen.
    states[2:, KNEE] = 1
    r = reliability_of_sequence(clip, states)["reliability"][:, KNEE]
    assert r[2] == pytest.approx(1.0 - w[0] / w[:3].sum())


def test_a_scale_multiplies_the_filtered_reliability_only(rng: np.random.Generator) -> None:
    clip = standing(8, speed=0.01)
    states = tracked(8)
    states[4:, KNEE] = 1
    plain, scaled = ReliabilityEstimator(), ReliabilityEstimator()
    for pose, state in zip(clip, states, strict=True):
        scale = rng.uniform(0.0, 1.0, skeleton.NUM_JOINTS)
        a, b = plain.update(pose, state), scaled.update(pose, state, scale)
        assert np.array_equal(b.reliability, a.reliability * scale)
        for name in ("behaviour", "kinematic", "tracking", "minimum", "reference_lengths"):
            assert np.array_equal(getattr(b, name), getattr(a, name))


def test_neutral_and_t_pose_detection() -> None:
    assert is_neutral_pose(poses.rest_pose())
    assert is_neutral_pose(t_pose())
    bent = poses.rest_pose().copy()
    bent[KNEE] += np.array([0.0, 0.2, 0.35], dtype=np.float32)  # knee raised forward
    assert not is_neutral_pose(bent)
    yawed = poses.denormalise(t_pose(), poses.Placement(np.zeros(3), np.array(1.2)))
    assert is_neutral_pose(yawed)  # heading does not matter


def test_reference_lengths_come_from_neutral_frames_with_documented_fallbacks() -> None:
    scale = 1.1
    user = poses.DEFAULT_BONE_LENGTHS * scale
    pose = poses.rest_pose(user) + np.array([0.0, 1.0, 2.5], dtype=np.float32)
    est = ReliabilityEstimator()
    states = np.full(skeleton.NUM_JOINTS, 1, dtype=np.int8)  # nothing tracked yet
    terms = est.update(pose, states)
    assert terms.reference_source == "prior-height"
    assert np.allclose(terms.reference_lengths, user, rtol=0.02)  # prior x height ratio
    # A crouching, partly tracked frame: one size factor times the prior proportions.
    crouch = pose.copy()
    crouch[KNEE] += np.array([0.0, 0.1, 0.3], dtype=np.float32)  # two bones change length
    partial = np.full(skeleton.NUM_JOINTS, 2, dtype=np.int8)
    partial[HAND] = 1
    terms = est.update(crouch, partial)
    assert terms.reference_source == "scaled-prior"
    assert np.allclose(terms.reference_lengths, user, rtol=1e-6)  # the median ratio is 1.1
    assert not terms.calibration_frame
    # The per-bone alternative takes the tracked bones as measured.
    other = ReliabilityEstimator(ReliabilityConfig(fallback="tracked-median"))
    terms = other.update(crouch, partial)
    assert terms.reference_source == "tracked-median"
    measured = poses.bone_lengths(crouch)
    hand_bone = skeleton.BONE_OF_JOINT[HAND]
    others = np.delete(np.arange(skeleton.NUM_BONES), hand_bone)
    assert np.allclose(terms.reference_lengths[others], measured[others])
    assert terms.reference_lengths[hand_bone] == pytest.approx(user[hand_bone], rel=0.05)
    # A given prior sets the proportions.
    prior = np.linspace(0.1, 0.3, skeleton.NUM_BONES)
    terms = ReliabilityEstimator(prior_lengths=prior).update(crouch, partial)
    ratio = terms.reference_lengths / prior
    assert np.allclose(ratio, ratio[0])
    # A fully tracked T-pose calibrates.
    calib = poses.retarget(t_pose(), user) + np.array([0.2, 1.0, 2.0], dtype=np.float32)
    terms = est.update(calib, tracked(1)[0])
    assert terms.calibration_frame
    assert terms.reference_source == "neutral"
    assert np.allclose(terms.reference_lengths, user, atol=1e-5)
    # Later non-neutral frames do not move it.
    terms = est.update(crouch * 1.3, tracked(1)[0])
    assert np.allclose(terms.reference_lengths, user, atol=1e-5)
    assert est.calibration_frames == 1


def test_given_reference_lengths_are_used_as_is() -> None:
    fixed = np.full(skeleton.NUM_BONES, 0.2)
    est = ReliabilityEstimator(reference_lengths=fixed)
    terms = est.update(standing(1)[0], tracked(1)[0])
    assert terms.reference_source == "given"
    assert np.array_equal(terms.reference_lengths, fixed)
    with pytest.raises(ValueError, match="reference_lengths"):
        ReliabilityEstimator(reference_lengths=np.ones(3))


def test_bad_input_shapes_are_reported() -> None:
    est = ReliabilityEstimator()
    with pytest.raises(ValueError, match="positions"):
        est.update(np.zeros((19, 3)), np.zeros(20))
    with pytest.raises(ValueError, match="states"):
        est.update(np.zeros((20, 3)), np.zeros(19))
    with pytest.raises(ValueError, match="theta"):
        ReliabilityConfig(theta_floor_deg=140.0)
    with pytest.raises(ValueError, match="fallback"):
        ReliabilityConfig(fallback="guess")
    with pytest.raises(ValueError, match="prior_lengths"):
        ReliabilityEstimator(prior_lengths=np.zeros(19))


def test_no_body_frame_is_unreliable_everywhere_and_restarts_behaviour() -> None:
    frames = 10
    clip = standing(frames)
    states = tracked(frames)
    clip[5] = 0.0
    states[5] = 0
    terms = reliability_of_sequence(clip, states)
    assert np.all(terms["reliability"][5] == 0.0)
    # The jump to (0, 0, 0) and back is not taken for vibration once the body is back.
    assert np.all(terms["behaviour"][6:] == 1.0)


def test_sorted_window_median_equals_nanmedian_of_its_rows() -> None:
    rng = np.random.default_rng(7)
    window, cap, ring = SortedWindow(), 12, []
    for step in range(80):  # rows with NaN gaps and repeated values, the oldest leaving
        row = np.round(rng.normal(1.0, 0.1, 19), 2)
        row[rng.random(19) < 0.3] = np.nan
        if len(ring) == cap:
            window.remove(ring.pop(0))
        ring.append(row)
        window.add(row)
        expected = np.nanmedian(np.stack(ring))
        assert window.median() == expected, step  # to the last bit
        assert len(window) == np.isfinite(np.stack(ring)).sum()
    assert np.isnan(SortedWindow().median())


def _mixed_stream(rng: np.random.Generator, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Calibration frames (rest and T-poses, slightly noisy), moving and vibrating frames with
    joints inferred or lost, and frames without a body."""
    clip = standing(frames, 0.01).astype(np.float64)
    clip[frames // 3 : frames // 2] = t_pose() + np.array([0.0, 1.0, 2.5])
    clip += rng.normal(0.0, 0.004, clip.shape)
    clip[frames // 2 :, HAND] += rng.normal(0.0, 0.05, (frames - frames // 2, 3))  # vibrates
    clip[2 * frames // 3 :, KNEE, 1] += 0.08  # a stretched shin
    states = tracked(frames)
    states[0] = 1  # no tracked bone yet: the prior scaled by the height
    states[:6, KNEE] = 1  # no calibration frame yet: the scaled prior
    lost = rng.random(states.shape) < 0.2
    lost[: frames // 2] = False
    states[lost] = rng.integers(0, 2, lost.sum())
    states[frames // 4 : frames // 4 + 3] = 0  # no body
    return clip.astype(np.float32), states


@pytest.mark.parametrize(
    "settings",
    [
        {},
        {"fallback": "tracked-median", "max_reference_frames": 7},
        {"max_reference_frames": 5, "behaviour_frames": 2, "smoothing_frames": 3},
        {"given": True},
    ],
)
def test_the_compiled_frame_gives_the_numpy_definitions_terms(settings: dict) -> None:
    """``compiled_reliability.reliability_frame`` (with numba) against the numpy code of
    ``ReliabilityEstimator.update``: the same reference lengths, sources and calibration frames
    to the bit, the terms to rounding (the behaviour angles' arccos), through calibration, the
    windows' wrap-around, lost joints, frames without a body and a motion restart."""
    settings = dict(settings)
    given = settings.pop("given", False)
    config = ReliabilityConfig(**settings)
    clip, states = _mixed_stream(np.random.default_rng(3), 60)
    runs = []
    for numpy_twin in (False, True):
        with numpy_only() if numpy_twin else contextlib.nullcontext():
            estimator = ReliabilityEstimator(
                config, poses.DEFAULT_BONE_LENGTHS * 1.1 if given else None
            )
            frames = []
            for t in range(len(clip)):
                if t == 40:
                    estimator.forget_motion()
                frames.append(estimator.update(clip[t], states[t]))
            runs.append(frames)
    calibrated = 0
    for compiled, reference in zip(*runs, strict=True):
        assert compiled.reference_source == reference.reference_source
        assert compiled.calibration_frame == reference.calibration_frame
        np.testing.assert_array_equal(compiled.reference_lengths, reference.reference_lengths)
        np.testing.assert_array_equal(compiled.tracking, reference.tracking)
        for name in ("reliability", "behaviour", "kinematic", "minimum"):
            np.testing.assert_allclose(
                getattr(compiled, name), getattr(reference, name), rtol=0, atol=1e-12
            )
        calibrated += compiled.calibration_frame
    assert given or calibrated > 5  # the stream calibrates (rest and T-poses)
    sources = {frame.reference_source for frame in runs[0]}
    fallback = "tracked-median" if config.fallback == "tracked-median" else "scaled-prior"
    assert sources == ({"given"} if given else {"prior-height", fallback, "neutral"})


def test_the_compiled_neutral_pose_check_decides_as_the_numpy_one() -> None:
    """``compiled_reliability.neutral_pose`` against :func:`is_neutral_pose` on rest and T-poses
    turned, bent and noisy, many of them near the tolerance."""
    from fpg_gym.core.compiled import compiled_module
    from fpg_gym.reconstruct import reliability

    compiled = compiled_module("fpg_gym.reconstruct.compiled_reliability")
    if compiled is None:
        pytest.skip("needs numba (fpg-gym[fast])")
    rng = np.random.default_rng(11)
    decisions = []
    for i in range(600):
        pose = (rest_or_t := (poses.rest_pose() if i % 2 else t_pose())).astype(np.float64)
        pose = pose + rng.normal(0.0, rng.choice([0.01, 0.05, 0.1]), rest_or_t.shape)
        yaw = rng.uniform(-np.pi, np.pi)
        pose = poses.denormalise(pose, poses.Placement(rng.normal(0, 1, 3), np.asarray(yaw)))
        pose = pose.astype(np.float64)
        tolerance = float(rng.choice([10.0, 20.0, 30.0]))
        expected = is_neutral_pose(pose, tolerance)
        got = compiled.neutral_pose(
            pose,
            float(np.cos(np.deg2rad(tolerance))),
            skeleton.ROOT,
            reliability._FACING,
            poses.DEGENERATE_LINE_M,
            skeleton.BONES,
            poses.REST_DIRECTIONS,
            reliability._BODY_BONES,
            reliability._ARM_BONES,
            reliability._SIDEWAYS,
        )
        assert got == expected, i
        decisions.append(expected)
    assert 0.1 < np.mean(decisions) < 0.9  # both answers, often


def test_the_compiled_column_medians_are_numpys_to_the_bit() -> None:
    """The calibration median of the compiled frame (a selection, not a sort) against
    ``np.median`` and ``np.nanmedian`` on columns with repeated values, NaN and odd and even
    lengths."""
    from fpg_gym.core.compiled import compiled_module

    compiled = compiled_module("fpg_gym.reconstruct.compiled_reliability")
    if compiled is None:
        pytest.skip("needs numba (fpg-gym[fast])")
    rng = np.random.default_rng(8)
    for _ in range(300):
        rows = np.round(rng.normal(0.3, 0.02, (int(rng.integers(1, 320)), 19)), 2)
        out = np.empty(19)
        compiled._column_medians(rows, False, out)
        np.testing.assert_array_equal(out, np.median(rows, axis=0))
        rows[rng.random(rows.shape) < 0.3] = np.nan
        compiled._column_medians(rows, False, out)
        np.testing.assert_array_equal(out, np.median(rows, axis=0))
        seen = np.isfinite(rows).any(axis=0)
        out[:] = -1.0
        compiled._column_medians(rows, True, out)
        expected = np.full(19, -1.0)
        expected[seen] = np.nanmedian(rows[:, seen], axis=0)
        np.testing.assert_array_equal(out, expected)
