"""Mocap readers: BVH (plain, gzip), DeepMimic, positions .npz; the embedded default; bad input."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path, tiny_bvh

from fpg_gym.core import poses, skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.io import (
    BANDAI_NAMCO_MAP,
    DEFAULT_CLIP_NAMES,
    Clip,
    load_clips,
    load_default_clips,
    read_bvh,
    read_clip,
    read_deepmimic,
    read_positions,
    write_positions,
)
from fpg_gym.io.bvh import joint_positions, parse_bvh
from fpg_gym.io.deepmimic import default_clip_path, forward_kinematics, humanoid_model

# --------------------------------------------------------------------------- synthetic BVH

_HIERARCHY = tiny_bvh(
    [
        "0 100 0 0 0 0 0 0 0 0 0 0",
        "10 100 0 0 0 90 90 90 0 0 0 0",
    ]
)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_bvh_forward_kinematics_applies_each_channel_order(tmp_path: Path) -> None:
    motion = parse_bvh(_write(tmp_path, "toy.bvh", _HIERARCHY))
    world = joint_positions(motion)
    np.testing.assert_allclose(world[0], [[0, 100, 0], [0, 150, 0], [0, 150, 30]], atol=1e-9)
    # Frame 2: root turned 90 deg about Y; chest (channels Z=90, X=90, order ZXY) maps its child's
    # offset (0, 0, 30) by R_Z(90) @ R_X(90) to (30, 0, 0), which the root turns to (0, 0, -30).
    # Applying the angles in the wrong order would give (0, -30, 0).
    np.testing.assert_allclose(world[1], [[10, 100, 0], [10, 150, 0], [10, 150, -30]], atol=1e-9)


def test_bvh_gzip_reads_like_plain(tmp_path: Path) -> None:
    plain = parse_bvh(_write(tmp_path, "toy.bvh", _HIERARCHY))
    packed = tmp_path / "toy.bvh.gz"
    packed.write_bytes(gzip.compress(_HIERARCHY.encode()))
    np.testing.assert_array_equal(parse_bvh(packed).values, plain.values)


def test_bvh_unit_detection(tmp_path: Path) -> None:
    toy_map = {name: "Hips" for name in skeleton.JOINT_NAMES}
    toy_map["Head"] = "Hand"
    path = _write(tmp_path, "toy.bvh", _HIERARCHY)
    in_cm = read_bvh(path, toy_map, fps=None)
    assert in_cm.metadata["scale"] == 0.01
    np.testing.assert_allclose(
        in_cm.positions[0, skeleton.joint_index("Head")], [0, 1.5, 0.3], atol=1e-6
    )
    in_m = read_bvh(path, toy_map, units="m", fps=None)
    np.testing.assert_allclose(in_m.positions, in_cm.positions * 100, rtol=1e-6)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (_HIERARCHY.replace("HIERARCHY\n", ""), "line 1: expected 'HIERARCHY'"),
        (
            _HIERARCHY.replace("OFFSET 0 50 0", "OFFSET 0 fifty 0"),
            "line 8: OFFSET needs three numbers",
        ),
        (_HIERARCHY.replace("CHANNELS 3 Zrotation", "CHANNELS 4 Zrotation"), "line 9: CHANNELS 4"),
        (_HIERARCHY.replace("Frames: 2", "Frames: 3"), "truncated: header says 3 frames"),
        (_HIERARCHY.replace("Frames: 2", "Frames: 0"), "no frames"),
        (_HIERARCHY.replace("10 100 0 0 0 90", "10 nan 0 0 0 90"), "line 25: NaN or inf"),
        (
            _HIERARCHY.replace("10 100 0 0 0 90", "10 oops 0 0 0 90"),
            "line 25: a frame holds a non-number",
        ),
        (_HIERARCHY.split("MOTION")[0], "no MOTION section"),
        (_HIERARCHY.replace("Frame Time: 0.0333333", "Frame Rate: 30"), "expected 'Frames: N'"),
    ],
)
def test_bvh_bad_input_names_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, "bad.bvh", text)
    with pytest.raises(DataFormatError, match=message) as info:
        read_bvh(path, {name: "Hips" for name in skeleton.JOINT_NAMES})
    assert str(path) in str(info.value)


def test_bvh_map_naming_missing_joint_is_rejected(tmp_path: Path) -> None:
    path = _write(tmp_path, "toy.bvh", _HIERARCHY)
    with pytest.raises(
        DataFormatError,
        match="entry 'ShoulderCenter' names BVH joint 'Neck', which this file does not have",
    ):
        read_bvh(path, BANDAI_NAMCO_MAP)
    incomplete = {name: "Hips" for name in skeleton.JOINT_NAMES[:-1]}
    with pytest.raises(DataFormatError, match=r"missing \['FootRight'\]"):
        read_bvh(path, incomplete)
    with pytest.raises(DataFormatError, match=r"not Kinect-20 joints: \['Tail'\]"):
        read_bvh(path, {**{name: "Hips" for name in skeleton.JOINT_NAMES}, "Tail": "Hips"})


def test_bvh_corrupt_gzip(tmp_path: Path) -> None:
    path = tmp_path / "broken.bvh.gz"
    path.write_bytes(gzip.compress(_HIERARCHY.encode())[:40])
    with pytest.raises(DataFormatError, match="corrupt gzip"):
        parse_bvh(path)


# --------------------------------------------------------------------------- Bandai Namco


def _few_bandai_files() -> list[Path]:
    root = shared_path("bandai_namco")
    return [
        *sorted((root / "dataset-1").glob("*.bvh"))[::40][:3],
        *sorted((root / "dataset-2").glob("*.bvh.gz"))[::700][:3],
    ]


def test_bandai_bvh_segments_are_rigid_and_height_plausible() -> None:
    for path in _few_bandai_files():
        motion = parse_bvh(path)
        world = joint_positions(motion)
        parents = motion.hierarchy.parents
        children = np.flatnonzero(
            parents > 0
        )  # joint_Root -> Hips is the animated root translation
        segment = np.linalg.norm(world[:, children] - world[:, parents[children]], axis=-1)
        assert np.ptp(segment, axis=0).max() * 0.01 < 1e-3, path.name  # cm -> m, within 1 mm

        clip = read_bvh(path)
        assert clip.fps == 30.0 and clip.num_frames == len(motion.values)
        lengths = poses.bone_lengths(clip.positions)
        # Kinect bones along one rigid BVH segment chain (limbs, head, hips) are constant to 1 mm;
        # spine and clavicle bones span articulated BVH joints and vary (reported, not asserted).
        rigid = [
            i
            for i, name in enumerate(skeleton.BONE_NAMES)
            if not name.startswith(("ShoulderCenter-Shoulder", "HipCenter-Spine", "Spine-"))
        ]
        assert np.ptp(lengths[:, rigid], axis=0).max() < 1e-3, path.name
        standing = float(np.median(poses.stature(lengths)))
        assert 1.4 < standing < 2.0, (path.name, standing)
        head, hip = skeleton.joint_index("Head"), skeleton.joint_index("HipCenter")
        assert np.all(clip.positions[:, head, 1] > clip.positions[:, hip, 1])


def test_bandai_left_is_left() -> None:
    clip = read_bvh(_few_bandai_files()[0])
    normalised, _ = poses.normalise(clip.positions)
    # Facing +Z the body's left is +X; the feet point forward (+Z).
    left, right = skeleton.joint_index("ShoulderLeft"), skeleton.joint_index("ShoulderRight")
    assert np.all(normalised[:, left, 0] > normalised[:, right, 0])
    foot = (
        normalised[:, skeleton.joint_index("FootLeft")]
        - normalised[:, skeleton.joint_index("AnkleLeft")]
    )
    assert np.median(foot[:, 2]) > 0.03


# --------------------------------------------------------------------------- DeepMimic / default


def test_default_clips_load_at_30hz_with_constant_bones() -> None:
    clips = load_default_clips()
    assert [c.name for c in clips] == list(DEFAULT_CLIP_NAMES)
    for clip in clips:
        assert clip.fps == 30.0 and clip.num_frames > 20
        lengths = poses.bone_lengths(clip.positions)
        assert np.ptp(lengths, axis=0).max() < 1e-3, clip.name
        assert 1.4 < float(np.median(poses.stature(lengths))) < 2.0, clip.name


def test_default_clip_duration_survives_resampling() -> None:
    for name in ("backflip", "spin", "cartwheel", "walk"):
        path = default_clip_path(name)
        frames = np.array(json.loads(path.read_text())["Frames"])
        duration = frames[:-1, 0].sum()
        clip = read_deepmimic(path)
        assert abs(clip.duration - duration) <= 1.0 / 30.0, name


def test_deepmimic_forward_kinematics_matches_pybullet() -> None:
    from fpg_gym.physics.pybullet_utils import connect_direct, data_path, pybullet, quiet_stdout

    frames = np.array(json.loads(default_clip_path("dance_a").read_text())["Frames"])
    ours = forward_kinematics(frames[[10, 60]])
    client = connect_direct()
    try:
        with quiet_stdout():
            body = pybullet.loadURDF(
                str(data_path() / "humanoid" / "humanoid.urdf"),
                globalScaling=0.25,
                physicsClientId=client,
            )
        index = {
            pybullet.getJointInfo(body, j, physicsClientId=client)[12].decode(): j
            for j in range(pybullet.getNumJoints(body, physicsClientId=client))
        }
        layout = [
            "chest",
            "neck",
            "right_hip",
            "right_knee",
            "right_ankle",
            "right_shoulder",
            "right_elbow",
            "left_hip",
            "left_knee",
            "left_ankle",
            "left_shoulder",
            "left_elbow",
        ]
        for row, frame in zip(ours, frames[[10, 60]], strict=True):
            xyzw = lambda q: [q[1], q[2], q[3], q[0]]  # noqa: E731
            pybullet.resetBasePositionAndOrientation(
                body, frame[1:4], xyzw(frame[4:8]), physicsClientId=client
            )
            column = 8
            for link in layout:
                if link.endswith(("knee", "elbow")):
                    pybullet.resetJointState(
                        body, index[link], frame[column], physicsClientId=client
                    )
                    column += 1
                else:
                    pybullet.resetJointStateMultiDof(
                        body, index[link], xyzw(frame[column : column + 4]), physicsClientId=client
                    )
                    column += 4
            for joint, link in [
                ("ElbowLeft", "left_elbow"),
                ("KneeRight", "right_knee"),
                ("WristRight", "right_wrist"),
                ("ShoulderCenter", "neck"),
                ("AnkleLeft", "left_ankle"),
            ]:
                expected = pybullet.getLinkState(
                    body, index[link], computeForwardKinematics=True, physicsClientId=client
                )[4]
                np.testing.assert_allclose(row[skeleton.joint_index(joint)], expected, atol=1e-5)
    finally:
        pybullet.disconnect(physicsClientId=client)
    assert humanoid_model().links[0] == "root"


def test_the_deepmimic_reader_s_humanoid_table_is_pybullet_s_humanoid_to_the_bit() -> None:
    """The reader reads the humanoid from a table (no physics engine below io); the table is
    what pybullet loads, every offset and point equal to the last bit."""
    from fpg_gym.physics.humanoid import humanoid_model_from_pybullet

    table, loaded = humanoid_model(), humanoid_model_from_pybullet()
    assert table.links == loaded.links and table.parents == loaded.parents
    assert np.array_equal(table.offsets, loaded.offsets) and table.offsets.dtype == np.float64
    assert table.points.keys() == loaded.points.keys()
    for key, point in loaded.points.items():
        assert np.array_equal(table.points[key], point), key


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not JSON"),
        ('{"Loop": "none"}', "expected a JSON object with a 'Frames' list"),
        ('{"Frames": []}', "the clip has no frames"),
        ('{"Frames": [[0.1, 1, 2]]}', "frame 0 has 3 values, expected 44"),
        ('{"Frames": [[0.1' + ", 0" * 42 + ", NaN]]}", "frame 0 holds NaN or inf"),
    ],
)
def test_deepmimic_bad_input(tmp_path: Path, content: str, message: str) -> None:
    path = _write(tmp_path, "humanoid3d_bad.txt", content)
    with pytest.raises(DataFormatError, match=message) as info:
        read_deepmimic(path)
    assert str(path) in str(info.value)


# --------------------------------------------------------------------------- positions .npz


def test_positions_round_trip(tmp_path: Path) -> None:
    clip = load_default_clips(["punch"])[0]
    path = write_positions(tmp_path / "punch.npz", clip)
    back = read_clip(path)
    assert back.name == "punch" and back.fps == clip.fps
    np.testing.assert_array_equal(back.positions, clip.positions)


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        ({"fps": 30.0}, "field 'positions': missing key 'positions'"),
        ({"positions": np.zeros((4, 20, 3))}, "field 'fps': missing key 'fps'"),
        (
            {"positions": np.zeros((4, 19, 3)), "fps": 30.0},
            r"expected shape \(T, 20, 3\), got \(4, 19, 3\)",
        ),
        ({"positions": np.zeros((0, 20, 3)), "fps": 30.0}, "no frames"),
        ({"positions": np.full((2, 20, 3), np.nan), "fps": 30.0}, "NaN or inf at frame 0"),
        ({"positions": np.zeros((2, 20, 3)), "fps": -1.0}, "expected a positive frame rate"),
        (
            {"positions": np.array([None] * 3, dtype=object), "fps": 30.0},
            "Python objects \\(pickle\\)",
        ),
    ],
)
def test_positions_bad_input(tmp_path: Path, arrays: dict[str, object], message: str) -> None:
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match=message) as info:
        read_positions(path)
    assert str(path) in str(info.value)


def test_positions_not_an_archive(tmp_path: Path) -> None:
    path = _write(tmp_path, "bad.npz", "hello")
    with pytest.raises(DataFormatError, match=r"not a readable \.npz archive"):
        read_positions(path)


# --------------------------------------------------------------------------- load_clips


def test_load_clips_expands_folders_and_default(tmp_path: Path) -> None:
    clip = load_default_clips(["kick"])[0]
    (tmp_path / "sub").mkdir()
    write_positions(tmp_path / "sub" / "a.npz", clip)
    write_positions(tmp_path / "b.npz", Clip("b", clip.positions[:5], 30.0))
    (tmp_path / "notes.md").write_text("ignored")
    clips = load_clips([tmp_path, "default"], progress=False, workers=1)
    # Files in sorted path order (b.npz, sub/a.npz holding the clip named "kick"), then the default.
    assert [c.name for c in clips] == ["b", "kick", *DEFAULT_CLIP_NAMES]


def test_load_clips_missing_input(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no such file or folder"):
        load_clips([tmp_path / "nope.bvh"], progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="folder holds no"):
        load_clips([tmp_path / "empty"], progress=False)


def test_unknown_extension_is_explained(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown mocap format"):
        read_clip(tmp_path / "clip.fbx")
