"""Kinect readers: MSRC-12, Kinect v2 text, NTU RGB+D .skeleton, documented CSV, detection."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from fpg_gym.core import poses, skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.io import Recording, read_recording
from fpg_gym.io.kinect import SkippedLinesWarning, detect_format, read_csv, write_csv

HIP = skeleton.joint_index("HipCenter")
HEAD = skeleton.joint_index("Head")
SHOULDER_L = skeleton.joint_index("ShoulderLeft")
SHOULDER_R = skeleton.joint_index("ShoulderRight")
HIP_L = skeleton.joint_index("HipLeft")
HIP_R = skeleton.joint_index("HipRight")

MSRC12 = {"P1_1_1_p06.csv": 1027, "P1_1_1_p19.csv": 1320, "P1_1_1_p21.csv": 1837}
KINECT_V2 = {
    "Ges01_wavehand.csv": 154,
    "Ges02_balancinghands.csv": 161,
    "Ges03_drawlines.csv": 213,
    "Ges04_comehere.csv": 172,
    "Ges05_demopoint.csv": 190,
    "joints.csv": 371,
}


def facing_sensor(x: float, z: float) -> np.ndarray:
    """The rest pose turned to face the sensor (camera space: its left at -X), at (x, 0, z)."""
    pose = poses.rest_pose().copy()
    pose[:, [0, 2]] *= -1.0  # half a turn about +Y
    return pose + np.array([x, 0.0, z], dtype=np.float32)


def assert_mapping_sane(recording: Recording) -> None:
    """Head above hips; a user facing the sensor has the left side at negative X."""
    body = recording.body_present
    p = recording.positions[body]
    assert np.mean(p[:, HEAD, 1] > p[:, HIP, 1]) > 0.99
    assert np.mean(p[:, SHOULDER_L, 0] < p[:, SHOULDER_R, 0]) > 0.95
    assert np.mean(p[:, HIP_L, 0] < p[:, HIP_R, 0]) > 0.95
    assert np.all(p[:, HIP, 2] > 0.5)  # in front of the sensor (inferred legs may not be)


# --------------------------------------------------------------------------- MSRC-12


@pytest.mark.parametrize(("name", "frames"), sorted(MSRC12.items()))
def test_msrc12_files(name: str, frames: int) -> None:
    path = shared_path("msrc12", name)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkippedLinesWarning)  # nothing may be skipped
        recording = read_recording(path)
    assert detect_format(path) == "msrc12"
    meta = recording.metadata
    assert recording.num_frames == frames
    assert meta["format"] == "msrc12" and meta["skipped_lines"]["count"] == 0
    raw = np.loadtxt(path)
    empty = np.all(raw[:, 1:].reshape(-1, 20, 4)[..., :3] == 0, axis=(1, 2))
    assert meta["no_body_frames"] == int(empty.sum()) == 20  # the files begin with 20 empty lines
    assert np.all(recording.states[empty] == 0)
    assert np.all(recording.states[~empty] == 2)  # no tracking state in this export
    assert meta["untracked_positions"] == "last_known"
    first = int(np.argmax(~empty))
    assert np.allclose(recording.positions[:first], recording.positions[first])  # held back
    joints = raw[~empty, 1:].reshape(-1, 20, 4)[..., :3]
    assert np.allclose(recording.positions[~empty], joints, atol=1e-6)
    steps = np.diff(recording.timestamps)
    assert recording.timestamps[0] == 0.0 and np.all(steps > 0)
    assert recording.fps == pytest.approx(30.0, rel=0.05)
    assert_mapping_sane(recording)


# --------------------------------------------------------------------------- Kinect v2


@pytest.mark.parametrize(("name", "frames"), sorted(KINECT_V2.items()))
def test_kinect_v2_files(name: str, frames: int) -> None:
    path = shared_path("kinect_v2_states", name)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkippedLinesWarning)
        recording = read_recording(path)
    assert detect_format(path) == "kinect_v2"
    assert recording.num_frames == frames
    meta = recording.metadata
    assert meta["skipped_lines"]["count"] == 0 and meta["no_body_frames"] == 0
    # An independent parse: 100 ns ticks, then 25 x (x, y, z, state) in JointType order.
    raw = np.loadtxt(path, delimiter=",", usecols=range(101))
    joints = raw[:, 1:].reshape(-1, 25, 4)[:, skeleton.FROM_KINECT_V2]
    assert np.array_equal(recording.states, joints[..., 3].astype(np.int8))
    assert np.allclose(recording.positions, joints[..., :3], atol=1e-6)
    assert np.allclose(recording.timestamps, (raw[:, 0] - raw[0, 0]) * 1e-7)
    assert recording.fps == pytest.approx(30.0, rel=0.05)
    assert_mapping_sane(recording)


def test_kinect_v2_joints_csv_is_the_occluded_sample() -> None:
    recording = read_recording(shared_path("kinect_v2_states", "joints.csv"))
    raw = np.loadtxt(
        shared_path("kinect_v2_states", "joints.csv"), delimiter=",", usecols=range(101)
    )
    assert int(np.sum(raw[:, 1:].reshape(-1, 25, 4)[..., 3] == 1)) == 2951  # data README
    legs = [skeleton.joint_index(n) for n in ("KneeLeft", "AnkleLeft", "KneeRight", "AnkleRight")]
    assert np.mean(recording.states[:, legs] == 1) > 0.8
    assert 0.3 < recording.state_shares()["inferred"] < 0.4


def _v2_line(tick: int, pose: np.ndarray, state: int = 2) -> str:
    full = np.zeros((25, 3))
    full[skeleton.FROM_KINECT_V2] = pose
    cells = [str(tick)]
    for x, y, z in full:
        cells += [f"{x:.5f}", f"{y:.5f}", f"{z:.5f}", str(state)]
    return ",".join(cells) + ","


def test_kinect_v2_skips_bad_lines_with_one_warning(tmp_path: Path) -> None:
    pose = facing_sensor(0.0, 2.5)
    lines = [_v2_line(1000 + 333_333 * i, pose) for i in range(10)]
    lines.insert(3, "1,2,3")  # wrong field count
    lines.insert(6, lines[5].replace("2.5", "abc", 1))  # not a number
    lines.insert(8, lines[7].rsplit(",", 2)[0] + ",7,")  # bad state
    lines.append(_v2_line(4_000_000, np.zeros((20, 3))))  # no body
    path = tmp_path / "stream.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.warns(SkippedLinesWarning, match=r"skipped 3 of 14 data lines") as record:
        recording = read_recording(path)
    assert len(record) == 1
    skipped = recording.metadata["skipped_lines"]
    assert skipped["count"] == 3 and skipped["first_lines"] == [4, 7, 9]
    assert skipped["reasons"] == {
        "expected 101 fields, got 3": 1,
        "a field is not a number": 1,
        "tracking state not 0, 1 or 2": 1,
    }
    assert recording.num_frames == 11
    assert recording.metadata["no_body_frames"] == 1
    assert np.all(recording.states[-1] == 0)
    assert np.allclose(recording.positions[-1], recording.positions[-2])  # last known


def test_kinect_v2_alternative_layout(tmp_path: Path) -> None:
    pose = facing_sensor(0.0, 2.0)
    full = np.zeros((25, 3))
    full[skeleton.FROM_KINECT_V2] = pose
    rows = []
    for i in range(4):
        cells = [str(i), f"{33.3 * i:.1f}"]
        for x, y, z in full:
            cells += ["1", f"{x:.5f}", f"{y:.5f}", f"{z:.5f}", "1", "0", "0", "0"]
        rows.append(",".join(cells))
    path = tmp_path / "alt.txt"
    path.write_text("\n".join(rows))
    recording = read_recording(path)
    assert recording.metadata["layout"].startswith("index,time_ms")
    assert np.allclose(recording.positions, pose, atol=1e-5)
    assert np.all(recording.states == 1)
    assert recording.timestamps[1] == pytest.approx(0.0333)


# --------------------------------------------------------------------------- NTU RGB+D


def _ntu_body(body_id: str, pose: np.ndarray, states: np.ndarray) -> list[str]:
    """One body block following the public NTU RGB+D .skeleton specification."""
    full = np.zeros((25, 3))
    full[skeleton.FROM_KINECT_V2] = pose
    full_states = np.full(25, 2)
    full_states[skeleton.FROM_KINECT_V2] = states
    lines = [f"{body_id} 0 1 1 1 1 0 -0.02 0.05 2", "25"]
    for (x, y, z), state in zip(full, full_states, strict=True):
        lines.append(f"{x:.6f} {y:.6f} {z:.6f} 250.1 200.2 950.3 500.4 0.9 0.1 0.2 0.3 {state}")
    return lines


def write_ntu(path: Path, frames: list[list[tuple[str, np.ndarray, np.ndarray]]]) -> Path:
    lines = [str(len(frames))]
    for bodies in frames:
        lines.append(str(len(bodies)))
        for body_id, pose, states in bodies:
            lines += _ntu_body(body_id, pose, states)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def ntu_file(tmp_path: Path) -> Path:
    first = facing_sensor(0.3, 3.0)
    second = facing_sensor(-0.5, 3.5)
    states = np.full(20, 2)
    states[skeleton.joint_index("HandLeft")] = 1
    states[skeleton.joint_index("FootRight")] = 0
    a, b = "72057594037931101", "72057594037931102"
    frames = [
        [(a, first, states)],
        [(b, second, np.full(20, 2)), (a, first + 0.01, states)],  # order changes
        [(b, second + 0.02, np.full(20, 1))],  # body a absent
    ]
    return write_ntu(tmp_path / "S001C001P001R001A001.skeleton", frames)


def test_ntu_first_body_by_default(ntu_file: Path) -> None:
    assert detect_format(ntu_file) == "ntu"
    recording = read_recording(ntu_file)
    meta = recording.metadata
    assert recording.num_frames == 3 and meta["bodies_in_file"] == 2
    assert meta["body_id"] == "72057594037931101"
    assert recording.positions[1, HIP, 0] == pytest.approx(0.31, abs=1e-5)  # tracked by ID
    assert recording.states[0, skeleton.joint_index("HandLeft")] == 1
    assert recording.states[0, skeleton.joint_index("FootRight")] == 0
    assert np.all(recording.states[2] == 0) and meta["no_body_frames"] == 1
    assert np.allclose(recording.positions[2], recording.positions[1])  # last known
    assert recording.fps == pytest.approx(30.0)
    assert_mapping_sane(recording)


def test_ntu_body_flag_picks_another_body(ntu_file: Path) -> None:
    recording = read_recording(ntu_file, body=1)
    assert recording.metadata["body_id"] == "72057594037931102"
    assert np.all(recording.states[0] == 0)
    assert np.all(recording.states[1] == 2) and np.all(recording.states[2] == 1)
    assert recording.positions[2, HIP, 0] == pytest.approx(-0.48, abs=1e-5)
    assert np.allclose(recording.positions[0], recording.positions[1])  # first known, held back
    with pytest.raises(DataFormatError, match="body 2 requested, but the file holds 2"):
        read_recording(ntu_file, body=2)


def test_ntu_malformed_files_name_the_line(ntu_file: Path, tmp_path: Path) -> None:
    lines = ntu_file.read_text().splitlines()
    truncated = tmp_path / "truncated.skeleton"
    truncated.write_text("\n".join(lines[:20]))
    with pytest.raises(DataFormatError, match=r"truncated.skeleton, line 21: file ends early"):
        read_recording(truncated)
    wrong_joints = tmp_path / "joints.skeleton"
    wrong_joints.write_text("\n".join([*lines[:3], "24", *lines[4:]]))
    with pytest.raises(DataFormatError, match=r"line 4: expected 25 joints"):
        read_recording(wrong_joints)
    short_joint = tmp_path / "short.skeleton"
    short_joint.write_text("\n".join([*lines[:4], "0.1 0.2", *lines[5:]]))
    with pytest.raises(DataFormatError, match=r"line 5: expected 12 finite numbers"):
        read_recording(short_joint)
    trailing = tmp_path / "trailing.skeleton"
    trailing.write_text("\n".join([*lines, "1"]))
    with pytest.raises(DataFormatError, match="unexpected content after the 3 declared frames"):
        read_recording(trailing)


# --------------------------------------------------------------------------- CSV, detection


def test_csv_round_trip_and_column_order(tmp_path: Path, rng: np.random.Generator) -> None:
    positions = facing_sensor(0.0, 2.0)[None] + rng.normal(scale=0.01, size=(5, 20, 3))
    states = rng.integers(1, 3, size=(5, 20))
    recording = Recording(positions, states, np.arange(5) * 0.04)
    path = write_csv(tmp_path / "rec.csv", recording)
    assert detect_format(path) == "csv"
    loaded = read_recording(path)
    assert np.allclose(loaded.positions, recording.positions, atol=1e-5)
    assert np.array_equal(loaded.states, recording.states)
    assert np.allclose(loaded.timestamps, recording.timestamps)
    # Columns in another order, no timestamp, an extra column: still read, extra one reported.
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    table = [line.split(",") for line in lines]
    order = [*range(len(table[0]) - 1, 0, -1)]
    shuffled = tmp_path / "shuffled.csv"
    shuffled.write_text(
        "\n".join(
            ",".join([row[i] for i in order] + ["note" if n == 0 else "7"])
            for n, row in enumerate(table)
        )
    )
    again = read_csv(shuffled)
    assert np.allclose(again.positions, recording.positions, atol=1e-5)
    assert again.metadata["ignored_columns"] == ["note"]
    assert again.timestamps[1] == pytest.approx(1 / 30)


def test_csv_header_must_name_every_joint(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("timestamp,HipCenter_x,HipCenter_y\n0,1,2\n")
    with pytest.raises(DataFormatError, match=r"bad.csv, line 1: header lacks 78 joint column"):
        read_recording(path)


def test_detection_override_and_errors(tmp_path: Path, ntu_file: Path) -> None:
    with pytest.raises(ValueError, match="format: expected one of"):
        read_recording(ntu_file, format="kinect_v3")
    csv = write_csv(tmp_path / "a.csv", read_recording(ntu_file))
    with pytest.raises(ValueError, match="only NTU files"):
        read_recording(csv, body=1)
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_recording(tmp_path / "absent.csv")
    empty = tmp_path / "empty.csv"
    empty.write_text("\n\n")
    with pytest.raises(DataFormatError, match="empty file"):
        read_recording(empty)
    odd = tmp_path / "odd.txt"
    odd.write_text("1 2 3 4\n5 6 7 8\n")
    with pytest.raises(DataFormatError, match="unknown Kinect layout"):
        read_recording(odd)
    # Forcing a reader onto the wrong file: most lines unusable -> a clear error, not junk.
    with pytest.raises(DataFormatError, match=r"do not fit the msrc12 layout; first bad line"):
        read_recording(ntu_file, format="msrc12")


def test_msrc12_nan_lines_are_skipped(tmp_path: Path) -> None:
    pose = facing_sensor(0.0, 2.5)
    row = " ".join(f"{v:.5f}" for v in np.concatenate([pose, np.ones((20, 1))], axis=1).ravel())
    lines = [f"{33333 * i} {row}" for i in range(6)]
    lines[2] = lines[2].replace("2.50000", "nan", 1)
    path = tmp_path / "p.csv"
    path.write_text("\n".join(lines))
    with pytest.warns(SkippedLinesWarning, match="1 x NaN or inf value"):
        recording = read_recording(path)
    assert recording.num_frames == 5
    assert recording.metadata["timestamp_unit_s"] == 1e-6
    assert np.all(np.isfinite(recording.positions))
