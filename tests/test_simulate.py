"""Kinect simulator: determinism, ground truth, occlusion by ray casts, CLI, realism smoke test."""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fpg_gym import cli
from fpg_gym.core import metrics, poses, skeleton
from fpg_gym.io import Clip, load_default_clips, read_recording
from fpg_gym.simulate import (
    SCENARIOS,
    Box,
    Camera,
    EpisodeSimulator,
    KinectSimulator,
    OcclusionModel,
    RayCaster,
    Scenario,
    get_scenario,
    place,
    scene,
    simulate,
)
from fpg_gym.simulate.ray_bounds import _slab_entry, segment_distances

REPO = Path(__file__).resolve().parents[1]
HAND_RIGHT = skeleton.joint_index("HandRight")


@pytest.fixture(scope="module")
def walk() -> Clip:
    return next(c for c in load_default_clips() if c.name == "walk")


def standing_clip(frames: int = 20) -> np.ndarray:
    """A still rest pose, feet on the floor, facing +Z."""
    pose = poses.rest_pose()
    pose = pose - np.array([0.0, pose[:, 1].min() - 0.05, 0.0], dtype=np.float32)
    return np.repeat(pose[None], frames, axis=0)


def test_deterministic_for_a_seed(walk: Clip) -> None:
    first = simulate(walk, "front-many", seed=7)
    second = simulate(walk, "front-many", seed=7)
    assert np.array_equal(first.positions, second.positions)
    assert np.array_equal(first.states, second.states)
    other = simulate(walk, "front-many", seed=8)
    assert not np.array_equal(first.positions, other.positions)
    with KinectSimulator("front-many") as simulator:  # a reused simulator gives the same
        assert np.array_equal(simulator.simulate(walk, seed=7).positions, first.positions)
        assert np.array_equal(simulator.simulate(walk, seed=7).positions, first.positions)


@pytest.mark.parametrize(
    ("clip_name", "scenario"),
    [("walk", "front-many"), ("kick", "left45-many"), ("dance_b", "right45-few")],
)
def test_ray_bounds_give_pybullets_answer(clip_name: str, scenario: str) -> None:
    """The rays the bounds settle without pybullet get the answer pybullet gives them."""
    clip = next(c for c in load_default_clips() if c.name == clip_name)
    spec = get_scenario(scenario)
    placement = place(clip.positions, spec)
    stage = placement.to_stage(clip.positions)
    heading = poses.facing_yaw(stage)
    with RayCaster() as caster:
        caster.build(stage, spec.occluders)
        fast = caster.trace(placement.camera.position, stage, spec.occluders, heading)
        every = caster.trace(
            placement.camera.position, stage, spec.occluders, heading, bounds=False
        )
    assert np.array_equal(fast.visible, every.visible)
    assert np.array_equal(fast.blocker, every.blocker)
    assert np.array_equal(fast.hit_point, every.hit_point)
    assert (every.blocker != -1).any() and (every.visible < 1).any()


def test_a_rebuilt_ray_caster_traces_as_a_new_one(
    walk: Clip, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Rebuilding keeps the boxes and remakes the body's shapes (the scene is reset every few
    builds): the same result as a new caster."""
    monkeypatch.setattr(scene, "_REMOVALS_PER_RESET", 2)
    spec = get_scenario("front-many")
    clips = [walk.positions[:30], walk.positions[30:60], walk.positions[10:50]]
    stages = [place(c, spec).to_stage(c) for c in clips]
    camera = place(clips[0], spec).camera.position
    with RayCaster() as reused:
        for _ in range(3):
            for stage in stages:
                heading = poses.facing_yaw(stage)
                reused.build(stage, spec.occluders)
                again = reused.trace(camera, stage, spec.occluders, heading)
                with RayCaster() as fresh:
                    fresh.build(stage, spec.occluders)
                    first = fresh.trace(camera, stage, spec.occluders, heading)
                assert np.array_equal(again.visible, first.visible)
                assert np.array_equal(again.blocker, first.blocker)
                assert np.array_equal(again.hit_point, first.hit_point)
        assert reused._removals == 2  # 9 builds: reset, removed, removed, reset, ...


def test_simulators_sharing_a_caster_give_their_own_streams(walk: Clip) -> None:
    """An episode simulator's scenarios cast in one pybullet client, taking turns."""
    run = walk.positions[15:55]
    names = ["front-many", "left45-few", "clean", "right45-many"]
    with EpisodeSimulator(names) as shared:
        for clip, seed in [(walk, 1), (run, 2), (walk, 3)]:
            for name in names:
                got = shared.simulator(name).simulate(clip, seed)
                alone = simulate(clip, name, seed)
                assert np.array_equal(got.positions, alone.positions)
                assert np.array_equal(got.states, alone.states)
    with RayCaster(rays_per_joint=1) as caster, pytest.raises(ValueError, match="rays per joint"):
        KinectSimulator("front-many", caster=caster)


def test_segment_distances_match_a_dense_search(rng: np.random.Generator) -> None:
    start, end, first, second = (rng.normal(size=(200, 3)) for _ in range(4))
    second[:20] = first[:20]  # a point
    distances = segment_distances(start, end, first, second)
    s = np.linspace(0.0, 1.0, 401)
    one = start[:, None] + s[:, None] * (end - start)[:, None]  # (200, 401, 3)
    other = first[:, None] + s[:, None] * (second - first)[:, None]
    dense = np.linalg.norm(one[:, :, None] - other[:, None], axis=-1).min(axis=(1, 2))
    assert np.all(distances <= dense + 1e-12)
    assert np.all(dense - distances < 0.01)


def test_kept_ray_casts_give_the_same_streams(walk: Clip) -> None:
    run = walk.positions[20:60]
    with (
        KinectSimulator("right45-many") as keeping,
        KinectSimulator("right45-many", traces_kept=0) as casting,
    ):
        for clip, seed in [(walk, 1), (run, 2), (walk, 3), (run, 3), (walk, 1)]:
            kept, cast = keeping.simulate(clip, seed), casting.simulate(clip, seed)
            assert np.array_equal(kept.positions, cast.positions)
            assert np.array_equal(kept.states, cast.states)
            assert np.array_equal(kept.occluded, cast.occluded)
        assert len(keeping._traces) == 2 and not casting._traces
    with pytest.raises(ValueError, match="traces_kept"):
        KinectSimulator("front-many", traces_kept=-1)


@pytest.mark.parametrize("scenario", ["clean", "front-few", "left45-many", "right45-many"])
def test_ground_truth_is_the_clip_in_camera_space(walk: Clip, scenario: str) -> None:
    recording = simulate(walk, scenario, seed=1)
    transform = recording.metadata["clip_to_camera"]
    rotation = np.array(transform["rotation"])
    translation = np.array(transform["translation"])
    assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(1.0)  # rigid, no mirror
    expected = walk.positions.astype(np.float64) @ rotation.T + translation
    assert recording.ground_truth is not None
    assert np.allclose(recording.ground_truth, expected, atol=1e-5)
    assert np.allclose(
        poses.bone_lengths(recording.ground_truth), poses.bone_lengths(walk.positions), atol=1e-5
    )
    assert np.all(np.isfinite(recording.positions))
    assert recording.metadata["untracked_positions"] == "simulated"
    assert recording.timestamps[1] == pytest.approx(1 / walk.fps)


def test_camera_space_follows_the_kinect_convention(walk: Clip) -> None:
    truth = simulate(walk, "clean", seed=0).ground_truth
    assert truth is not None
    left = skeleton.joint_index("ShoulderLeft")
    right = skeleton.joint_index("ShoulderRight")
    # The body faces the sensor: its left side at negative X, head up, 2.5 m away.
    assert np.mean(truth[:, left, 0] < truth[:, right, 0]) > 0.9
    assert np.all(truth[:, skeleton.joint_index("Head"), 1] > truth[:, 0, 1])
    assert abs(float(np.mean(truth[:, 0, 2])) - 2.5) < 0.3


def test_clean_has_only_sensor_noise(walk: Clip) -> None:
    recording = simulate(walk, "clean", seed=0)
    assert recording.ground_truth is not None
    error = metrics.mean_error(recording.ground_truth, recording.positions)
    assert 0.01 < error < 0.08
    assert recording.state_shares()["tracked"] > 0.95
    many = simulate(walk, "front-many", seed=0)
    assert many.ground_truth is not None
    assert many.state_shares()["tracked"] < 0.8
    assert metrics.mean_error(many.ground_truth, many.positions) > error


def _blocked_hand_scenario(**occlusion: object) -> Scenario:
    base = Scenario(
        name="box-in-front-of-the-hand",
        description="test",
        self_occlusion=False,
        left_right_confusion=False,
        occlusion=OcclusionModel(snap_probability=0.0, **occlusion),  # type: ignore[arg-type]
    )
    clip = standing_clip()
    placement = place(clip, base)
    hand = placement.to_stage(clip)[0, HAND_RIGHT]
    camera = np.asarray(placement.camera.position)
    center = camera + 0.6 * (hand - camera)
    box = Box("blocker", size=(0.08, 0.08, 0.02), center=tuple(center.tolist()))
    return replace(base, occluders=(box,))


def test_a_box_between_camera_and_hand_hides_only_the_hand() -> None:
    scenario = _blocked_hand_scenario(not_tracked_probability=1.0, not_tracked_after=(0, 0))
    recording = simulate(standing_clip(), scenario, seed=3)
    others = np.arange(skeleton.NUM_JOINTS) != HAND_RIGHT
    assert np.all(recording.states[:, HAND_RIGHT] == 0)  # not tracked
    assert np.all(recording.states[:, others] == 2)  # every other joint tracked
    # Without the box, the hand is tracked.
    free = simulate(standing_clip(), replace(scenario, occluders=()), seed=3)
    assert np.all(free.states == 2)


def test_a_hidden_hand_is_first_inferred_by_default() -> None:
    recording = simulate(standing_clip(), _blocked_hand_scenario(), seed=3)
    assert np.all(recording.states[:10, HAND_RIGHT] == 1)


def test_tracking_state_flickers_and_inferred_joints_move_calmly() -> None:
    # A seen joint is reported inferred for short runs; its position stays the seen one.
    flicker = _blocked_hand_scenario(flicker_rate=0.05, flicker_mean_frames=2.0)
    still = standing_clip(400)
    plain = simulate(still, _blocked_hand_scenario(), seed=3)
    flickering = simulate(still, flicker, seed=3)
    seen = np.arange(skeleton.NUM_JOINTS) != HAND_RIGHT
    assert np.all(plain.states[:, seen] == 2)
    share = np.mean(flickering.states[:, seen] == 1)
    assert 0.03 < share < 0.2  # about rate × mean length = 10 %, minus overlaps
    np.testing.assert_array_equal(flickering.states[:, HAND_RIGHT], plain.states[:, HAND_RIGHT])
    # Smoothing an inferred joint's reported position lowers its jitter, not the seen ones'.
    calm = simulate(still, _blocked_hand_scenario(inferred_calm=0.8), seed=3)
    hand_jitter = {name: metrics.jitter(r.positions)[HAND_RIGHT] for name, r in
                   (("plain", plain), ("calm", calm))}  # fmt: skip
    assert hand_jitter["calm"] < 0.5 * hand_jitter["plain"]
    np.testing.assert_array_equal(calm.positions[:, seen], plain.positions[:, seen])
    with pytest.raises(ValueError, match="inferred_calm"):
        OcclusionModel(inferred_calm=1.0)
    with pytest.raises(ValueError, match="flicker_mean_frames"):
        OcclusionModel(flicker_mean_frames=0.5)


def test_back_to_the_sensor_is_reported_mirrored() -> None:
    still = standing_clip(60)
    turned = still.copy()
    turned[40:] = still[40:] @ poses.yaw_matrix(np.array(np.pi)).T  # last third turned around
    mirror_on = simulate(turned, replace(get_scenario("clean"), left_right_confusion=True), seed=0)
    mirror_off = simulate(turned, "clean", seed=0)
    left, right = skeleton.joint_index("ShoulderLeft"), skeleton.joint_index("ShoulderRight")
    truth = mirror_on.ground_truth
    assert truth is not None
    assert np.allclose(mirror_on.positions[45:, left], truth[45:, right], atol=0.12)
    assert np.allclose(mirror_off.positions[45:, left], truth[45:, left], atol=0.12)
    assert np.allclose(mirror_on.positions[:35, left], truth[:35, left], atol=0.12)
    assert mirror_on.metadata["stats"]["mirrored_frames"] >= 15


def test_metadata_records_the_setup(walk: Clip) -> None:
    recording = simulate(walk, "left45-many", seed=2)
    meta = recording.metadata
    json.dumps(meta)
    assert meta["scenario"] == "left45-many" and meta["seed"] == 2
    assert meta["scenario_parameters"]["view_deg"] == 45.0
    assert {"position_m", "yaw_deg", "pitch_deg"} <= set(meta["camera"])
    assert meta["stats"]["ms_per_frame"] > 0
    assert {o["name"] for o in meta["scenario_parameters"]["occluders"]} >= {"workbench", "panel"}


@pytest.mark.parametrize(
    ("call", "error", "message"),
    [
        (lambda c: simulate(c, "nowhere", seed=0), ValueError, "unknown scenario 'nowhere'"),
        (lambda c: simulate(np.zeros((5, 19, 3)), "clean", seed=0), ValueError, "shape"),
        (lambda c: simulate(np.full((5, 20, 3), np.nan), "clean"), ValueError, "non-finite"),
        (lambda c: simulate(c, "clean", seed=-1), ValueError, "seed"),
        (lambda c: simulate(c, "clean", seed=1.5), ValueError, "seed"),
        (lambda c: replace(get_scenario("clean"), distance=6.0), ValueError, "0.8-4 m"),
        (lambda c: OcclusionModel(snap_probability=2.0), ValueError, "snap_probability"),
        (lambda c: Box("b", size=(0.0, 1.0, 1.0), center=(0, 0, 0)), ValueError, "size"),
        (lambda c: Box("b", (1, 1, 1), (0, 0, 0), carried_by="Tail"), KeyError, "Tail"),
        (lambda c: Camera((0, 1, 0), yaw=0.0, pitch=2.0), ValueError, "pitch"),
    ],
)
def test_bad_input_gives_clear_errors(walk: Clip, call: object, error: type, message: str) -> None:
    with pytest.raises(error, match=message):
        call(walk)  # type: ignore[operator]


def test_camera_transforms_round_trip(rng: np.random.Generator) -> None:
    camera = Camera.look_at((1.0, 1.5, 3.0), (0.0, 1.0, 0.0))
    points = rng.normal(size=(7, 3))
    assert np.allclose(camera.camera_to_world(camera.world_to_camera(points)), points)
    target = camera.world_to_camera([0.0, 1.0, 0.0])
    assert np.allclose(target[:2], 0.0, atol=1e-9) and target[2] > 0  # on the optical axis
    assert camera.in_view(target) and not camera.in_view([0.0, 0.0, 5.0])
    assert not camera.in_view([3.0, 0.0, 2.0])  # outside the 57° field of view


def test_every_named_scenario_runs(walk: Clip) -> None:
    for name in SCENARIOS:
        recording = simulate(walk.positions[:10], name, seed=0)
        assert recording.num_frames == 10
        assert set(np.unique(recording.states)) <= {0, 1, 2}


# --------------------------------------------------------------------------- CLI, realism


def test_cli_simulate_writes_a_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "walk.npz"
    argv = ["simulate", "default:walk", "--scenario", "front-few", "--seed", "4", "--out", str(out)]
    assert cli.main([*argv, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["scenario"] == "front-few" and summary["frames"] > 0
    recording = read_recording(out)
    assert recording.metadata["seed"] == 4 and recording.ground_truth is not None
    assert summary["raw_error_m"] == pytest.approx(
        metrics.mean_error(recording.ground_truth, recording.positions), rel=1e-5
    )


def test_cli_list_and_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["simulate", "--list"]) == 0
    listing = capsys.readouterr().out
    for name in ("clean", "front-few", "front-many", "left45-many", "right45-many"):
        assert name in listing
    out = str(tmp_path / "x.npz")
    assert cli.main(["simulate", "default:walk", "--scenario", "nope", "--out", out]) == 2
    assert "unknown scenario 'nope'" in capsys.readouterr().err
    assert cli.main(["simulate", "default:nothing", "--out", out]) == 2
    assert cli.main(["simulate", "default:walk"]) == 2  # --out missing


def test_realism_script_smoke(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    spec = importlib.util.spec_from_file_location("realism", REPO / "scripts" / "realism.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "realism", module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    assert module.main(["--quick"]) == 0
    text = capsys.readouterr().out
    assert "| sim clean |" in text and "| sim front-many |" in text
    assert "HandRight" in text


def test_slab_entry_of_segments_parallel_to_a_slab() -> None:
    """A segment parallel to a box's slab enters where the other slabs say when it lies
    inside that slab, and never when it lies outside."""
    half = np.array([[1.0, 1.0, 1.0]])
    starts = np.array([[-2.0, 0.5, 0.0], [-2.0, 1.5, 0.0], [0.0, 0.0, 0.0], [0.5, -3.0, 2.0]])
    ends = np.array([[2.0, 0.5, 0.0], [2.0, 1.5, 0.0], [0.0, 0.0, 0.0], [0.5, 1.0, 2.0]])
    start = [starts[None, :, k, None] for k in range(3)]  # (B, T, 1) per coordinate
    direction = [(ends - starts)[None, :, k, None] for k in range(3)]  # (B, T, R)
    entry = _slab_entry(start, direction, half)[0, :, 0]
    assert entry[0] == 0.25  # inside the Y and Z slabs all along
    assert entry[1] == np.inf  # outside the Y slab all along
    assert entry[2] == 0.0  # a point inside the box
    assert entry[3] == np.inf  # outside the Z slab
