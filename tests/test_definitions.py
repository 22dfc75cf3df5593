"""Joint-definition maps: frames, exact fit on synthetic data with known offsets, inverse, files,
the unpaired database fit, and their use in the reconstructor."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fpg_gym.core import metrics, poses, skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.rotations import axis_rotation
from fpg_gym.definitions import (
    KINECT_V2_TO_VICON,
    TRUNK_JOINTS,
    DefinitionMap,
    fit_sensor_maps,
    fit_to_database,
    joint_frames,
    load_map,
    packaged_map,
)
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import Clip, Recording
from fpg_gym.reconstruct import BoneSettlingConfig, Reconstructor
from fpg_gym.reconstruct.output_calibration import OnlineDefinitionFit

J = skeleton.joint_index


def _poses(rng: np.random.Generator, count: int) -> np.ndarray:
    """Varied poses: the rest pose with every bone turned a little, placed anywhere."""
    rest = poses.rest_pose().astype(np.float64)
    directions = poses.bone_directions(rest)[None] + 0.35 * rng.normal(size=(count, 19, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    lengths = poses.bone_lengths(rest) * rng.uniform(0.9, 1.1, size=(count, 1))
    local = poses._assemble(np.zeros((count, 3)), directions, lengths)
    turn = axis_rotation("Y", rng.uniform(-np.pi, np.pi, size=count))
    return np.einsum("nab,njb->nja", turn, local) + rng.normal(size=(count, 1, 3))


def test_frames_are_rotations_that_move_with_the_body(rng):
    pose = _poses(rng, 1)[0]
    frames = joint_frames(pose)
    np.testing.assert_allclose(frames @ np.swapaxes(frames, -1, -2), np.eye(3)[None].repeat(20, 0),
                               atol=1e-9)  # fmt: skip
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-9)
    rotation = axis_rotation("X", 0.4) @ axis_rotation("Y", 1.1)
    moved = pose @ rotation.T + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(joint_frames(moved), rotation @ frames, atol=1e-9)


def test_one_pose_map_and_frames_in_compiled_calls_are_the_numpy_code_to_the_bit(rng):
    """``DefinitionMap.apply`` and ``joint_frames`` of one pose through
    ``compiled_poses.bone_frame_turns`` (and ``offset_pose``; with numba) against their numpy
    code: equal to the bit on varied and random poses, and a bone pointing opposite its rest
    direction takes the numpy path."""
    from fpg_gym.core.compiled import numpy_only

    mapping = packaged_map(KINECT_V2_TO_VICON)
    sample = [*_poses(rng, 300), *rng.normal(0.0, 0.4, (300, 20, 3))]
    opposite = poses.rest_pose().astype(np.float64)
    opposite[J("Head")] = 2 * opposite[J("ShoulderCenter")] - opposite[J("Head")]  # head down
    for pose in [*sample, opposite]:
        mapped, frames = mapping.apply(pose), joint_frames(pose)
        with numpy_only():
            reference, reference_frames = mapping.apply(pose), joint_frames(pose)
        np.testing.assert_array_equal(mapped, reference)
        np.testing.assert_array_equal(frames, reference_frames)
    np.testing.assert_array_equal(
        mapping.apply(np.stack(sample[:5])), np.stack([mapping.apply(p) for p in sample[:5]])
    )
    np.testing.assert_array_equal(
        joint_frames(np.stack(sample[:5])), np.stack([joint_frames(p) for p in sample[:5]])
    )


def test_a_map_sent_to_another_process_keeps_its_offsets_read_only(rng):
    """A map unpickled in a worker process keeps read-only offsets (as built: a writeable array
    would compile ``offset_pose`` for a second argument type) and maps as the original."""
    import pickle

    mapping = packaged_map(KINECT_V2_TO_VICON)
    copy = pickle.loads(pickle.dumps(mapping))
    assert not copy.offsets.flags.writeable
    assert (copy.source, copy.target, copy.info) == (mapping.source, mapping.target, mapping.info)
    pose = _poses(rng, 1)[0]
    np.testing.assert_array_equal(copy.apply(pose), mapping.apply(pose))


def test_fit_is_exact_on_synthetic_data_with_known_offsets(rng):
    offsets = 0.05 * rng.normal(size=(20, 3))
    truth = DefinitionMap(offsets, source="a", target="b")
    source = _poses(rng, 50)
    fitted = DefinitionMap.fit(
        source, truth.apply(source), source="a", target="b", symmetric=False, robust=False
    )
    np.testing.assert_allclose(fitted.offsets, offsets, atol=1e-9)
    assert fitted.info["residual_m"] < 1e-8 and fitted.info["pairs"] == 50
    robust = DefinitionMap.fit(source, truth.apply(source), source="a", target="b", symmetric=False)
    np.testing.assert_allclose(robust.offsets, offsets, atol=1e-9)


def test_symmetric_fit_and_joint_mask(rng):
    offsets = np.zeros((20, 3))
    offsets[J("ShoulderLeft")] = (0.02, -0.03, 0.01)
    offsets[J("ShoulderRight")] = (-0.02, -0.03, 0.01)  # the mirror image
    offsets[J("Head")] = (0.0, 0.05, 0.02)
    source = _poses(rng, 30)
    target = DefinitionMap(offsets, source="a", target="b").apply(source)
    fitted = DefinitionMap.fit(source, target, source="a", target="b")
    np.testing.assert_allclose(fitted.offsets, offsets, atol=1e-9)
    only_head = DefinitionMap.fit(source, target, source="a", target="b", joints=[J("Head")])
    assert np.count_nonzero(np.abs(only_head.offsets).sum(axis=1)) == 1


def test_mapping_is_rigid_motion_equivariant(rng):
    mapping = DefinitionMap(0.04 * rng.normal(size=(20, 3)), source="a", target="b")
    pose = _poses(rng, 1)[0]
    rotation = axis_rotation("Z", 0.3) @ axis_rotation("Y", -2.0)
    shift = np.array([0.5, -0.1, 2.0])
    np.testing.assert_allclose(
        mapping.apply(pose @ rotation.T + shift), mapping.apply(pose) @ rotation.T + shift,
        atol=1e-9,
    )  # fmt: skip


def test_inverse_undoes_the_map(rng):
    """Offsets of a few centimetres, as between real systems (the fixed point converges when
    an offset is small against the bone that turns its frame)."""
    mapping = DefinitionMap(0.025 * rng.normal(size=(20, 3)), source="kinect", target="vicon")
    source = _poses(rng, 10)
    back = mapping.inverse()
    assert (back.source, back.target) == ("vicon", "kinect")
    np.testing.assert_allclose(back.apply(mapping.apply(source)), source, atol=1e-4)
    np.testing.assert_allclose(back.inverse().apply(source), mapping.apply(source), atol=1e-12)


def test_files_round_trip_and_bad_files(tmp_path, rng):
    mapping = DefinitionMap(0.03 * rng.normal(size=(20, 3)), source="k", target="v", info={"x": 1})
    path = mapping.save(tmp_path / "map.json")
    again = DefinitionMap.load(path)
    np.testing.assert_allclose(again.offsets, mapping.offsets, atol=1e-6)
    assert (again.source, again.target, again.info) == ("k", "v", {"x": 1})
    inverse = DefinitionMap.load(mapping.inverse().save(tmp_path / "inverse.json"))
    assert inverse.inverted and inverse.source == "v"
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(DataFormatError, match="not JSON"):
        DefinitionMap.load(tmp_path / "bad.json")
    data = mapping.to_dict()
    del data["offsets_m"]["Head"]
    (tmp_path / "short.json").write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=r"one .* entry per Kinect-20 joint"):
        DefinitionMap.load(tmp_path / "short.json")
    (tmp_path / "other.json").write_text(json.dumps({"format": "something"}))
    with pytest.raises(DataFormatError, match="not a definition map"):
        DefinitionMap.load(tmp_path / "other.json")
    with pytest.raises(ValueError, match=r"more than 0\.5 m"):
        DefinitionMap(np.full((20, 3), 0.6), source="a", target="b")
    # load_map: a file, or a packaged map by name (every command's --sensor-map).
    np.testing.assert_array_equal(load_map(path).offsets, again.offsets)
    named = load_map(KINECT_V2_TO_VICON)
    np.testing.assert_array_equal(named.offsets, packaged_map(KINECT_V2_TO_VICON).offsets)
    with pytest.raises(FileNotFoundError):
        load_map("no-such-map")


def test_database_fit_finds_a_trunk_definition_change(rng):
    """Database and poses share the bodies' motion; the database's Spine sits 6 cm further
    back (a bend, not a length change): the unpaired fit recovers it within 1.5 cm."""
    database = _poses(rng, 400)
    database = poses.normalise(database)[0].astype(np.float64)
    shifted = np.zeros((20, 3))
    shifted[J("Spine")] = (0.0, 0.0, -0.06)
    in_database = DefinitionMap(shifted, source="user", target="db").apply(database)
    fitted = fit_to_database(database[:200], in_database, source="user", target="db")
    assert np.abs(fitted.offsets[J("Spine")] - shifted[J("Spine")]).max() < 0.015
    limbs = np.setdiff1d(np.arange(20), TRUNK_JOINTS)
    assert not fitted.offsets[limbs].any()


def test_fit_sensor_maps_without_and_with_a_database(rng):
    sensor = _poses(rng, 40)
    offsets = np.zeros((20, 3))
    offsets[J("Head")] = (0.0, 0.08, 0.0)
    truth = DefinitionMap(offsets, source="s", target="t").apply(sensor)
    sensor_map, output_map = fit_sensor_maps(sensor, truth, sensor="s", truth="t")
    assert output_map is None
    np.testing.assert_allclose(sensor_map.apply(sensor), truth, atol=1e-9)
    database = poses.normalise(_poses(rng, 200))[0]
    sensor_map, output_map = fit_sensor_maps(
        sensor, truth, sensor="s", truth="t", database=database, database_name="db"
    )
    assert output_map is not None and (output_map.source, output_map.target) == ("db", "t")
    # Through the database's definitions and back: the sensor lands on the truth.
    np.testing.assert_allclose(output_map.apply(sensor_map.apply(sensor)), truth, atol=2e-3)


# --------------------------------------------------------------------------- reconstructor


@pytest.fixture(scope="module")
def small_graph() -> FilteredPoseGraph:
    rng = np.random.default_rng(7)
    clip = Clip("synthetic", _poses(rng, 300).astype(np.float32), fps=30.0)
    return FilteredPoseGraph.build([clip], thres1=0.05, progress=False)


def _recording(rng: np.random.Generator) -> Recording:
    frames = np.repeat(_poses(rng, 1), 8, axis=0) + 0.002 * rng.normal(size=(8, 20, 3))
    return Recording(
        positions=frames.astype(np.float32),
        states=np.full((8, 20), skeleton.TRACKED, dtype=np.int8),
        timestamps=np.arange(8) / 30.0,
    )


def test_identity_maps_change_nothing(small_graph, rng):
    recording = _recording(rng)
    plain = Reconstructor(small_graph).reconstruct(recording, "local-search", rng=3).poses
    identity = DefinitionMap.identity("kinect")
    mapped = Reconstructor(small_graph, sensor_map=identity, output_map=identity).reconstruct(
        recording, "local-search", rng=3
    )
    np.testing.assert_array_equal(mapped.poses, plain)


def test_output_map_applies_to_the_output_only(small_graph, rng):
    recording = _recording(rng)
    offsets = np.zeros((20, 3))
    offsets[J("Head")] = (0.0, 0.1, 0.0)
    head_up = DefinitionMap(offsets, source="db", target="out")
    plain = Reconstructor(small_graph).reconstruct(recording, "local-search", rng=3).poses
    moved = Reconstructor(small_graph, output_map=head_up).reconstruct(
        recording, "local-search", rng=3
    )
    np.testing.assert_allclose(moved.poses, head_up.apply(plain), atol=1e-5)


def test_sensor_blend_follows_reliable_joints(small_graph, rng):
    recording = _recording(rng)
    errors = {}
    for blend in (0.0, 1.0):
        out = Reconstructor(small_graph, sensor_blend=blend).reconstruct(
            recording, "local-search", rng=3
        )
        errors[blend] = float(np.abs(out.poses - recording.positions)[2:].mean())
    assert errors[1.0] < 0.5 * errors[0.0]
    with pytest.raises(ValueError, match="sensor_blend"):
        Reconstructor(small_graph, sensor_blend=1.5)


def test_online_fit_learns_known_offsets_causally_from_used_joints(rng):
    offsets = 0.04 * rng.normal(size=(20, 3))
    truth = DefinitionMap(offsets, source="db", target="sensor")
    source = _poses(rng, 60)
    target = truth.apply(source) + 0.005 * rng.normal(size=source.shape)  # tracking noise
    use = np.ones(20, dtype=bool)
    use[J("HandLeft")] = False  # never trusted: learns nothing
    online = OnlineDefinitionFit(symmetric=False)
    first = online.update(source[0], target[0], use)
    assert np.abs(first - source[0]).max() > 0.0  # frame 0 already uses its own evidence
    for pose, sensor in zip(source[1:], target[1:], strict=True):
        online.update(pose, sensor, use)
    learnt = online.offsets
    assert np.all(learnt[J("HandLeft")] == 0.0) and online.frames_seen[J("HandLeft")] == 0
    others = np.arange(20) != J("HandLeft")
    np.testing.assert_allclose(learnt[others], offsets[others], atol=0.003)
    far = target[0].copy()
    far[J("Head")] += 1.0  # a tracking failure, not a definition: left out
    online.update(source[0], far, use)
    assert online.frames_seen[J("Head")] == 60
    online.reset()
    assert np.all(online.offsets == 0.0)


def test_calibrated_output_moves_onto_the_sensor_definitions(small_graph, rng):
    recording = _recording(rng)
    offsets = np.zeros((20, 3))
    offsets[J("Head")] = (0.0, 0.08, 0.0)  # the sensor's head sits 8 cm above the database's
    head_up = DefinitionMap(offsets, source="db", target="sensor")
    shifted = Recording(
        head_up.apply(recording.positions).astype(np.float32),
        recording.states,
        recording.timestamps,
    )
    head = J("Head")
    errors = {}
    for calibrate in (False, True):
        rec = Reconstructor(small_graph, sensor_map=head_up.inverse(), calibrate_output=calibrate)
        out = rec.reconstruct(shifted, "local-search", rng=3).poses
        errors[calibrate] = float(np.linalg.norm(out - shifted.positions, axis=-1)[5:, head].mean())
    assert errors[True] < 0.5 * errors[False]
    with pytest.raises(ValueError, match="calibrate_output and output_map"):
        Reconstructor(small_graph, calibrate_output=True, output_map=head_up)
    with pytest.raises(ValueError, match="calibration_map"):
        Reconstructor(small_graph, calibration_map=head_up)


def test_a_mapped_output_keeps_settled_bone_lengths(small_graph, rng):
    frames = _poses(rng, 60)  # two seconds of changing poses
    recording = Recording(
        positions=frames.astype(np.float32),
        states=np.full((60, 20), skeleton.TRACKED, dtype=np.int8),
        timestamps=np.arange(60) / 30.0,
    )
    offsets = np.zeros((20, 3))
    offsets[J("ShoulderCenter")] = (0.0, 0.0, 0.08)  # thorax frame
    offsets[J("Head")] = (0.0, 0.1, -0.05)  # head-bone frame: the neck stretches as poses turn
    output_map = DefinitionMap(offsets, source="db", target="out")
    spreads = {}
    for settle in (True, False):
        config = BoneSettlingConfig(enabled=settle)
        out = Reconstructor(small_graph, output_map=output_map, bones=config).reconstruct(
            recording, "local-search", rng=3
        )
        spreads[settle] = metrics.settled_bone_spread(out.poses, timestamps=recording.timestamps)
    neck = skeleton.BONE_OF_JOINT[J("Head")]
    assert spreads[False][neck] > 0.01  # the map alone stretches the neck by centimetres
    assert np.all(spreads[True] <= 0.004 + 1e-6)  # settled like the database-side lengths
