"""Occlusions put into real streams, the sensor's trust, the fusion, the bone model, presets."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fpg_gym.core import metrics, poses, skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.graph import default_graph, packaged_graph
from fpg_gym.io import Recording, load_default_clips
from fpg_gym.reconstruct import Reconstructor, bone_model
from fpg_gym.reconstruct.bone_model import LinearBoneModel, packaged_bone_model
from fpg_gym.reconstruct.fusion import FusionConfig, SensorFusion, SensorTrust, fuse_positions
from fpg_gym.reconstruct.left_right import LABEL_PERMUTATIONS, LABELLINGS
from fpg_gym.reconstruct.presets import (
    SensorResources,
    choose_pipeline,
    default_graph_name,
    pipeline,
    sensor_of,
)
from fpg_gym.simulate import simulate
from fpg_gym.simulate.occlude import OCCLUSION_CASES, occlude

_J = skeleton.joint_index


@pytest.fixture(scope="module")
def stream() -> Recording:
    """A clean, Kinect-like stream (no occlusion) with its truth, 3 s long (walk, looped)."""
    clip = load_default_clips(["walk"])[0]
    step = np.array([0.6, 0.0, 0.0])
    positions = np.concatenate([clip.positions + i * step for i in range(3)])[:90]
    return simulate(positions, "clean", seed=3)


# --------------------------------------------------------------------------- occlusion cases


@pytest.mark.parametrize("case", list(OCCLUSION_CASES))
def test_occlude_changes_only_the_occluded_joints(stream: Recording, case: str) -> None:
    first = occlude(stream, case, seed=1)
    again = occlude(stream, case, seed=1)
    assert np.array_equal(first.positions, again.positions)  # same seed, same occlusion
    assert first.occluded is not None and first.occluded.any()
    assert np.array_equal(first.ground_truth, stream.ground_truth)
    # Joints never occluded keep the stream's report (the model's recovery is on hidden ones).
    never = ~first.occluded.any(axis=0)
    assert np.array_equal(first.positions[:, never], stream.positions[:, never])
    hidden = first.occluded
    moved = np.linalg.norm(first.positions - stream.positions, axis=-1)
    assert moved[hidden].mean() > 0.01
    states = first.states[hidden]
    description = first.metadata["occlusion"]
    assert description["case"] == case and description["frames"] > 0
    if case == "legs":
        assert np.mean(states == skeleton.NOT_TRACKED) > 0.5
    elif case in ("hand-on-surface", "side-turn"):
        assert np.all(states == skeleton.TRACKED)  # false positives and swaps look tracked
    else:
        assert np.all(states == skeleton.INFERRED)


def test_occlude_rejects_an_unknown_case(stream: Recording) -> None:
    with pytest.raises(ValueError, match="unknown 'moon'"):
        occlude(stream, "moon")


# --------------------------------------------------------------------------- trust


def test_trust_of_states_runs_and_bones() -> None:
    trust = SensorTrust(FusionConfig(flicker_s=0.1, inferred_half_life_s=0.2))
    pose = poses.rest_pose()
    states = np.full(20, skeleton.TRACKED)
    for t in range(10):  # the lengths settle on a tracked stream
        assert np.allclose(trust.update(pose, states, t / 30.0), 1.0)
    lost = states.copy()
    lost[_J("WristLeft")] = skeleton.INFERRED
    lost[_J("AnkleRight")] = skeleton.NOT_TRACKED
    values = [trust.update(pose, lost, (10 + t) / 30.0) for t in range(16)]
    wrist = [v[_J("WristLeft")] for v in values]
    assert wrist[0] == 1.0 and wrist[2] == 1.0  # a flicker keeps full trust
    assert wrist[9] == pytest.approx(0.5 ** ((9 / 30.0 - 0.1) / 0.2))  # then halves every 0.2 s
    assert wrist[15] == pytest.approx(0.25)  # 0.4 s after the flicker: two half-lives
    hand = [v[_J("HandLeft")] for v in values]  # tracked: its own sight counts, not the wrist's
    assert min(hand) == 1.0
    assert all(v[_J("AnkleRight")] == 0.0 for v in values)
    # A tracked joint that snaps away (its bone stretches by half) loses its trust.
    snapped = pose.copy()
    snapped[_J("HandRight")] += 0.5 * (pose[_J("HandRight")] - pose[_J("WristRight")])
    assert trust.update(snapped, states, 2.0)[_J("HandRight")] < 0.5
    # An inferred joint hangs off its parent: no more trust than the parent's.
    child = states.copy()
    child[_J("ElbowRight")] = skeleton.NOT_TRACKED
    child[_J("WristRight")] = skeleton.INFERRED
    out = trust.update(pose, child, 2.1)
    assert out[_J("WristRight")] == 0.0


def test_trust_keeps_a_joint_the_stream_always_infers() -> None:
    trust = SensorTrust()
    states = np.full(20, skeleton.TRACKED)
    states[_J("HandLeft")] = skeleton.INFERRED  # e.g. UI-PRMD's placed hands
    values = [trust.update(poses.rest_pose(), states, t / 30.0) for t in range(60)]
    assert all(v[_J("HandLeft")] == 1.0 for v in values)


def test_trust_in_compiled_calls_is_the_numpy_trust_to_the_bit() -> None:
    """``compiled_fusion.trust_exponents`` and ``sensor_trust`` (with numba) against
    ``SensorTrust.update``'s numpy code on a noisy stream with flickering, lost and stretched
    joints: the same trust, run starts and trusted lengths to the bit."""
    import contextlib

    from fpg_gym.core.compiled import numpy_only

    rng = np.random.default_rng(4)
    pose = poses.rest_pose().astype(np.float64)
    frames = pose + rng.normal(0.0, 0.01, (120, 20, 3))
    frames[60:, _J("HandRight")] += 0.15  # a stretched bone
    states = rng.choice(
        [skeleton.NOT_TRACKED, skeleton.INFERRED, skeleton.TRACKED], (120, 20), p=[0.05, 0.2, 0.75]
    )
    states[:10] = skeleton.TRACKED
    runs = []
    for hidden in (False, True):
        with numpy_only() if hidden else contextlib.nullcontext():
            trust = SensorTrust()
            values = [trust.update(frames[t], states[t], t / 30.0) for t in range(120)]
            runs.append((np.array(values), trust.lengths, trust._run_start.copy()))
    for compiled, reference in zip(*runs, strict=True):
        np.testing.assert_array_equal(compiled, reference)
    values = runs[0][0]
    assert np.any((values > 0.0) & (values < 0.5)) and values.mean() > 0.5  # decays, mostly 1


# --------------------------------------------------------------------------- fusion


def test_fuse_positions_keeps_trusted_joints_and_hangs_the_rest() -> None:
    rng = np.random.default_rng(0)
    truth = poses.rest_pose().astype(np.float64)
    sensor = truth + rng.normal(scale=0.01, size=truth.shape)
    database = truth + 0.2  # a rigid shift: right bones, wrong place
    trust = np.ones(20)
    trust[[_J("WristLeft"), _J("HandLeft")]] = 0.0
    sensor[[_J("WristLeft"), _J("HandLeft")]] += 0.5  # the sensor's lost joints are far off
    bones = poses.bone_vectors(truth)
    fused = fuse_positions(sensor, trust, database, bones, bone_weight=50.0, database_weight=1e-3)
    seen = trust > 0
    assert np.abs(fused[seen] - truth[seen]).max() < 0.03
    lost = [_J("WristLeft"), _J("HandLeft")]
    assert np.linalg.norm(fused[lost] - truth[lost], axis=-1).max() < 0.05  # hung off the elbow
    # Without a bone term, trusted joints are the sensor's and lost ones the database's.
    plain = fuse_positions(sensor, trust, database, bones, bone_weight=0.0, database_weight=1.0)
    assert np.allclose(plain[seen], sensor[seen]) and np.allclose(plain[lost], database[lost])


def test_fusion_holds_a_lost_limb_where_it_was_moving_with_the_body() -> None:
    config = FusionConfig(
        sensor_filter="raw",
        output_filter="raw",
        lengths="none",
        agreement_good=0.0,
        agreement_bad=1e-6,
        database_weight=1e-3,
    )
    fusion = SensorFusion(config)
    pose = poses.rest_pose().astype(np.float64)
    trust = np.ones(20)
    for t in range(10):
        out = fusion.update(pose, pose, trust, t / 30.0)
    assert np.allclose(out, pose, atol=1e-6)
    # The left forearm is lost; the database puts it elsewhere, the sensor drifts it away;
    # the body walks 0.3 m: the held forearm comes along, in its last configuration.
    lost = trust.copy()
    lost[[_J("WristLeft"), _J("HandLeft")]] = 0.0
    moved = pose + np.array([0.3, 0.0, 0.0])
    drifted = moved.copy()
    drifted[[_J("WristLeft"), _J("HandLeft")]] += np.array([0.0, 0.3, 0.2])
    database = moved.copy()
    database[[_J("WristLeft"), _J("HandLeft")]] -= np.array([0.0, 0.2, 0.0])
    out = fusion.update(database, drifted, lost, 11 / 30.0)
    assert np.abs(out - moved).max() < 0.02


@pytest.mark.parametrize("lengths", ["retarget", "solve", "none"])
def test_fusion_in_compiled_calls_is_the_numpy_fusion_to_the_bit(lengths: str) -> None:
    """``SensorFusion.update`` through ``compiled_fusion.fusion_bone_terms``, ``fusion_bones``
    and ``held_directions`` (with numba) against its numpy code on a noisy stream whose limbs
    are lost and found again (held bones, the database's share, the settling): the same poses
    and state to the bit, with and without a bone model."""
    import contextlib

    from fpg_gym.core.compiled import numpy_only

    rng = np.random.default_rng(5)
    pose = poses.rest_pose().astype(np.float64)
    count = 90
    sensor = (
        pose + rng.normal(0.0, 0.01, (count, 20, 3)) + np.linspace(0, 0.3, count)[:, None, None]
    )
    database = sensor + rng.normal(0.0, 0.02, (count, 20, 3))
    trust = rng.uniform(0.8, 1.0, (count, 20))
    trust[30:50, [_J("WristLeft"), _J("HandLeft")]] = 0.0  # lost, then found again
    trust[40:70, [_J("KneeRight"), _J("AnkleRight"), _J("FootRight")]] = 0.3
    trust[:20, _J("FootLeft")] = 0.0  # never seen before frame 20
    config = FusionConfig(enabled=True, lengths=lengths)
    for model in (None, packaged_bone_model("kinect-v2-to-vicon")):
        runs = []
        for hidden in (False, True):
            with numpy_only() if hidden else contextlib.nullcontext():
                fusion = SensorFusion(config, bone_model=model)
                out = [
                    fusion.update(database[t], sensor[t], trust[t], t / 30.0) for t in range(count)
                ]
                state = (fusion._held, fusion._disagreement, fusion._last_seen, fusion._length_sum)
                runs.append((np.array(out), *state))
        for compiled, reference in zip(*runs, strict=True):
            np.testing.assert_array_equal(compiled, reference)
        assert np.isfinite(runs[0][0]).all()


# --------------------------------------------------------------------------- bone model


def _pairs(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    clips = load_default_clips(["punch", "dance_b", "crawl"])
    clip = np.concatenate([c.positions[:40] for c in clips]).astype(np.float64)
    sensor = clip + rng.normal(scale=0.003, size=clip.shape)
    truth = clip.copy()  # the sensor's knees sit 4 cm low: a bias the model should learn
    for knee in (_J("KneeLeft"), _J("KneeRight")):
        truth[:, knee] += np.array([0.0, 0.04, 0.0])
    return sensor, truth


def test_bone_model_learns_a_bias_and_round_trips(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    sensor, truth = _pairs(rng)
    groups = np.repeat(["a", "b", "c"], 40)
    model = LinearBoneModel.fit(sensor, truth, groups, source="s", target="t")
    errors_before = metrics.mean_error(truth, sensor)
    bones = np.stack([model.bone_vectors(p) for p in sensor])
    after = np.linalg.norm(bones - poses.bone_vectors(truth), axis=-1).mean()
    assert after < 0.5 * errors_before
    assert model.info["penalty"] in (10.0, 100.0, 1000.0, 10000.0, 100000.0)
    assert set(model.info["cross_validation_m"]) == {"10", "100", "1000", "10000", "100000"}
    path = model.save(tmp_path / "bones.npz")
    loaded = LinearBoneModel.load(path)
    assert np.allclose(loaded.corrections(sensor[:5]), model.corrections(sensor[:5]), atol=1e-5)


def test_bone_model_files_are_checked(tmp_path: Path) -> None:
    np.savez(tmp_path / "bad.npz", weights=np.zeros(3))
    with pytest.raises(DataFormatError, match="not a bone model"):
        LinearBoneModel.load(tmp_path / "bad.npz")
    packaged = packaged_bone_model("kinect-v2-to-vicon")
    assert packaged.target == "vicon"
    with pytest.raises(ValueError, match="unknown name"):
        packaged_bone_model("kinect-v9")


# --------------------------------------------------------------------------- presets


def test_sensor_of_reads_the_recording() -> None:
    class Rec:
        def __init__(self, metadata: dict[str, Any]) -> None:
            self.metadata = metadata

    assert sensor_of(Rec({"sensor": "kinect-v2", "format": "msrc12"})) == "kinect-v2"
    assert sensor_of(Rec({"format": "msrc12"})) == "kinect-v1"
    assert sensor_of(Rec({"format": "simulated"})) == "simulated"
    assert sensor_of(Rec({})) == "unknown"
    assert sensor_of(Rec({"format": "msrc12"}), override="azure-kinect") == "azure-kinect"
    assert default_graph_name("kinect-v2") == "uiprmd"
    assert default_graph_name("simulated") == "embedded"


def test_pipelines_by_sensor_and_preset() -> None:
    uiprmd = packaged_graph("uiprmd")
    assert uiprmd.params["definitions"] == "vicon"
    kinect = pipeline("auto", "kinect-v2", uiprmd)
    assert kinect.options["fusion"].enabled and kinect.options["bone_model"] is not None
    assert "calibrate_output" not in kinect.options  # a database of joint centres
    foreign = pipeline("auto", "kinect-v2", default_graph())
    assert foreign.options["calibrate_output"] is True
    assert foreign.options["calibration_map"].target == "vicon"
    assert pipeline("auto", "simulated", uiprmd).options == {}
    unknown = pipeline("auto", "kinect-v1", uiprmd)
    assert unknown.options["calibrate_output"] is True and unknown.note
    papers = pipeline("papers", "kinect-v2", uiprmd)
    assert "fusion" not in papers.options and not papers.options["bones"].enabled
    manual = choose_pipeline("auto", "kinect-v2", uiprmd, {"sensor_blend": 0.5, "sensor_map": None})
    assert manual.preset == "manual" and manual.options == {"sensor_blend": 0.5}
    with pytest.raises(ValueError, match="preset"):
        pipeline("fastest", "kinect-v2", uiprmd)


def test_kinect_v2_pipeline_runs_and_keeps_a_tracked_stream_near_the_sensor(
    stream: Recording,
) -> None:
    graph = default_graph(exclude=["walk"])
    resources = SensorResources.packaged("kinect-v2")
    assert resources is not None
    plain = resources.__class__(resources.to_reference, None, resources.reference_poses)
    chosen = pipeline("auto", "kinect-v2", graph, resources=plain)
    with Reconstructor(graph, **chosen.options) as reconstructor:
        result = reconstructor.reconstruct(stream, "closed-form", rng=0)
    mapped = resources.to_reference.apply(stream.positions)
    distance = np.linalg.norm(result.poses - mapped, axis=-1)
    assert np.median(distance[30:]) < 0.03  # a tracked stream: the output is the mapped sensor
    occluded = occlude(stream, "legs", seed=2)
    with Reconstructor(graph, **chosen.options) as reconstructor:
        lost = reconstructor.reconstruct(occluded, "closed-form", rng=0).poses
    assert occluded.occluded is not None and occluded.ground_truth is not None
    raw = metrics.mpjpe(occluded.ground_truth, occluded.positions, mask=occluded.occluded)
    fused = metrics.mpjpe(occluded.ground_truth, lost, mask=occluded.occluded)
    assert fused < raw


def test_float32_energies_in_the_kinect_v2_pipeline(stream: Recording) -> None:
    """``energy_dtype`` through the auto preset's path (map, bone model, fusion): the closed
    form's point does not read the energy (same poses to the bit), its recorded energy is the
    float32 one; the local search keeps its accuracy on a lost limb."""
    graph = default_graph(exclude=["walk"])
    chosen = pipeline("auto", "kinect-v2", graph)
    occluded = occlude(stream, "legs", seed=2)
    assert occluded.ground_truth is not None
    out = {}
    for dtype in ("float64", "float32"):
        for method in ("closed-form", "local-search"):
            with Reconstructor(graph, **chosen.options, energy_dtype=dtype) as reconstructor:
                out[dtype, method] = reconstructor.reconstruct(occluded, method, rng=0)
    with Reconstructor(graph, **chosen.options, energy_dtype="float32") as reconstructor:
        first = reconstructor.prepare(occluded.positions[0], occluded.states[0], 0.0)
        assert first.energy.tables.matrix.dtype == np.float32
    np.testing.assert_array_equal(
        out["float32", "closed-form"].poses, out["float64", "closed-form"].poses
    )
    energies = {
        d: np.array([r.energy for r in out[d, "closed-form"].records])
        for d in ("float64", "float32")
    }
    np.testing.assert_allclose(energies["float32"], energies["float64"], rtol=1e-4)
    errors = {
        d: metrics.mpjpe(occluded.ground_truth, out[d, "local-search"].poses)
        for d in ("float64", "float32")
    }
    assert errors["float32"] == pytest.approx(errors["float64"], rel=0.01)


def test_cli_gives_a_kinect_v2_recording_its_pipeline(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 34: no tuning flag on a Kinect v2 recording runs its pipeline (printed, stored);
    --preset papers and explicit maps replace it; maps are usable by name."""
    import json

    from fpg_gym.cli import main
    from fpg_gym.experiments.demo import demo_recordings

    recording = demo_recordings()[0]  # UI-PRMD s08, in no packaged model
    out = tmp_path / "auto.npz"
    argv = ["reconstruct", "--input", str(recording), "--graph", "default", "--no-ragdoll"]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "configuration    auto: kinect-v2" in printed and "closed-form" in printed
    with np.load(out, allow_pickle=False) as archive:
        metadata = json.loads(str(archive["metadata"]))
        auto_error = float(archive["frame_error"].mean())
        raw_error = float(archive["frame_error_raw"].mean())
    assert metadata["pipeline"]["preset"] == "auto"
    assert metadata["pipeline"]["sensor"] == "kinect-v2"
    assert auto_error < 0.8 * raw_error
    papers = tmp_path / "papers.npz"
    assert main([*argv, "--out", str(papers), "--preset", "papers", "--no-progress"]) == 0
    assert "configuration    papers" in capsys.readouterr().out
    manual = tmp_path / "manual.npz"
    flags = ["--sensor-map", "kinect-v2-to-vicon", "--sensor-blend", "0.5", "--no-progress"]
    assert main([*argv, "--out", str(manual), *flags]) == 0
    assert "configuration    manual" in capsys.readouterr().out
    compare = tmp_path / "compare"
    argv = ["compare", "--inputs", str(recording), "--methods", "raw,holt+map,fpg:closed-form"]
    assert main([*argv, "--out", str(compare), "--quiet", "--no-plots", "--workers", "1"]) == 0
    config = json.loads((compare / "config.json").read_text())
    assert config["graph_resolved"] == "uiprmd"
    assert config["pipeline"]["preset"] == "auto"
    summary = json.loads((compare / "summary.json").read_text())["methods"]
    assert summary["fpg:closed-form"]["mpjpe_m"] < summary["holt+map"]["mpjpe_m"]
    assert summary["holt+map"]["mpjpe_m"] < summary["raw"]["mpjpe_m"]


@pytest.mark.parametrize("database", ["uiprmd", "embedded"])
def test_fusion_reuses_the_relabelling_map_only_where_the_labels_stay(
    stream: Recording, database: str
) -> None:
    """The fusion (and the online calibration, the embedded database's pipeline) take the
    sensor in the output's definitions from the relabelling (mapped once a frame) where the
    labels stay, and map a relabelled frame again: the outputs are those of mapping every
    frame again, to the bit."""
    graph = default_graph(exclude=["walk"])
    chosen = pipeline(
        "auto", "kinect-v2", packaged_graph("uiprmd") if database == "uiprmd" else graph
    )
    assert chosen.options.get("calibrate_output", False) == (database == "embedded")
    positions = stream.positions.copy()
    arms = LABEL_PERMUTATIONS[LABELLINGS.index("arms-swapped")]
    positions[40:55] = positions[40:55][:, arms]
    swapped = dataclasses.replace(stream, positions=positions)
    outputs, labellings = [], []
    for reuse in (True, False):
        with Reconstructor(graph, **chosen.options) as reconstructor:
            assert reconstructor._maps_for_fusion
            reconstructor._maps_for_fusion = reuse
            result = reconstructor.reconstruct(swapped, "closed-form", rng=0)
        outputs.append(result.poses)
        labellings.append(result.arrays()["labelling"])
    assert (labellings[0] != 0).any() and (labellings[0] == 0).any()
    np.testing.assert_array_equal(outputs[0], outputs[1])


def test_bone_model_of_one_pose_is_its_numpy_model_to_the_bit(
    stream: Recording, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A single pose's corrected bones (compiled turns with numba) equal those of numpy's
    einsums, to the bit."""
    model = packaged_bone_model("kinect-v2-to-vicon")
    batch = stream.positions[::7].astype(np.float64)
    batch[1] += 1.5  # away from the origin, and a half-turned pose
    batch[2] = batch[2] * np.array([-1.0, 1.0, -1.0])
    fast = [model.bone_vectors(pose) for pose in batch]
    monkeypatch.setattr(bone_model, "compiled_module", lambda name: None)
    for pose, expected in zip(batch, fast, strict=True):
        np.testing.assert_array_equal(model.bone_vectors(pose), expected)
