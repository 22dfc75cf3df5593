"""Today's body trackers (issue 20): Azure Kinect Body Tracking JSON and generic per-joint
CSV/JSON files with a user-given joint map, into the Kinect-20 pipeline."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from fpg_gym.cli import main
from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.skeleton import AZURE_KINECT_JOINT_NAMES, AZURE_KINECT_TO_KINECT20
from fpg_gym.io import read_recording
from fpg_gym.io.trackers import JointMap, read_azure_kinect, read_mapped

AZURE_INDEX = np.array(
    [AZURE_KINECT_JOINT_NAMES.index(AZURE_KINECT_TO_KINECT20[n]) for n in skeleton.JOINT_NAMES]
)


def kinect_poses(rng: np.random.Generator, frames: int = 6) -> np.ndarray:
    """Kinect-20 camera-space poses (metres) about 2 m in front of the sensor."""
    return (rng.normal(scale=0.2, size=(frames, 20, 3)) + np.array([0.0, 0.0, 2.0])).astype(
        np.float32
    )


def azure_body(pose: np.ndarray, body_id: int, rng: np.random.Generator, **extra) -> dict:
    """An Azure body holding ``pose`` (Kinect space, m) in depth-camera space (mm, Y down)."""
    joints = rng.normal(scale=300.0, size=(32, 3)) + np.array([0.0, 0.0, 2000.0])
    joints[AZURE_INDEX] = pose.astype(np.float64) * [-1000.0, -1000.0, 1000.0]
    return {
        "body_id": body_id,
        "joint_positions": joints.tolist(),
        "joint_orientations": [[1.0, 0.0, 0.0, 0.0]] * 32,
        **extra,
    }


def azure_file(path: Path, frames: list[dict]) -> Path:
    """The offline processor's layout."""
    document = {
        "k4abt_sdk_version": "1.1.2",
        "source_file": "capture.mkv",
        "joint_names": list(AZURE_KINECT_JOINT_NAMES),
        "bone_list": [["SPINE_CHEST", "SPINE_NAVEL"]],
        "frames": frames,
    }
    path.write_text(json.dumps(document, indent=4))
    return path


def test_azure_kinect_positions_bodies_and_confidence(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    poses = kinect_poses(rng)
    other = kinect_poses(rng)
    levels = ["MEDIUM"] * 32
    levels[AZURE_INDEX[skeleton.joint_index("HandLeft")]] = "LOW"
    levels[AZURE_INDEX[skeleton.joint_index("FootRight")]] = "K4ABT_JOINT_CONFIDENCE_NONE"
    frames = []
    for i in range(len(poses)):
        bodies = [azure_body(other[i], 7, rng), azure_body(poses[i], 3, rng)]
        if i == 0:
            bodies[1]["joint_confidences"] = levels
        if i == 2:
            bodies = bodies[:1]  # body 3 absent in this frame
        frames.append({"timestamp_usec": 1_000_000 + 33_333 * i, "frame_id": i, "bodies": bodies})
    frames.insert(4, {"timestamp_usec": "x", "bodies": []})  # a bad frame: skipped, counted
    path = azure_file(tmp_path / "azure.json", frames)
    with pytest.warns(UserWarning, match="skipped 1 of"):
        recording = read_recording(path, body=1)  # detected from the content
    assert recording.metadata["format"] == "azure_kinect"
    assert recording.metadata["body_id"] == 3
    assert recording.metadata["skipped_lines"]["count"] == 1
    assert recording.num_frames == len(poses)
    present = [0, 1, 3, 4, 5]
    np.testing.assert_allclose(recording.positions[present], poses[present], atol=1e-6)
    np.testing.assert_allclose(recording.timestamps, 0.033333 * np.arange(6), atol=1e-9)
    assert recording.metadata["no_body_frames"] == 1
    assert np.all(recording.states[2] == skeleton.NOT_TRACKED)
    first = recording.states[0]
    assert first[skeleton.joint_index("HandLeft")] == skeleton.INFERRED
    assert first[skeleton.joint_index("FootRight")] == skeleton.NOT_TRACKED
    assert np.sum(first == skeleton.TRACKED) == 18
    assert recording.metadata["states_in_file"] is True
    with pytest.warns(UserWarning, match="skipped 1 of"):
        body0 = read_azure_kinect(path, body=0)
    np.testing.assert_allclose(body0.positions[2], other[2], atol=1e-6)
    with pytest.raises(DataFormatError, match="2 distinct body_id"), pytest.warns(UserWarning):
        read_azure_kinect(path, body=2)


def test_azure_kinect_is_turned_into_kinect_camera_space(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    """The depth camera's Y points down: a standing body's head must come out above its feet."""
    pose = np.zeros((20, 3))
    pose[:, 1] = np.linspace(1.0, -1.0, 20)  # higher joints first, in Kinect space
    joints = np.zeros((32, 3))
    joints[AZURE_INDEX] = pose * [1.0, -1000.0, 1.0]  # mm, Y down
    joints[:, 2] = 2500.0
    body = {"body_id": 1, "joint_positions": joints.tolist()}
    frames = [{"timestamp_usec": i * 33_333, "bodies": [body]} for i in range(3)]
    recording = read_azure_kinect(azure_file(tmp_path / "a.json", frames))
    head, foot = skeleton.joint_index("Head"), skeleton.joint_index("FootLeft")
    assert recording.positions[0, head, 1] > recording.positions[0, foot, 1]
    assert recording.positions[0, head, 2] == pytest.approx(2.5)


def test_azure_joint_names_as_written_or_with_the_sdk_prefix(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    """The offline processor writes ``PELVIS``, ``SPINE_NAVEL``, ... (docs/input.md); the SDK's
    ``K4ABT_JOINT_PELVIS`` spelling reads the same."""
    poses = kinect_poses(rng, 3)
    frames = [
        {"timestamp_usec": 33_333 * i, "bodies": [azure_body(poses[i], 1, rng)]} for i in range(3)
    ]
    path = azure_file(tmp_path / "a.json", frames)
    assert json.loads(path.read_text())["joint_names"][:2] == ["PELVIS", "SPINE_NAVEL"]
    document = json.loads(path.read_text())
    document["joint_names"] = [f"K4ABT_JOINT_{n}" for n in document["joint_names"]]
    prefixed = tmp_path / "prefixed.json"
    prefixed.write_text(json.dumps(document))
    for file in (path, prefixed):
        np.testing.assert_allclose(read_recording(file).positions, poses, atol=1e-6)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{not json", "not JSON"),
        ('{"frames": 3}', "'frames' list"),
        ('{"joint_names": ["A"], "frames": []}', "lacks"),
        ('{"frames": []}', "no frames"),
    ],
)
def test_azure_kinect_bad_files(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(DataFormatError, match=message) as caught:
        read_azure_kinect(path)
    assert str(path) in str(caught.value)


def full_map(**overrides: str) -> list[str]:
    """``src_<Joint>=<Joint>`` for every Kinect-20 joint, with overrides by Kinect name."""
    return [
        f"{overrides.get(n, 'src_' + n)}={n}" for n in skeleton.JOINT_NAMES if n not in overrides
    ] + [f"{v}={k}" for k, v in overrides.items()]


def test_mapped_csv_with_units_axes_and_a_mean_joint(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    poses = kinect_poses(rng, 5)
    names = [f"src_{n}" for n in skeleton.JOINT_NAMES if n != "HipCenter"]
    source = {f"src_{n}": poses[:, j] for j, n in enumerate(skeleton.JOINT_NAMES)}
    offset = np.array([0.05, 0.0, 0.0])
    source["l_hip"] = poses[:, 0] + offset  # the pelvis is the mean of two hips
    source["r_hip"] = poses[:, 0] - offset
    names += ["l_hip", "r_hip"]
    header = ["timestamp"] + [f"{n}_{a}" for n in names for a in "xyz"] + ["src_Head_state"]
    lines = ["# a tracker export, mm, Y down", ",".join(header)]
    for t in range(len(poses)):
        cells = [f"{t / 30:.6f}"]
        for n in names:  # source frame: mm, X right, Y down  -> Kinect: -x, -y, z
            x, y, z = source[n][t] * [-1000.0, -1000.0, 1000.0]
            cells += [repr(float(x)), repr(float(y)), repr(float(z))]
        cells.append("1")
        lines.append(",".join(cells))
    lines.append("1,2,3")  # wrong field count: skipped
    path = tmp_path / "tracker.csv"
    path.write_text("\n".join(lines) + "\n")
    pairs = [*full_map(HipCenter="l_hip"), "r_hip=HipCenter"]
    joint_map = JointMap.from_pairs(pairs, units="mm", axes="-x,-y,z")
    assert joint_map.joints["HipCenter"] == ("l_hip", "r_hip")
    with pytest.warns(UserWarning, match="skipped 1"):
        recording = read_mapped(path, joint_map)
    np.testing.assert_allclose(recording.positions, poses, atol=1e-5)
    assert np.all(recording.states[:, skeleton.joint_index("Head")] == skeleton.INFERRED)
    assert recording.metadata["format"] == "mapped" and recording.metadata["layout"] == "csv"


def test_mapped_json_and_joint_map_files(tmp_path: Path, rng: np.random.Generator) -> None:
    poses = kinect_poses(rng, 4)
    frames = [
        {
            "timestamp": 10.0 + t / 30,
            "joints": {f"j{j}": poses[t, j].tolist() for j in range(20)},
            "states": {"j3": 0},
        }
        for t in range(4)
    ]
    data = tmp_path / "frames.json"
    data.write_text(json.dumps({"frames": frames}))
    map_json = tmp_path / "map.json"
    map_json.write_text(
        json.dumps({"joints": {f"j{j}": n for j, n in enumerate(skeleton.JOINT_NAMES)}})
    )
    map_text = tmp_path / "map.txt"
    map_text.write_text(
        "# source=Kinect\n" + "\n".join(f"j{j}={n}" for j, n in enumerate(skeleton.JOINT_NAMES))
    )
    for map_file in (map_json, map_text):
        recording = read_recording(data, joint_map=JointMap.load(map_file))
        np.testing.assert_allclose(recording.positions, poses, atol=1e-6)
        np.testing.assert_allclose(recording.timestamps, np.arange(4) / 30, atol=1e-9)
        assert np.all(recording.states[:, 3] == skeleton.NOT_TRACKED)


#: A tracker's joint names (no pelvis) -> Kinect-20; HipCenter is the mean of the two hips.
TRACKER_NAMES = {
    "spine": "Spine",
    "neck": "ShoulderCenter",
    "head": "Head",
    **{
        f"{side[0].lower()}_{part.lower()}": f"{part}{side}"
        for side in ("Left", "Right")
        for part in ("Shoulder", "Elbow", "Wrist", "Hand", "Hip", "Knee", "Ankle", "Foot")
    },
}


def test_a_millimetre_y_down_tracker_without_a_pelvis_is_mapped(
    tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 39: a JSON map lists several Kinect joints for a source (a pelvis from two hips)
    and a text map sets units and axes, so a millimetre, Y-down, X-right tracker with no pelvis
    joint is read in Kinect camera space through ``fpg-gym reconstruct --joint-map``."""
    poses = kinect_poses(rng, 5)
    hips = [skeleton.joint_index("HipLeft"), skeleton.joint_index("HipRight")]
    poses[:, skeleton.joint_index("HipCenter")] = poses[:, hips].mean(axis=1)
    names = list(TRACKER_NAMES)
    header = ["timestamp"] + [f"{n}_{a}" for n in names for a in "xyz"]
    lines = [",".join(header)]
    for t in range(len(poses)):
        cells = [f"{t / 30:.6f}"]
        for name in names:  # the tracker: millimetres, X right, Y down, Z forward
            point = poses[t, skeleton.joint_index(TRACKER_NAMES[name])].astype(float)
            cells += [repr(v) for v in (point * [-1000.0, -1000.0, 1000.0]).tolist()]
        lines.append(",".join(cells))
    tracker = tmp_path / "tracker.csv"
    tracker.write_text("\n".join(lines) + "\n")
    joints: dict[str, str | list[str]] = dict(TRACKER_NAMES)
    joints["l_hip"] = ["HipLeft", "HipCenter"]
    joints["r_hip"] = ["HipRight", "HipCenter"]
    json_map = tmp_path / "map.json"
    json_map.write_text(json.dumps({"joints": joints, "units": "mm", "axes": "-x,-y,z"}))
    text_map = tmp_path / "map.txt"
    text_map.write_text(
        "# tracker joint = Kinect-20 joint\nunits = mm  # the tracker's unit\naxes=-x,-y,z\n"
        + "".join(f"{s}={k}\n" for s, k in TRACKER_NAMES.items())
        + "l_hip=HipCenter\nr_hip=HipCenter\n"
    )
    for map_file in (json_map, text_map):
        joint_map = JointMap.load(map_file)
        assert joint_map.joints["HipCenter"] == ("l_hip", "r_hip")
        assert joint_map.joints["HipLeft"] == ("l_hip",)
        assert (joint_map.units, joint_map.axes) == ("mm", "-x,-y,z")
        out = tmp_path / f"{map_file.suffix[1:]}.npz"
        argv = ["reconstruct", "--method", "raw", "--input", str(tracker), "--out", str(out)]
        assert main([*argv, "--joint-map", str(map_file)]) == 0, capsys.readouterr().err
        np.testing.assert_allclose(np.load(out)["poses"], poses, atol=1e-5)
    # the same map as arguments
    pairs = [f"{s}={k}" for s, k in TRACKER_NAMES.items()]
    pairs += ["l_hip=HipCenter", "r_hip=HipCenter", "units=mm", "axes=-x,-y,z"]
    out = tmp_path / "pairs.npz"
    argv = ["reconstruct", "--method", "raw", "--input", str(tracker), "--out", str(out)]
    assert main([*argv, "--joint-map", *pairs]) == 0
    np.testing.assert_allclose(np.load(out)["poses"], poses, atol=1e-5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"joints": {"a": ["HipLeft", 3]}}', "Kinect name or list of names"),
        ('{"joints": {"a": []}}', "Kinect name or list of names"),
        ('{"joints": {"a": "Head"}, "units": 1000}', "'units': expected text"),
        ("a=Head\nunits=furlongs\n", "units"),
        ("a=Head\njust a name\n", "line 2"),
    ],
)
def test_bad_joint_map_files_name_the_file(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "map.txt"
    path.write_text(text)
    with pytest.raises(DataFormatError, match=message) as caught:
        JointMap.load(path)
    assert str(path) in str(caught.value)


def test_joint_map_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no source joint for Spine"):
        JointMap.from_pairs(full_map()[:1] + full_map()[2:])
    with pytest.raises(ValueError, match="not Kinect-20 joints"):
        JointMap.from_pairs([*full_map(), "x=Pelvis"])
    with pytest.raises(ValueError, match="name=KinectName"):
        JointMap.from_pairs(["oops"])
    with pytest.raises(ValueError, match="axes"):
        JointMap.from_pairs(full_map(), axes="x,x,z")
    bad = tmp_path / "map.json"
    bad.write_text('{"joints": {"a": 1}}')
    with pytest.raises(DataFormatError, match=r"map\.json"):
        JointMap.load(bad)
    csv = tmp_path / "t.csv"
    csv.write_text("timestamp,a_x,a_y,a_z\n0,1,2,3\n")
    with pytest.raises(DataFormatError, match="header lacks"):
        read_mapped(csv, full_map())
    with pytest.raises(ValueError, match="joint_map"):
        read_recording(csv, format="mapped")


def test_reconstruct_command_reads_azure_and_mapped_files(
    tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]
) -> None:
    poses = kinect_poses(rng, 3)
    frames = [
        {"timestamp_usec": 33_333 * i, "bodies": [azure_body(poses[i], 1, rng)]} for i in range(3)
    ]
    azure = azure_file(tmp_path / "k4abt.json", frames)
    out = tmp_path / "out.npz"
    assert main(["reconstruct", "--method", "raw", "--input", str(azure), "--out", str(out)]) == 0
    np.testing.assert_allclose(np.load(out)["poses"], poses, atol=1e-6)
    generic = tmp_path / "generic.json"
    generic.write_text(
        json.dumps(
            [{"joints": {f"s{j}": p.tolist() for j, p in enumerate(pose)}} for pose in poses]
        )
    )
    pairs = [f"s{j}={n}" for j, n in enumerate(skeleton.JOINT_NAMES)]
    out2 = tmp_path / "out2.npz"
    argv = ["reconstruct", "--method", "raw", "--input", str(generic), "--out", str(out2)]
    assert main([*argv, "--joint-map", *pairs]) == 0
    np.testing.assert_allclose(np.load(out2)["poses"], poses, atol=1e-6)
    assert main([*argv, "--joint-map", "s0=HipCenter"]) == 2
    assert "no source joint for Spine" in capsys.readouterr().err


hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fpg_gym.core.errors import FpgGymError  # noqa: E402

_KEYS = [
    "frames",
    "bodies",
    "body_id",
    "joint_positions",
    "joint_confidences",
    "timestamp_usec",
    "joint_names",
    "joints",
    "states",
    "timestamp",
    "s0",
]


def _nest(inner: st.SearchStrategy) -> st.SearchStrategy:
    return st.lists(inner, max_size=5) | st.dictionaries(st.sampled_from(_KEYS), inner)


_JSON = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(10**400), 10**400)
    | st.sampled_from([10**400, -(10**309), 2**63])
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=4)
    | st.sampled_from(["NONE", "LOW", "MEDIUM", "HIGH", *AZURE_KINECT_JOINT_NAMES[:3]]),
    _nest,
    max_leaves=30,
)


@settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(document=_JSON, frame=_JSON, where=st.integers(0, 5))
def test_tracker_readers_read_or_raise_the_projects_error(
    tmp_path: Path, document: object, frame: object, where: int
) -> None:
    """Arbitrary JSON, and a valid Azure file with one frame replaced by arbitrary JSON: each
    reader returns a recording or raises FpgGymError, never another exception."""
    rng = np.random.default_rng(where)
    frames: list = [
        {"timestamp_usec": 33_333 * i, "bodies": [azure_body(kinect_poses(rng, 1)[0], 1, rng)]}
        for i in range(6)
    ]
    frames[where] = frame
    valid = azure_file(tmp_path / "valid.json", frames)
    arbitrary = tmp_path / "any.json"
    arbitrary.write_text(json.dumps(document, allow_nan=True))
    mapping = JointMap.from_pairs([f"s0={n}" for n in skeleton.JOINT_NAMES])
    for read in (read_azure_kinect, lambda p: read_mapped(p, mapping)):
        for path in (valid, arbitrary):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    read(path)
            except FpgGymError:
                pass
