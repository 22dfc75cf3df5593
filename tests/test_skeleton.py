"""The one skeleton definition: structure, maps and derived tables."""

from __future__ import annotations

import numpy as np

from fpg_gym.core import skeleton


def test_joint_and_bone_counts() -> None:
    assert skeleton.NUM_JOINTS == 20
    assert skeleton.NUM_BONES == 19
    assert len(set(skeleton.JOINT_NAMES)) == 20
    assert skeleton.JOINT_NAMES[skeleton.ROOT] == "HipCenter"


def test_parents_come_before_children() -> None:
    for child, parent in enumerate(skeleton.PARENTS):
        assert parent < child
    assert (skeleton.PARENTS == -1).sum() == 1


def test_bones_are_parent_child_pairs() -> None:
    for parent, child in skeleton.BONES:
        assert skeleton.PARENTS[child] == parent
    assert list(skeleton.BONE_OF_JOINT[skeleton.BONES[:, 1]]) == list(range(19))


def test_mirror_pairs_swap_left_and_right() -> None:
    for left, right in skeleton.MIRROR_PAIRS:
        assert skeleton.is_left(int(left)) and skeleton.is_right(int(right))
        assert skeleton.JOINT_NAMES[left].replace("Left", "Right") == skeleton.JOINT_NAMES[right]
    permutation = skeleton.MIRROR_PERMUTATION
    assert np.array_equal(permutation[permutation], np.arange(20))
    # Mirroring maps bones onto bones.
    bones = {tuple(b) for b in skeleton.BONES.tolist()}
    assert {(int(permutation[p]), int(permutation[c])) for p, c in bones} == bones


def test_path_matrix_rebuilds_positions_from_bone_vectors(rng: np.random.Generator) -> None:
    pose = rng.normal(size=(20, 3))
    vectors = pose[skeleton.BONES[:, 1]] - pose[skeleton.BONES[:, 0]]
    rebuilt = pose[skeleton.ROOT] + skeleton.PATH_MATRIX @ vectors
    np.testing.assert_allclose(rebuilt, pose, atol=1e-12)


def test_kinect_v2_map() -> None:
    names = [skeleton.KINECT_V2_JOINT_NAMES[i] for i in skeleton.FROM_KINECT_V2]
    assert names[skeleton.joint_index("HipCenter")] == "SpineBase"
    assert names[skeleton.joint_index("Spine")] == "SpineMid"
    assert names[skeleton.joint_index("ShoulderCenter")] == "SpineShoulder"
    assert names[skeleton.joint_index("HandRight")] == "HandRight"
    assert len(set(skeleton.FROM_KINECT_V2.tolist())) == 20
    assert np.array_equal(skeleton.FROM_KINECT_V1, np.arange(20))


def test_unknown_joint_name_lists_valid_names() -> None:
    try:
        skeleton.joint_index("Elbow")
    except KeyError as error:
        assert "ElbowLeft" in str(error)
    else:  # pragma: no cover
        raise AssertionError("expected KeyError")


def test_tables_are_read_only() -> None:
    for table in (
        skeleton.PARENTS,
        skeleton.BONES,
        skeleton.MIRROR_PERMUTATION,
        skeleton.PATH_MATRIX,
    ):
        assert not table.flags.writeable
