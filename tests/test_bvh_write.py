"""Motion out (issue 20): BVH with rotations solved from positions, read back by our reader and
by an independent one (bvhio), and ``fpg-gym export`` to BVH and CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fpg_gym.cli import main
from fpg_gym.core import skeleton
from fpg_gym.core.outputs import save_npz
from fpg_gym.io import BVH_JOINT_MAP, load_default_clips, read_bvh, read_recording, write_bvh
from fpg_gym.io.bvh import parse_bvh
from fpg_gym.io.bvh_write import _REST, bvh_hierarchy


def bones(poses: np.ndarray) -> np.ndarray:
    return poses[:, skeleton.BONES[:, 1]] - poses[:, skeleton.BONES[:, 0]]


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def noisy_clip(rng: np.random.Generator) -> np.ndarray:
    """A walk turned towards a camera, with joints jittered by ~1 cm (bone lengths vary)."""
    clip = load_default_clips(["walk"])[0].positions.astype(np.float64)
    return clip + rng.normal(scale=0.01, size=clip.shape) + [0.2, -0.9, 2.4]


def test_round_trip_with_our_reader_keeps_every_bone_direction(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    poses = noisy_clip(rng)
    path = write_bvh(tmp_path / "walk.bvh", poses, fps=30.0)
    back = read_bvh(path, BVH_JOINT_MAP, units="cm", fps=None).positions.astype(np.float64)
    assert back.shape == poses.shape
    np.testing.assert_allclose(unit(bones(back)), unit(bones(poses)), atol=1e-5)
    np.testing.assert_allclose(back[:, skeleton.ROOT], poses[:, skeleton.ROOT], atol=1e-5)
    lengths = np.linalg.norm(bones(back), axis=-1)
    median = np.median(np.linalg.norm(bones(poses), axis=-1), axis=0)
    np.testing.assert_allclose(lengths, np.broadcast_to(median, lengths.shape), atol=1e-5)
    # constant bone lengths come back exactly
    exact = load_default_clips(["walk"])[0].positions
    again = read_bvh(write_bvh(tmp_path / "exact.bvh", exact), BVH_JOINT_MAP, units="cm", fps=None)
    np.testing.assert_allclose(again.positions, exact, atol=1e-5)


def test_round_trip_with_bvhio(tmp_path: Path, rng: np.random.Generator) -> None:
    bvhio = pytest.importorskip("bvhio", reason="bvhio (dev extra) reads the BVH independently")
    poses = noisy_clip(rng)[:12]
    path = write_bvh(tmp_path / "walk.bvh", poses)
    ours = read_bvh(path, BVH_JOINT_MAP, units="cm", fps=None).positions
    root = bvhio.readAsHierarchy(str(path))
    by_name = {joint.Name: joint for joint, _, _ in root.layout()}
    assert set(skeleton.JOINT_NAMES) <= set(by_name)
    for frame in (0, 5, 11):
        root.loadPose(frame)
        theirs = np.array([list(by_name[n].PositionWorld) for n in skeleton.JOINT_NAMES]) / 100.0
        np.testing.assert_allclose(theirs, ours[frame], atol=1e-4)


def test_rest_pose_has_zero_rotations(tmp_path: Path) -> None:
    """A T-pose facing +Z is the hierarchy's rest pose: every rotation channel is 0."""
    rest = np.zeros((skeleton.NUM_JOINTS, 3))
    for joint in range(1, skeleton.NUM_JOINTS):
        parent = skeleton.PARENTS[joint]
        rest[joint] = rest[parent] + 0.2 * np.array(_REST[skeleton.JOINT_NAMES[joint]])
    poses = np.repeat(rest[None] + [0.0, 1.0, 2.0], 3, axis=0)
    motion = parse_bvh(write_bvh(tmp_path / "rest.bvh", poses))
    np.testing.assert_allclose(motion.values[:, :3], 100.0 * poses[:, 0])
    np.testing.assert_allclose(motion.values[:, 3:], 0.0, atol=1e-6)
    # bending an elbow moves that joint's rotation only
    bent = poses.copy()
    elbow, wrist, hand = (skeleton.joint_index(n) for n in ("ElbowLeft", "WristLeft", "HandLeft"))
    pivot = bent[:, elbow][:, None]
    bent[:, [wrist, hand]] = pivot + (bent[:, [wrist, hand]] - pivot) @ np.array(
        [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
    )
    moved = parse_bvh(write_bvh(tmp_path / "bent.bvh", bent)).values[0, 3:].reshape(-1, 3)
    names = [n.name for n in bvh_hierarchy()]
    turned = np.flatnonzero(np.abs(moved).max(axis=1) > 1e-6)
    assert [names[i] for i in turned] == ["ElbowLeft"]
    assert np.abs(moved[names.index("ElbowLeft")]).max() == pytest.approx(90.0)


def test_hierarchy_and_bad_input(tmp_path: Path) -> None:
    nodes = bvh_hierarchy()
    names = [n.name for n in nodes]
    assert [n for n in names if n in skeleton.JOINT_NAMES] == sorted(
        skeleton.JOINT_NAMES, key=names.index
    )
    assert len(names) == 20 + 6  # three branches at the hips, three at the shoulders
    assert all(nodes[n.parent].name in (n.name, *names) for n in nodes[1:])
    with pytest.raises(ValueError, match="poses: expected shape"):
        write_bvh(tmp_path / "a.bvh", np.zeros((4, 19, 3)))
    with pytest.raises(ValueError, match="NaN or inf"):
        write_bvh(tmp_path / "a.bvh", np.full((2, 20, 3), np.nan))
    with pytest.raises(ValueError, match="fps"):
        write_bvh(tmp_path / "a.bvh", np.zeros((2, 20, 3)), fps=0)
    assert not (tmp_path / "a.bvh").exists()


def test_export_command_bvh_and_csv(
    tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]
) -> None:
    poses = noisy_clip(rng).astype(np.float32)
    stamps = np.arange(len(poses)) / 15.0
    result = save_npz(tmp_path / "result.npz", {"poses": poses, "timestamps": stamps})
    bvh, csv = tmp_path / "out.bvh", tmp_path / "out.csv"
    assert main(["export", str(result), "--out", str(bvh)]) == 0
    assert parse_bvh(bvh).frame_time == pytest.approx(1 / 15.0)
    assert main(["export", str(result), "--out", str(csv)]) == 0
    back = read_recording(csv)
    np.testing.assert_allclose(back.positions, poses, atol=1e-5)
    np.testing.assert_allclose(back.timestamps, stamps, atol=1e-6)
    capsys.readouterr()
    assert main(["export", str(result), "--out", str(tmp_path / "x.fbx")]) == 2
    assert "expected a .bvh or .csv" in capsys.readouterr().err
    assert main(["export", str(result), "--out", str(csv), "--key", "ground_truth"]) == 2
    assert "no array 'ground_truth'" in capsys.readouterr().err
    assert main(["export", str(csv), "--out", str(csv)]) == 2
    assert "refusing to overwrite an input" in capsys.readouterr().err
