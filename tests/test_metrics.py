"""FPG Eq. 13 error, Err0.2, bone-length variation and jitter."""

from __future__ import annotations

import numpy as np
import pytest

from fpg_gym.core import metrics, poses, skeleton


@pytest.fixture
def clip(rng: np.random.Generator) -> np.ndarray:
    """Ten frames of a rest pose moving along a random walk (rigidly)."""
    steps = rng.normal(scale=0.05, size=(10, 1, 3)).cumsum(axis=0)
    return (poses.rest_pose()[None] + steps).astype(np.float64)


def test_frame_error_zero_for_identical_and_rigid_shift(clip: np.ndarray) -> None:
    assert np.allclose(metrics.frame_error(clip, clip), 0.0)
    assert np.allclose(metrics.frame_error(clip, clip + np.array([0.3, -0.2, 1.0])), 0.0)


def test_frame_error_counts_each_bone_a_joint_belongs_to(clip: np.ndarray) -> None:
    shift = np.array([0.03, 0.04, 0.0])  # 5 cm
    leaf = skeleton.joint_index("HandLeft")  # one bone ends there, none starts
    moved = clip.copy()
    moved[:, leaf] += shift
    assert np.allclose(metrics.frame_error(clip, moved), 0.05 / skeleton.NUM_BONES)
    middle = skeleton.joint_index("ElbowLeft")  # ends one bone and starts another
    moved = clip.copy()
    moved[:, middle] += shift
    assert np.allclose(metrics.frame_error(clip, moved), 2 * 0.05 / skeleton.NUM_BONES)
    assert metrics.mean_error(clip, moved) == pytest.approx(2 * 0.05 / skeleton.NUM_BONES)


def test_frame_error_accepts_a_single_pose() -> None:
    pose = poses.rest_pose()
    assert metrics.frame_error(pose, pose).shape == (1,)


def test_err_ratio_counts_frames_at_or_above_threshold() -> None:
    assert metrics.err_ratio([0.1, 0.2, 0.3]) == pytest.approx(2 / 3)
    assert metrics.err_ratio([0.1, 0.19], threshold=0.2) == 0.0
    assert metrics.err_ratio([0.5], threshold=0.6) == 0.0


def test_bone_length_variation(clip: np.ndarray) -> None:
    assert np.allclose(metrics.bone_length_variation(clip), 0.0, atol=1e-7)
    varied = clip.copy()
    hand = skeleton.joint_index("HandLeft")
    wrist = skeleton.joint_index("WristLeft")
    direction = varied[:, hand] - varied[:, wrist]
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    extra = np.where(np.arange(len(clip)) % 2 == 0, 0.01, -0.01)  # +-1 cm: std 1 cm
    varied[:, hand] += direction * extra[:, None]
    result = metrics.bone_length_variation(varied)
    bone = skeleton.BONE_OF_JOINT[hand]
    assert result[bone] == pytest.approx(0.01, rel=1e-6)
    assert np.allclose(np.delete(result, bone), 0.0, atol=1e-7)


def test_bone_length_variation_uses_only_tracked_frames(clip: np.ndarray) -> None:
    varied = clip.copy()
    hand = skeleton.joint_index("HandLeft")
    varied[:3, hand] += 0.2  # a glitch in three frames
    states = np.full(varied.shape[:2], 2)
    states[:3, hand] = 1
    bone = skeleton.BONE_OF_JOINT[hand]
    assert metrics.bone_length_variation(varied)[bone] > 0.05
    assert metrics.bone_length_variation(varied, states)[bone] == pytest.approx(0.0, abs=1e-7)
    states[:, hand] = 1
    assert np.isnan(metrics.bone_length_variation(varied, states)[bone])


def test_bones_tracked_needs_both_joints() -> None:
    tracked = np.ones(skeleton.NUM_JOINTS, dtype=bool)
    assert metrics.bones_tracked(tracked).shape == (skeleton.NUM_BONES,)
    assert metrics.bones_tracked(tracked).all()
    hand = skeleton.joint_index("HandLeft")
    tracked[hand] = False
    lost = metrics.bones_tracked(np.stack([tracked, ~tracked]))  # (2, 19)
    touching = (skeleton.BONES == hand).any(axis=1)
    assert np.array_equal(lost[0], ~touching)
    assert not lost[1].any()


def test_jitter_of_known_motions() -> None:
    times = np.arange(30) / 30.0
    pose = poses.rest_pose().astype(np.float64)
    steady = pose[None] + times[:, None, None] * np.array([1.0, 0.0, 0.0])
    assert np.allclose(metrics.jitter(steady), 0.0, atol=1e-9)
    accelerating = pose[None] + 0.5 * 2.0 * times[:, None, None] ** 2 * np.array([0.0, 1.0, 0.0])
    assert np.allclose(metrics.jitter(accelerating), 2.0)
    uneven = np.cumsum(np.where(np.arange(30) % 3 == 0, 0.066, 0.033))
    moving = pose[None] + 0.5 * 2.0 * uneven[:, None, None] ** 2 * np.array([0.0, 0.0, 1.0])
    assert np.allclose(metrics.jitter(moving, timestamps=uneven), 2.0)


def test_jitter_valid_mask_and_short_input() -> None:
    pose = poses.rest_pose().astype(np.float64)
    clip = np.repeat(pose[None], 6, axis=0)
    clip[3] += 1.0  # a spike
    valid = np.ones(6, dtype=bool)
    assert metrics.jitter(clip).mean() > 10
    valid[3] = False
    assert np.allclose(metrics.jitter(clip, valid=valid), 0.0)
    assert np.all(np.isnan(metrics.jitter(clip[:2])))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: metrics.frame_error(np.zeros((3, 19, 3)), np.zeros((3, 19, 3))), "shape"),
        (lambda: metrics.frame_error(np.zeros((3, 20, 3)), np.zeros((4, 20, 3))), "differ"),
        (
            lambda: metrics.frame_error(np.full((2, 20, 3), np.nan), np.zeros((2, 20, 3))),
            "non-finite",
        ),
        (lambda: metrics.err_ratio([]), "empty"),
        (lambda: metrics.err_ratio([np.nan]), "non-finite"),
        (lambda: metrics.jitter(np.zeros((5, 20, 3)), timestamps=np.zeros(5)), "increasing"),
        (lambda: metrics.jitter(np.zeros((5, 20, 3)), timestamps=np.arange(4.0)), "timestamps"),
        (lambda: metrics.jitter(np.zeros((5, 20, 3)), fps=0), "fps"),
        (lambda: metrics.bone_length_variation(np.zeros((5, 20, 3)), np.zeros((5, 19))), "states"),
    ],
)
def test_bad_input_gives_clear_errors(call: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        call()  # type: ignore[operator]


# --------------------------------------------------------------------------- bands, curves, joints


def test_error_band_edges_are_the_papers_and_shared_with_plots() -> None:
    from fpg_gym.experiments import plots

    assert metrics.ERROR_BAND_EDGES[:-1] == (0.0, 0.05, 0.10, 0.15, 0.20, 0.30)
    assert np.isinf(metrics.ERROR_BAND_EDGES[-1])
    assert plots.ERROR_BAND_EDGES is metrics.ERROR_BAND_EDGES


def test_error_histogram_puts_edges_in_the_upper_band() -> None:
    errors = [0.0, 0.049, 0.05, 0.12, 0.2, 0.25, 0.3, 1.5]
    counts = metrics.error_histogram(errors)
    assert counts.tolist() == [2, 1, 1, 0, 2, 2]
    shares = metrics.band_shares(errors)
    assert shares.sum() == pytest.approx(1.0)
    assert shares[0] == pytest.approx(2 / 8)
    # Closed edges: errors beyond the last edge are not counted.
    assert metrics.error_histogram([0.1, 0.5], edges=[0.0, 0.2, 0.4]).tolist() == [1, 0]


def test_error_histogram_matches_err_ratio(rng: np.random.Generator) -> None:
    errors = np.abs(rng.normal(0.15, 0.08, 500))
    counts = metrics.error_histogram(errors)
    above = counts[list(metrics.ERROR_BAND_EDGES).index(0.2) :].sum() / len(errors)
    assert above == pytest.approx(metrics.err_ratio(errors))


def test_frames_above_is_the_cumulative_curve(rng: np.random.Generator) -> None:
    errors = np.abs(rng.normal(0.12, 0.06, 400))
    thresholds = np.linspace(0.0, 0.5, 51)
    curve = metrics.frames_above(errors, thresholds)
    assert curve[0] == pytest.approx(1.0)
    assert np.all(np.diff(curve) <= 0)
    assert curve[20] == pytest.approx(metrics.err_ratio(errors, threshold=thresholds[20]))
    assert metrics.frames_above([0.1, 0.2, 0.3], [0.2]).tolist() == pytest.approx([2 / 3])


def test_per_joint_error_isolates_the_moved_bone(clip: np.ndarray) -> None:
    hand = skeleton.joint_index("HandRight")
    moved = clip.copy()
    moved[:, hand] += np.array([0.0, 0.03, 0.04])  # 5 cm, a leaf: only its bone changes
    result = metrics.per_joint_error(clip, moved)
    assert np.isnan(result[skeleton.ROOT])
    assert result[hand] == pytest.approx(0.05)
    others = np.delete(np.arange(skeleton.NUM_JOINTS), [skeleton.ROOT, hand])
    assert np.allclose(result[others], 0.0)
    assert np.nanmean(result) == pytest.approx(metrics.mean_error(clip, moved))


def test_time_summary() -> None:
    summary = metrics.time_summary(np.arange(1.0, 101.0))
    assert summary["median"] == pytest.approx(50.5)
    assert summary["p95"] == pytest.approx(np.percentile(np.arange(1.0, 101.0), 95))
    assert summary["mean"] == pytest.approx(50.5)
    assert summary["max"] == 100.0


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: metrics.error_histogram([]), "empty"),
        (lambda: metrics.error_histogram([0.1], edges=[0.2, 0.1]), "increasing"),
        (lambda: metrics.frames_above([np.inf], [0.1]), "non-finite"),
        (lambda: metrics.frames_above([0.1], [np.nan]), "NaN"),
        (lambda: metrics.time_summary([-1.0]), "negative"),
        (lambda: metrics.per_joint_error(np.zeros((2, 20, 3)), np.zeros((3, 20, 3))), "differ"),
    ],
)
def test_new_metrics_reject_bad_input(call: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        call()  # type: ignore[operator]


def test_root_relative_error_by_hand():
    reference = np.zeros((2, 20, 3))
    estimate = np.zeros((2, 20, 3))
    estimate[:, 0] = (1.0, 1.0, 1.0)  # the root moves: every other joint is 1.732 m off
    estimate[:, 3] = (1.0, 1.5, 1.0)  # the head keeps 0.5 m above it
    expected = np.full(20, np.sqrt(3.0))
    expected[0] = 0.0
    expected[3] = 0.5
    np.testing.assert_allclose(metrics.root_relative_error(reference, estimate), expected)
    with pytest.raises(ValueError, match="differ in shape"):
        metrics.root_relative_error(reference, estimate[:1])


def test_bootstrap_mean_ci_covers_the_pooled_mean_and_the_paired_change() -> None:
    values = np.array([0.10, 0.12, 0.08, 0.11, 0.30])
    frames = np.array([100, 100, 100, 100, 10])  # the outlier is a short episode
    low, high = metrics.bootstrap_mean_ci(values, weights=frames)
    pooled = float(np.sum(values * frames) / frames.sum())
    assert low < pooled < high < 0.2
    assert (
        metrics.bootstrap_mean_ci(values)[1] > high
    )  # unweighted, the short outlier counts as much as the others
    assert metrics.bootstrap_mean_ci([0.1]) == (0.1, 0.1)
    # Paired: every episode 10 % below its baseline gives a change of exactly -10 %.
    change = metrics.bootstrap_mean_ci(0.9 * values, base=values, weights=frames)
    assert change == pytest.approx((-0.1, -0.1))
    assert metrics.bootstrap_mean_ci(values, rng=3) == metrics.bootstrap_mean_ci(values, rng=3)
    base = np.random.default_rng(0).uniform(0.05, 0.15, 30)
    noisy = 0.9 * base * np.random.default_rng(2).uniform(0.95, 1.05, 30)
    low, high = metrics.bootstrap_mean_ci(noisy, base=base, rng=np.random.default_rng(1))
    assert low < noisy.mean() / base.mean() - 1 < high < 0
    with pytest.raises(ValueError, match="one per episode"):
        metrics.bootstrap_mean_ci(values, weights=frames[:2])
    with pytest.raises(ValueError, match="at least one"):
        metrics.bootstrap_mean_ci([])


def test_mpjpe_alignments_by_hand() -> None:
    rng = np.random.default_rng(3)
    reference = rng.normal(size=(4, 20, 3))
    shifted = reference + np.array([0.1, -0.2, 0.3])
    assert metrics.mpjpe(reference, shifted) == pytest.approx(np.sqrt(0.14))
    assert metrics.mpjpe(reference, shifted, "root") == pytest.approx(0.0, abs=1e-12)
    assert metrics.mpjpe(reference, shifted, "procrustes") == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(
        metrics.root_relative_error(reference, shifted), np.zeros(20), atol=1e-12
    )
    mask = np.zeros((4, 20), dtype=bool)
    mask[:, 5] = True
    moved = reference.copy()
    moved[:, 5] += (0.0, 0.5, 0.0)
    assert metrics.mpjpe(reference, moved, mask=mask) == pytest.approx(0.5)
    assert metrics.mpjpe(reference, moved, mask=~mask) == pytest.approx(0.0)
    assert np.isnan(metrics.mpjpe(reference, moved, mask=np.zeros((4, 20), dtype=bool)))
    with pytest.raises(ValueError, match="align"):
        metrics.mpjpe(reference, moved, "bones")
    with pytest.raises(ValueError, match="mask"):
        metrics.mpjpe(reference, moved, mask=mask[:2])


def test_procrustes_alignment_matches_an_independent_fit() -> None:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    reference = rng.normal(size=(3, 20, 3))
    rotations = Rotation.random(3, random_state=5)
    similar = np.stack(
        [1.7 * rotations[t].apply(reference[t]) + rng.normal(size=3) for t in range(3)]
    )
    assert metrics.mpjpe(reference, similar, "procrustes") == pytest.approx(0.0, abs=1e-9)
    noisy = similar + 0.05 * rng.normal(size=similar.shape)
    expected = []
    for t in range(3):  # the best rotation, then the best scale, of centred points
        ref_c = reference[t] - reference[t].mean(axis=0)
        est_c = noisy[t] - noisy[t].mean(axis=0)
        rotation, _ = Rotation.align_vectors(ref_c, est_c)
        turned = rotation.apply(est_c)
        scale = (ref_c * turned).sum() / (est_c**2).sum()
        expected.append(np.linalg.norm(ref_c - scale * turned, axis=1))
    np.testing.assert_allclose(
        metrics.joint_distances(reference, noisy, "procrustes"), np.stack(expected), atol=1e-9
    )
    mirrored = reference * np.array([-1.0, 1.0, 1.0])  # no reflection allowed
    assert metrics.mpjpe(reference, mirrored, "procrustes") > 0.1


def test_bone_length_error_sees_a_constant_wrong_bone(clip: np.ndarray) -> None:
    longer = clip.copy()
    child = int(skeleton.BONES[5, 1])
    subtree = [j for j in range(20) if child in _ancestors_and_self(j)]
    direction = longer[:, child] - longer[:, int(skeleton.BONES[5, 0])]
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    longer[:, subtree] += 0.05 * direction[:, None]
    error = metrics.bone_length_error(clip, longer)
    assert error[5] == pytest.approx(0.05, abs=1e-6)
    assert np.delete(error, 5).max() < 1e-6
    np.testing.assert_allclose(
        metrics.bone_length_variation(longer), metrics.bone_length_variation(clip), atol=1e-6
    )


def _ancestors_and_self(joint: int) -> set[int]:
    chain = {joint}
    while skeleton.PARENTS[joint] >= 0:
        joint = int(skeleton.PARENTS[joint])
        chain.add(joint)
    return chain
