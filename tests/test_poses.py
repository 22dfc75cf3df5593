"""Pose utilities: Eq. 1 distance, normalisation, bones, retargeting, mirroring, resampling."""

from __future__ import annotations

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.io import load_default_clips


@pytest.fixture(scope="module")
def clip_poses() -> np.ndarray:
    return np.concatenate([c.positions for c in load_default_clips(["walk", "punch"])])


def _naive_distance(a: np.ndarray, b: np.ndarray) -> float:
    return max(float(np.linalg.norm(a[j].astype(np.float64) - b[j])) for j in range(20))


def test_eq1_one_against_many_matches_naive_loop(clip_poses: np.ndarray) -> None:
    query, others = clip_poses[0], clip_poses[1:40]
    expected = [_naive_distance(query, other) for other in others]
    np.testing.assert_allclose(poses.pose_distance(query, others), expected, rtol=1e-12)


def test_eq1_pairwise_matches_naive_loop_across_blocks(clip_poses: np.ndarray) -> None:
    a, b = clip_poses[:17], clip_poses[20:45]
    expected = np.array([[_naive_distance(x, y) for y in b] for x in a])
    # A tiny block size forces several blocks.
    result = poses.pairwise_pose_distance(a, b, max_block_bytes=3 * 25 * 60 * 8)
    np.testing.assert_allclose(result, expected, rtol=1e-12)


def _hand_made_poses() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A query at the origin, three database poses and their Eq. 1 distances worked by hand."""
    query = np.zeros((1, skeleton.NUM_JOINTS, 3))
    database = np.zeros((3, skeleton.NUM_JOINTS, 3))
    database[0, 4] = [0.3, 0.4, 0.0]  # ||.|| = sqrt(0.09 + 0.16) = 0.5, the largest joint
    database[0, 7] = [0.1, 0.0, 0.0]  # 0.1 < 0.5: not the max
    database[1, :] = [0.0, 0.2, 0.0]  # every joint 0.2 away ...
    database[1, 19] = [0.6, 0.0, 0.8]  # ... but one sqrt(0.36 + 0.64) = 1.0 away
    # database[2] is the query itself: distance 0.
    return query, database, np.array([[0.5, 1.0, 0.0]])


@pytest.mark.parametrize("max_block_bytes", [1, 256 * 2**20])
def test_eq1_one_row_query_by_hand(max_block_bytes: int) -> None:
    """A one-row query gets its distances, with one row per block and with the default block."""
    query, database, expected = _hand_made_poses()
    result = poses.pairwise_pose_distance(query, database, max_block_bytes=max_block_bytes)
    assert result.shape == (1, 3)
    np.testing.assert_allclose(result, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(poses.pose_distance(query[0], database), expected[0], rtol=1e-12)


def test_eq1_last_short_block_is_filled_by_hand() -> None:
    """Five query rows in blocks of two: the last block holds one row and must be computed."""
    _, database, _ = _hand_made_poses()
    queries = np.zeros((5, skeleton.NUM_JOINTS, 3))
    queries[:, 4] = [0.3, 0.4, 0.0]  # each query equals database[0] ...
    queries[4, 4] = [0.0, 0.0, 0.0]  # ... but the last, which is the origin again
    per_row = len(database) * skeleton.NUM_JOINTS * 3 * 8
    result = poses.pairwise_pose_distance(queries, database, max_block_bytes=2 * per_row)
    # Rows 0-3 (joint 4 at (0.3, 0.4, 0)) against database[0]: joint 4 agrees, joint 7 is 0.1
    # away -> 0.1; database[1]: joint 4 is ||(0.3, 0.2, 0)|| = 0.36 away, joint 19 1.0 -> 1.0;
    # database[2] (the origin): joint 4 is 0.5 away -> 0.5. Row 4 is the origin: 0.5, 1.0, 0.
    row = [0.1, 1.0, 0.5]
    expected = np.array([row] * 4 + [[0.5, 1.0, 0.0]])
    np.testing.assert_allclose(result, expected, rtol=1e-12, atol=1e-15)


def test_normalise_is_invariant_to_yaw_and_translation(
    clip_poses: np.ndarray, rng: np.random.Generator
) -> None:
    normalised, _ = poses.normalise(clip_poses)
    yaw = rng.uniform(-np.pi, np.pi, size=len(clip_poses))
    shift = rng.normal(size=(len(clip_poses), 3))
    moved = np.einsum("tdc,tjc->tjd", poses.yaw_matrix(yaw), clip_poses) + shift[:, None]
    moved_normalised, _ = poses.normalise(moved)
    np.testing.assert_allclose(moved_normalised, normalised, atol=2e-5)


def test_normalised_pose_faces_plus_z_with_root_at_origin(clip_poses: np.ndarray) -> None:
    normalised, _ = poses.normalise(clip_poses)
    np.testing.assert_allclose(normalised[:, skeleton.ROOT], 0.0, atol=1e-6)
    hips = (
        normalised[:, skeleton.joint_index("HipRight")]
        - normalised[:, skeleton.joint_index("HipLeft")]
    )
    # right = -X when facing +Z: no Z component of the hip line, and right hip at negative X.
    np.testing.assert_allclose(hips[:, 2], 0.0, atol=1e-5)
    assert np.all(hips[:, 0] < 0)


def test_denormalise_inverts_normalise(clip_poses: np.ndarray) -> None:
    normalised, placement = poses.normalise(clip_poses)
    np.testing.assert_allclose(poses.denormalise(normalised, placement), clip_poses, atol=2e-5)


def test_degenerate_hips_fall_back_to_shoulders() -> None:
    pose = poses.rest_pose()
    pose[skeleton.joint_index("HipLeft")] = pose[skeleton.joint_index("HipRight")]
    assert abs(float(poses.facing_yaw(pose))) < 1e-9
    assert np.isfinite(poses.normalise(pose)[0]).all()


def test_retarget_gives_exact_lengths_and_keeps_directions(clip_poses: np.ndarray) -> None:
    target = poses.DEFAULT_BONE_LENGTHS * 1.1
    out = poses.retarget(clip_poses, target)
    np.testing.assert_allclose(
        poses.bone_lengths(out), np.broadcast_to(target, (len(out), 19)), atol=1e-5
    )
    before = poses.bone_vectors(clip_poses.astype(np.float64))
    after = poses.bone_vectors(out.astype(np.float64))
    cosine = (
        (before * after).sum(-1) / np.linalg.norm(before, axis=-1) / np.linalg.norm(after, axis=-1)
    )
    assert cosine.min() > 1 - 1e-6
    np.testing.assert_allclose(out[:, skeleton.ROOT], clip_poses[:, skeleton.ROOT], atol=1e-6)


def test_retarget_rejects_wrong_length_count(clip_poses: np.ndarray) -> None:
    with pytest.raises(ValueError, match=r"lengths: expected shape \(\.\.\., 19\)"):
        poses.retarget(clip_poses, np.ones(18))


def test_rest_pose_has_default_lengths_and_stands() -> None:
    rest = poses.rest_pose()
    np.testing.assert_allclose(poses.bone_lengths(rest), poses.DEFAULT_BONE_LENGTHS, atol=1e-6)
    assert 1.4 < float(poses.height(rest)) < 2.0
    assert abs(float(poses.stature(poses.DEFAULT_BONE_LENGTHS)) - 1.75) < 0.1
    assert rest[skeleton.joint_index("Head"), 1] > rest[skeleton.joint_index("FootLeft"), 1]


def test_mirror_is_an_involution_that_keeps_bone_lengths(clip_poses: np.ndarray) -> None:
    normalised, _ = poses.normalise(clip_poses)
    mirrored = poses.mirror(normalised)
    np.testing.assert_array_equal(poses.mirror(mirrored), normalised)
    np.testing.assert_allclose(
        np.sort(poses.bone_lengths(mirrored), axis=1),
        np.sort(poses.bone_lengths(normalised), axis=1),
        atol=1e-6,
    )
    left = skeleton.joint_index("HandLeft")
    right = skeleton.joint_index("HandRight")
    np.testing.assert_allclose(mirrored[:, left, 0], -normalised[:, right, 0])


def test_resample_halves_a_60hz_clip_exactly(clip_poses: np.ndarray) -> None:
    out = poses.resample(clip_poses[:21], 60.0, 30.0)
    np.testing.assert_array_equal(out, clip_poses[:21:2])


def test_resample_interpolates_linearly() -> None:
    ramp = np.arange(5, dtype=np.float64)[:, None] * np.ones((1, 3))
    out = poses.resample(ramp, 10.0, 25.0)
    assert len(out) == 11
    np.testing.assert_allclose(out[:, 0], np.arange(11) * 0.4)


def test_as_poses_names_argument_and_shape() -> None:
    with pytest.raises(ValueError, match=r"target: expected shape \(20, 3\), got \(19, 3\)"):
        poses.as_poses(np.zeros((19, 3)), "target", ndim=2)
    bad = np.zeros((2, 20, 3))
    bad[1, 4, 2] = np.nan
    with pytest.raises(ValueError, match=r"clip: non-finite value at index \(1, 4, 2\)"):
        poses.as_poses(bad, "clip")


def test_into_placement_inverts_denormalise(clip_poses: np.ndarray) -> None:
    normalised, placement = poses.normalise(clip_poses)
    local = poses.into_placement(clip_poses, placement)
    assert local.dtype == np.float64
    assert np.allclose(local, normalised, atol=1e-5)
    # Another frame's placement: the inverse of denormalise with that placement.
    other = poses.Placement(root=placement.root[-1], yaw=placement.yaw[-1])
    back = poses.denormalise(poses.into_placement(clip_poses[0], other), other)
    assert np.allclose(back, clip_poses[0], atol=1e-5)


def test_bone_directions_are_unit_with_rest_fallback(clip_poses: np.ndarray) -> None:
    directions = poses.bone_directions(clip_poses[:5])
    assert directions.shape == (5, skeleton.NUM_BONES, 3)
    assert np.allclose(np.linalg.norm(directions, axis=-1), 1.0)
    lengths = poses.bone_lengths(clip_poses[:5])[..., None]
    assert np.allclose(directions * lengths, poses.bone_vectors(clip_poses[:5]), atol=1e-6)
    collapsed = np.zeros((skeleton.NUM_JOINTS, 3))
    assert np.array_equal(poses.bone_directions(collapsed), poses.REST_DIRECTIONS)


def test_bone_fit_matches_least_squares_and_leaves_unused_axes_at_zero(
    clip_poses: np.ndarray,
) -> None:
    # Axes as a local PCA's whitened ones: orthonormal directions of real pose offsets times
    # spreads from 10 cm to 1 mm; the last two unused in the second system.
    flat = clip_poses.reshape(len(clip_poses), -1).astype(np.float64)
    basis = np.linalg.qr((flat[::7][:8] - flat.mean(axis=0)).T)[0].T
    axes = np.stack([basis * np.logspace(-1, -3, 8)[:, None]] * 2)
    axes[1, 6:] = 0.0
    design = poses.latent_bone_design(axes)
    assert design.shape == (2, 57, 8)
    z = np.array([[0.3, -1.2, 2.0, 0.5, -0.7, 1.1, 4.0, -2.5]] * 2)
    bones = np.einsum("nbl,nl->nb", design, z) + 0.01 * np.sin(np.arange(57))
    fitted = poses.fit_bone_vectors(design, bones)
    for n in range(2):
        used = np.any(design[n] != 0.0, axis=0)
        expected, *_ = np.linalg.lstsq(design[n][:, used], bones[n], rcond=None)
        np.testing.assert_allclose(fitted[n, used], expected, rtol=1e-5, atol=1e-8)
        assert np.all(fitted[n, ~used] == 0.0)
    # The design is the bone vectors of a unit step along each axis.
    np.testing.assert_allclose(design[0, :, 2], poses.flat_bone_vectors(axes[0, 2]))
