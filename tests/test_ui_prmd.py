"""UI-PRMD readers (Kinect forward kinematics, Vicon markers and joint centres), the pairing of
two systems (lag and rigid transform) and the import command, on fixtures built here and on the
real files (skipped when ``../shared/data`` is absent)."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from fpg_gym.cli import main
from fpg_gym.core import metrics, skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.pairing import apply_rigid, best_lag, kabsch, pair_session
from fpg_gym.core.rotations import axis_rotation
from fpg_gym.io.positions import read_positions
from fpg_gym.io.recording import load_recording
from fpg_gym.io.ui_prmd import (
    HAND_EXTENSION_M,
    KINECT20_SOURCE,
    KINECT_PARENTS,
    PLAUSIBLE_PELVIS_WIDTH_M,
    VICON_MARKERS,
    kinect_forward_kinematics,
    parse_repetition_name,
    pelvis_width,
    read_kinect_repetition,
    read_vicon_markers,
    vicon_joint_centres,
)
from fpg_gym.io.ui_prmd_import import (
    ALIGNMENT_OUTLIER_Z,
    MAX_ALIGNMENT_M,
    find_repetitions,
    flag_alignment_outliers,
    pair_repetitions,
)

J = skeleton.joint_index


def _write_table(path: Path, rows: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "\n".join(",".join(f"{v:.6f}" for v in row) for row in rows) + "\n"
    path.write_bytes(gzip.compress(text.encode()))
    return path


def _standing_joints22(count: int, rng: np.random.Generator) -> np.ndarray:
    """A plausible 22-joint UI-PRMD Kinect skeleton (data-set space: facing +Z, left at +X),
    metres, with a little motion."""
    base = np.array(
        [
            [0.0, 0.95, -2.4],  # 0 waist
            [0.0, 1.20, -2.4],  # 1 spine
            [0.0, 1.42, -2.4],  # 2 chest (shoulder centre)
            [0.0, 1.50, -2.4],  # 3 neck
            [0.0, 1.58, -2.4],  # 4 head
            [0.0, 1.72, -2.4],  # 5 head tip
            [0.08, 1.42, -2.4],  # 6 left collar
            [0.18, 1.40, -2.4],  # 7 left upper arm (shoulder)
            [0.20, 1.12, -2.4],  # 8 left forearm (elbow)
            [0.21, 0.88, -2.4],  # 9 left hand (wrist)
            [-0.08, 1.42, -2.4],  # 10 right collar
            [-0.18, 1.40, -2.4],  # 11
            [-0.20, 1.12, -2.4],  # 12
            [-0.21, 0.88, -2.4],  # 13
            [0.09, 0.90, -2.4],  # 14 left upper leg (hip)
            [0.10, 0.50, -2.38],  # 15 knee
            [0.10, 0.10, -2.42],  # 16 ankle
            [0.10, 0.03, -2.30],  # 17 toes
            [-0.09, 0.90, -2.4],  # 18
            [-0.10, 0.50, -2.38],  # 19
            [-0.10, 0.10, -2.42],  # 20
            [-0.10, 0.03, -2.30],  # 21
        ]
    )
    wobble = 0.02 * np.sin(np.linspace(0, 3, count))[:, None, None] * rng.normal(size=(1, 22, 3))
    return base[None] + wobble


def _write_kinect(folder: Path, stem: str, joints22: np.ndarray) -> None:
    """Kinect files with zero angles: offsets are then world-space child - parent (cm)."""
    offsets = joints22.copy()
    parents = np.asarray(KINECT_PARENTS)
    offsets[:, 1:] = joints22[:, 1:] - joints22[:, parents[1:]]
    _write_table(folder / "Kinect" / "Positions" / f"{stem}_positions.txt.gz",
                 100 * offsets.reshape(len(joints22), -1))  # fmt: skip
    _write_table(folder / "Kinect" / "Angles" / f"{stem}_angles.txt.gz",
                 np.zeros((len(joints22), 66)))  # fmt: skip


def _markers_for(joints22: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """39 markers (metres, Y up, data-set space) loosely placed on a 22-joint skeleton."""
    spots = {
        "LFHD": (5, [0.05, -0.05, 0.08]), "RFHD": (5, [-0.05, -0.05, 0.08]),
        "LBHD": (5, [0.05, -0.05, -0.08]), "RBHD": (5, [-0.05, -0.05, -0.08]),
        "C7": (2, [0.0, 0.05, -0.08]), "T10": (1, [0.0, 0.0, -0.12]),
        "CLAV": (2, [0.0, 0.0, 0.08]), "STRN": (1, [0.0, 0.05, 0.12]),
        "RBAK": (2, [-0.08, -0.1, -0.1]),
        "LSHO": (7, [0.0, 0.04, 0.0]), "LUPA": (8, [0.05, 0.1, 0.0]), "LELB": (8, [0.04, 0, 0]),
        "LFRM": (9, [0.04, 0.1, 0.0]), "LWRA": (9, [0.02, 0.0, 0.02]),
        "LWRB": (9, [0.02, 0.0, -0.02]), "LFIN": (9, [0.0, -0.08, 0.0]),
        "RSHO": (11, [0.0, 0.04, 0.0]), "RUPA": (12, [-0.05, 0.1, 0.0]),
        "RELB": (12, [-0.04, 0, 0]), "RFRM": (13, [-0.04, 0.1, 0.0]),
        "RWRA": (13, [-0.02, 0.0, 0.02]), "RWRB": (13, [-0.02, 0.0, -0.02]),
        "RFIN": (13, [0.0, -0.08, 0.0]),
        "LASI": (14, [0.04, 0.08, 0.1]), "RASI": (18, [-0.04, 0.08, 0.1]),
        "LPSI": (14, [-0.04, 0.1, -0.08]), "RPSI": (18, [0.04, 0.1, -0.08]),
        "LTHI": (15, [0.06, 0.15, 0.0]), "LKNE": (15, [0.06, 0, 0]),
        "LTIB": (16, [0.05, 0.15, 0.0]), "LANK": (16, [0.04, 0, 0]),
        "LHEE": (16, [0.0, -0.05, -0.06]), "LTOE": (17, [0.0, 0.0, 0.0]),
        "RTHI": (19, [-0.06, 0.15, 0.0]), "RKNE": (19, [-0.06, 0, 0]),
        "RTIB": (20, [-0.05, 0.15, 0.0]), "RANK": (20, [-0.04, 0, 0]),
        "RHEE": (20, [0.0, -0.05, -0.06]), "RTOE": (21, [0.0, 0.0, 0.0]),
    }  # fmt: skip
    markers = np.stack(
        [joints22[:, j] + np.asarray(o) for j, o in (spots[n] for n in VICON_MARKERS)], 1
    )
    return markers + 0.001 * rng.normal(size=markers.shape)


def _write_vicon(folder: Path, stem: str, markers: np.ndarray) -> None:
    """Markers (metres, Y up) as a Vicon file (millimetres, Z up: (x, y, z) -> (x, -z, y))."""
    zup = np.stack([markers[..., 0], -markers[..., 2], markers[..., 1]], axis=-1)
    _write_table(folder / "Vicon" / "Positions" / f"{stem}_positions.txt.gz",
                 1000 * zup.reshape(len(markers), -1))  # fmt: skip


# --------------------------------------------------------------------------- Kinect


def test_repetition_names():
    rep = parse_repetition_name("m07_s02_e03_positions.txt.gz")
    assert (rep.movement, rep.subject, rep.repetition) == (7, 2, 3)
    assert rep.session == "m07_s02" and rep.name == "m07_s02_e03" and rep.subject_name == "s02"
    with pytest.raises(DataFormatError, match="not a UI-PRMD file name"):
        parse_repetition_name("walk.bvh")


def test_forward_kinematics_rotation_order():
    """R_local = Rz(z) Rx(x) Ry(y): a child offset turns with its parent's three angles."""
    offsets = np.zeros((1, 22, 3))
    offsets[0, 1] = (10.0, 0.0, 0.0)
    angles = np.zeros((1, 22, 3))
    angles[0, 0] = (30.0, 40.0, 50.0)  # columns x, y, z (degrees)
    expected = (
        axis_rotation("Z", np.radians(50.0))
        @ axis_rotation("X", np.radians(30.0))
        @ axis_rotation("Y", np.radians(40.0))
        @ np.array([0.1, 0.0, 0.0])
    )
    joints = kinect_forward_kinematics(offsets, angles)
    np.testing.assert_allclose(joints[0, 1], expected, atol=1e-12)
    # A grandchild turns with both ancestors: R0 R1 offset.
    offsets[0, 2] = (0.0, 10.0, 0.0)
    angles[0, 1] = (0.0, 0.0, 90.0)
    joints = kinect_forward_kinematics(offsets, angles)
    r0 = axis_rotation("Z", np.radians(50.0)) @ axis_rotation("X", np.radians(30.0))
    r0 = r0 @ axis_rotation("Y", np.radians(40.0))
    grand = joints[0, 1] + r0 @ axis_rotation("Z", np.radians(90.0)) @ np.array([0.0, 0.1, 0.0])
    np.testing.assert_allclose(joints[0, 2], grand, atol=1e-12)


def test_kinect_repetition_fixture(tmp_path, rng):
    joints22 = _standing_joints22(12, rng)
    _write_kinect(tmp_path, "m01_s09_e01", joints22)
    folder = tmp_path / "Kinect"
    recording = read_kinect_repetition(
        folder / "Positions" / "m01_s09_e01_positions.txt.gz",
        folder / "Angles" / "m01_s09_e01_angles.txt.gz",
    )
    assert recording.num_frames == 12 and recording.fps == pytest.approx(30.0)
    # Camera convention: half a turn about Y; the head is the head tip (joint 5).
    camera = joints22 * np.array([-1.0, 1.0, -1.0])
    for k20, k22 in enumerate(KINECT20_SOURCE):
        if k22 >= 0:
            np.testing.assert_allclose(recording.positions[:, k20], camera[:, k22], atol=1e-5)
    assert (
        recording.positions[0, J("ShoulderLeft"), 0] < recording.positions[0, J("ShoulderRight"), 0]
    )
    hand = recording.positions[:, J("HandLeft")] - recording.positions[:, J("WristLeft")]
    np.testing.assert_allclose(np.linalg.norm(hand, axis=-1), HAND_EXTENSION_M, atol=1e-5)
    assert (recording.states[:, J("HandLeft")] == skeleton.INFERRED).all()
    assert (recording.states[:, J("Head")] == skeleton.TRACKED).all()
    assert recording.metadata["subject"] == "s09"


def test_kinect_bad_files(tmp_path):
    positions = _write_table(tmp_path / "m01_s01_e01_positions.txt.gz", np.zeros((3, 66)))
    short = _write_table(tmp_path / "m01_s01_e01_angles.txt.gz", np.zeros((2, 66)))
    with pytest.raises(DataFormatError, match="2 frames"):
        read_kinect_repetition(positions, short)
    bad = tmp_path / "m01_s01_e02_angles.txt.gz"
    bad.write_bytes(gzip.compress(b"1,2,3\n"))
    with pytest.raises(DataFormatError, match=r"line 1: expected 66"):
        read_kinect_repetition(positions, bad)
    corrupt = tmp_path / "m01_s01_e03_angles.txt.gz"
    corrupt.write_bytes(b"\x1f\x8bnot gzip")
    with pytest.raises(DataFormatError, match="corrupt gzip"):
        read_kinect_repetition(positions, corrupt)
    huge = tmp_path / "m01_s01_e04_angles.txt.gz"
    huge.write_bytes(gzip.compress((",".join(["1e30"] * 66) + "\n").encode()))
    with pytest.raises(DataFormatError, match="line 1"):
        read_kinect_repetition(positions, huge)


# --------------------------------------------------------------------------- Vicon


def test_vicon_units_axes_and_gaps(tmp_path, rng):
    markers = _markers_for(_standing_joints22(20, rng), rng)
    markers_with_gap = markers.copy()
    _write_vicon(tmp_path, "m01_s09_e01", markers)
    read, gaps = read_vicon_markers(tmp_path / "Vicon/Positions/m01_s09_e01_positions.txt.gz")
    np.testing.assert_allclose(read, markers, atol=1e-6)  # mm -> m, Z up -> Y up
    assert not gaps.any()
    markers_with_gap[5, 3] = 0.0  # a gap: (0, 0, 0) in the file
    zup_zero = markers_with_gap.copy()
    _write_vicon(tmp_path, "m01_s09_e02", zup_zero)
    read, gaps = read_vicon_markers(tmp_path / "Vicon/Positions/m01_s09_e02_positions.txt.gz")
    assert gaps[5, 3] and gaps.sum() == 1
    np.testing.assert_allclose(read[5, 3], 0.5 * (markers[4, 3] + markers[6, 3]), atol=1e-6)
    markers_with_gap[:, VICON_MARKERS.index("LTOE")] = 0.0
    _write_vicon(tmp_path, "m01_s09_e03", markers_with_gap)
    with pytest.raises(DataFormatError, match="marker LTOE is missing in every frame"):
        read_vicon_markers(tmp_path / "Vicon/Positions/m01_s09_e03_positions.txt.gz")


def test_harrington_hip_centres():
    """Hip joint centres by hand: pelvis with inter-ASIS width 0.24 m and depth 0.16 m."""
    markers = np.zeros((1, len(VICON_MARKERS), 3))
    put = {
        "LASI": (0.12, 1.0, 0.1), "RASI": (-0.12, 1.0, 0.1),
        "LPSI": (0.04, 1.0, -0.06), "RPSI": (-0.04, 1.0, -0.06),
    }  # fmt: skip
    for name, xyz in put.items():
        markers[0, VICON_MARKERS.index(name)] = xyz
    centres = vicon_joint_centres(markers)[0]
    width, depth = 0.24, 0.16
    expected_left = np.array(
        [0.33 * width + 0.0073, 1.0 - (0.30 * width + 0.0109), 0.1 - (0.24 * depth + 0.0099)]
    )
    np.testing.assert_allclose(centres[J("HipLeft")], expected_left, atol=1e-9)
    np.testing.assert_allclose(centres[J("HipRight")], expected_left * [-1.0, 1.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(centres[J("HipCenter")], [0.0, *expected_left[1:]], atol=1e-9)


# --------------------------------------------------------------------------- pairing


def test_kabsch_recovers_a_rigid_transform(rng):
    points = rng.normal(size=(200, 3))
    rotation = axis_rotation("Y", 0.7) @ axis_rotation("X", -0.3)
    rotation_fit, shift_fit = kabsch(points, points @ rotation.T + [0.5, -1.0, 2.0])
    np.testing.assert_allclose(rotation_fit, rotation, atol=1e-10)
    np.testing.assert_allclose(shift_fit, [0.5, -1.0, 2.0], atol=1e-10)
    assert np.linalg.det(rotation_fit) == pytest.approx(1.0)


def test_pairing_recovers_lag_and_transform(rng):
    """Three repetitions of one session: a known lag each and one rigid transform."""
    rotation = axis_rotation("Y", 2.5) @ axis_rotation("Z", 0.1)
    shift = np.array([0.3, -0.2, 2.4])
    sensors, references, lags = [], [], [4, -3, 0]
    for lag in lags:
        steps = np.arange(90)[:, None, None]
        reference = 0.3 * np.sin(0.11 * steps + rng.normal(size=(1, 20, 3))) + rng.normal(
            size=(1, 20, 3)
        )
        start = max(lag, 0)
        sensor = apply_rigid(reference[start : start + 70], rotation, shift)
        if lag < 0:  # the sensor starts before the reference
            sensor = apply_rigid(reference[: 70 + lag], rotation, shift)
            sensor = np.concatenate([sensor[:1].repeat(-lag, axis=0), sensor])
        sensors.append(sensor + 0.003 * rng.normal(size=sensor.shape))
        references.append(reference)
    pairing = pair_session(sensors, references, max_lag=8)
    assert pairing.lags == lags
    np.testing.assert_allclose(pairing.rotation, rotation, atol=1e-3)
    np.testing.assert_allclose(pairing.shift, shift, atol=5e-3)
    assert pairing.mean_distance < 0.01


def test_best_lag_needs_overlap():
    sensor = np.zeros((10, 20, 3))
    reference = np.ones((3, 20, 3))
    # Lag 2 pairs one frame, under 90 % of the shorter stream: no lag qualifies.
    lag, distance = best_lag(sensor, reference, [2], min_overlap=0.9)
    assert distance == float("inf") and lag == 0
    lag, distance = best_lag(sensor, reference, [2, -1], min_overlap=0.9)
    assert lag == -1 and distance == pytest.approx(np.sqrt(3.0))


# --------------------------------------------------------------------------- import


def test_import_command_on_a_fixture(tmp_path, rng, capsys):
    """Two repetitions: Vicon starts 5 Kinect frames (about 17 samples) earlier in the second."""
    root = tmp_path / "UI-PRMD" / "Segmented Movements"
    for repetition, early in ((1, 0), (2, 5)):
        joints22 = _standing_joints22(150, rng)
        joints22[:, :, 0] += 0.3 * np.sin(np.linspace(0, 6, 150))[:, None]  # a sway to pair on
        stem = f"m02_s07_e{repetition:02d}"
        _write_kinect(root, stem, joints22[early : early + 100])
        # Vicon at 100 Hz over the same moments: resample the 30 Hz motion.
        times = np.arange(0, (early + 100 - 1) / 30.0, 0.01)
        frames = np.interp(times * 30.0, np.arange(150), np.arange(150))
        low = np.floor(frames).astype(int)
        frac = (frames - low)[:, None, None]
        vicon22 = joints22[low] * (1 - frac) + joints22[np.minimum(low + 1, 149)] * frac
        _write_vicon(root, stem, _markers_for(vicon22, rng))
    out = tmp_path / "imported"
    assert main(["import-uiprmd", str(tmp_path / "UI-PRMD"), "--out", str(out), "--json",
                 "--workers", "1"]) == 0  # fmt: skip
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["repetitions"] == 2 and summary["sessions"] == 1
    report = json.loads((out / "import.json").read_text())["session_reports"][0]
    assert report["lags"] == [0, 5]
    # The fixture's ASIS markers sit 4 cm outside hips about 18 cm apart: a plausible pelvis.
    assert 0.2 < report["pelvis_width_m"] < 0.32
    assert report["warnings"] == [] and summary["warnings"] == []
    recording = load_recording(out / "recordings" / "m02_s07_e02.npz")
    assert recording.ground_truth is not None
    assert recording.metadata["lag_frames"] == 5 and recording.metadata["ground_truth"] == "vicon"
    # The ground truth moves with the stream: pairing error far below the sway.
    sway = np.ptp(recording.positions[:, J("HipCenter"), 0])
    distance = np.linalg.norm(recording.ground_truth - recording.positions, axis=-1)
    assert sway > 0.3 and np.median(distance) < 0.15
    clip = read_positions(out / "clips" / "m02_s07_e02.npz")
    assert clip.fps == 30.0 and clip.num_frames >= recording.num_frames
    # Fit the sensor's definition map on the pairs and reconstruct with it.
    capsys.readouterr()
    sensor_map = tmp_path / "map.json"
    assert main(["fit-map", str(out / "recordings"), "--out", str(sensor_map), "--json"]) == 0
    fitted = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert fitted["recordings"] == 2 and fitted["sensor_map"]["target"] == "vicon"
    assert main(["fit-map", str(out / "recordings"), "--out",
                 str(out / "recordings" / "m02_s07_e01.npz")]) == 2  # fmt: skip
    graph = tmp_path / "graph.npz"
    assert main(["build-graph", str(out / "clips"), "--out", str(graph), "--thres1", "0.02"]) == 0
    result = tmp_path / "rec.npz"
    command = ["reconstruct", "--graph", str(graph), "--out", str(result), "--no-ragdoll",
               "--input", str(out / "recordings" / "m02_s07_e02.npz"),
               "--sensor-map", str(sensor_map), "--sensor-blend", "0.5"]  # fmt: skip
    assert main(command) == 0
    assert np.load(result)["poses"].shape == recording.positions.shape
    # The output's definitions calibrated online to the sensor mapped to Vicon joint centres.
    calibrated = tmp_path / "calibrated.npz"
    command[command.index(str(result))] = str(calibrated)
    assert main([*command, "--calibrate-output", "--calibration-map", str(sensor_map)]) == 0
    assert np.load(calibrated)["poses"].shape == recording.positions.shape
    capsys.readouterr()
    assert main([*command, "--calibrate-output", "--output-map", str(sensor_map)]) == 2
    assert "--calibrate-output and --output-map" in capsys.readouterr().err
    assert main([*command, "--calibration-map", str(sensor_map)]) == 2
    assert "--calibration-map: only used with --calibrate-output" in capsys.readouterr().err


def test_import_warns_of_an_implausible_pelvis(tmp_path, rng, capsys):
    """ASIS markers 0.44 m apart (as UI-PRMD's s05): the session is written, with a warning
    naming it and the width, because the Harrington hip centres scale with that width."""
    root = tmp_path / "UI-PRMD"
    joints22 = _standing_joints22(60, rng)
    joints22[:, :, 0] += 0.2 * np.sin(np.linspace(0, 6, 60))[:, None]
    stem = "m01_s05_e01"
    _write_kinect(root, stem, joints22)
    times = np.arange(0, 59 / 30.0, 0.01)
    vicon22 = np.stack([np.interp(times * 30.0, np.arange(60), joints22[:, j, a])
                        for j in range(22) for a in range(3)], 1).reshape(-1, 22, 3)  # fmt: skip
    markers = _markers_for(vicon22, rng)
    left, right = VICON_MARKERS.index("LASI"), VICON_MARKERS.index("RASI")
    middle = 0.5 * (markers[:, left] + markers[:, right])
    half = np.array([0.22, 0.0, 0.0])
    markers[:, left], markers[:, right] = middle + half, middle - half
    _write_vicon(root, stem, markers)
    assert pelvis_width(markers) == pytest.approx(np.full(len(markers), 0.44))
    paired, report = pair_repetitions(root, find_repetitions(root)["m01_s05"])
    assert len(paired) == 1 and report.pelvis_width_m == pytest.approx(0.44, abs=0.01)
    assert len(report.warnings) == 1
    assert report.warnings[0].startswith("m01_s05: the Vicon pelvis markers LASI-RASI are 44")
    assert main(["import-uiprmd", str(root), "--out", str(tmp_path / "o"), "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert "warning: m01_s05: the Vicon pelvis markers" in printed
    assert (tmp_path / "o" / "recordings" / f"{stem}.npz").is_file()


def _write_session(root: Path, stem: str, rng: np.random.Generator, arm_shift=None) -> None:
    """One repetition, Kinect and Vicon over the same moments; ``arm_shift`` (metres) moves
    the Vicon markers of the left forearm and hand (a misplaced marker set)."""
    joints22 = _standing_joints22(60, rng)
    joints22[:, :, 0] += 0.2 * np.sin(np.linspace(0, 6, 60))[:, None]
    _write_kinect(root, stem, joints22)
    times = np.arange(0, 59 / 30.0, 0.01)
    vicon22 = np.stack([np.interp(times * 30.0, np.arange(60), joints22[:, j, a])
                        for j in range(22) for a in range(3)], 1).reshape(-1, 22, 3)  # fmt: skip
    markers = _markers_for(vicon22, rng)
    if arm_shift is not None:
        for name in ("LELB", "LFRM", "LWRA", "LWRB", "LFIN"):
            markers[:, VICON_MARKERS.index(name)] += arm_shift
    _write_vicon(root, stem, markers)


def test_import_warns_of_a_session_whose_alignment_is_an_outlier(tmp_path, rng, capsys):
    """Issue 39: a session whose Kinect and Vicon joints stay far apart after the alignment
    (here a forearm's markers 0.3 m off) is flagged against the other sessions (robust z-score)
    and recorded in import.json; the others are not, and every session is written."""
    root = tmp_path / "UI-PRMD"
    for subject in range(1, 8):
        shift = np.array([0.0, -0.3, 0.2]) if subject == 4 else None
        _write_session(root, f"m01_s{subject:02d}_e01", rng, arm_shift=shift)
    out = tmp_path / "o"
    assert main(["import-uiprmd", str(root), "--out", str(out), "--workers", "1", "--json"]) == 0
    printed = capsys.readouterr().out
    assert "warning: m01_s04: Kinect and Vicon joints" in printed
    assert sum("warning:" in line for line in printed.splitlines()) == 1
    summary = json.loads(printed.strip().splitlines()[-1])
    assert summary["alignment_outliers"] == ["m01_s04"] and summary["repetitions"] == 7
    reports = json.loads((out / "import.json").read_text())["session_reports"]
    flagged = {r["session"]: (r["alignment_outlier"], r["alignment_z"]) for r in reports}
    assert flagged["m01_s04"][0] and flagged["m01_s04"][1] > ALIGNMENT_OUTLIER_Z
    assert not any(outlier for name, (outlier, _) in flagged.items() if name != "m01_s04")
    assert len(list((out / "recordings").glob("*.npz"))) == 7


def test_alignment_outliers_need_enough_sessions_or_a_large_error():
    def reports(errors):
        return [{"session": f"s{i}", "mean_alignment_m": e} for i, e in enumerate(errors)]

    many = reports([0.050, 0.055, 0.060, 0.052, 0.058, 0.120, None])
    assert [w.split(":")[0] for w in flag_alignment_outliers(many)] == ["s5"]
    assert many[5]["alignment_outlier"] and many[5]["alignment_z"] > 3.5
    assert "alignment_z" not in many[6]  # no alignment: nothing to score
    few = reports([0.050, 0.060, 0.120])  # too few to compare: only the absolute bound
    assert flag_alignment_outliers(few) == [] and few[2]["alignment_z"] is None
    far = reports([0.050, 0.060, MAX_ALIGNMENT_M + 0.01])
    assert "above 150 mm" in flag_alignment_outliers(far)[0]


def test_import_refuses_bad_arguments(tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="not a UI-PRMD folder"):
        find_repetitions(tmp_path)
    assert main(["import-uiprmd", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    assert "not a UI-PRMD folder" in capsys.readouterr().err
    (tmp_path / "Kinect" / "Positions").mkdir(parents=True)
    assert main(["import-uiprmd", str(tmp_path), "--out", str(tmp_path / "Kinect")]) == 2
    assert main(["import-uiprmd", str(tmp_path), "--out", str(tmp_path / "o"),
                 "--subjects", "subject1"]) == 2  # fmt: skip


# --------------------------------------------------------------------------- real files


def test_real_uiprmd_session_pairs_against_vicon():
    root = shared_path("ui_prmd")
    sessions = find_repetitions(root, ["s02"])
    assert len(sessions) == 10 and all(len(reps) == 10 for reps in sessions.values())
    paired, report = pair_repetitions(root, sessions["m07_s02"])
    assert len(paired) == 10 and not report.skipped
    assert report.warnings == [] and 0.24 < report.pelvis_width_m < 0.29
    errors = [metrics.mean_error(p.recording.ground_truth, p.recording.positions) for p in paired]
    # Raw Kinect v2 against Vicon joint centres: a few centimetres (README: about 5-7 cm).
    assert 0.02 < float(np.mean(errors)) < 0.1
    heights = [np.ptp(p.recording.positions[0, :, 1]) for p in paired]
    assert all(1.3 < h < 2.0 for h in heights)


def test_real_uiprmd_s05_pelvis_markers_are_flagged():
    """s05's ASIS markers sit about 0.44 m apart in every session (the other subjects 0.24-0.28
    m), out of :data:`PLAUSIBLE_PELVIS_WIDTH_M`: the import flags its hip centres."""
    root = shared_path("ui_prmd")
    vicon = Path(root) / "Segmented Movements" / "Vicon" / "Positions"
    low, high = PLAUSIBLE_PELVIS_WIDTH_M
    for stem, plausible in (("m07_s05_e01", False), ("m07_s01_e01", True)):
        markers, _ = read_vicon_markers(vicon / f"{stem}_positions.txt.gz")
        width = float(np.median(pelvis_width(markers)))
        assert (low <= width <= high) is plausible, (stem, width)
