"""KinectPoseEnv: Gymnasium API, spaces, rewards, options, determinism, vector use, rendering."""

from __future__ import annotations

import copy
import multiprocessing
import pickle
import warnings
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

import fpg_gym  # registers the env
from fpg_gym.core.metrics import acceleration, frame_error
from fpg_gym.env import ENV_ID, ExactAction, KinectPoseEnv, StageTimes
from fpg_gym.env_observation import LATENT_LIMIT, ObservationLayout
from fpg_gym.io import Recording, load_default_clips, write_recording
from fpg_gym.reconstruct import SearchProblem
from fpg_gym.simulate import plan_episode, simulate

SMALL = {"k": 8, "clips": ("walk",), "scenarios": ("front-many",)}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A private cache for the embedded default graph (built once for this module)."""
    return tmp_path_factory.mktemp("fpg-cache")


def make(cache_dir: Path, **kwargs: Any) -> KinectPoseEnv:
    options: dict[str, Any] = {**SMALL, "ragdoll": False, "cache_dir": cache_dir}
    options.update(kwargs)
    return KinectPoseEnv(**options)


def walk_recording(seed: int = 0, frames: int | None = None, truth: bool = True) -> Recording:
    rec = simulate(load_default_clips(["walk"])[0], "front-many", seed=seed)
    n = frames or rec.num_frames
    return Recording(
        positions=rec.positions[:n],
        states=rec.states[:n],
        timestamps=rec.timestamps[:n],
        ground_truth=rec.ground_truth[:n] if truth and rec.ground_truth is not None else None,
        metadata={"name": f"walk-{seed}"},
    )


# --------------------------------------------------------------------------- registration, spaces


def test_registered_and_made_with_keyword_arguments(cache_dir: Path) -> None:
    assert ENV_ID in gym.registry
    env = gym.make(ENV_ID, cache_dir=cache_dir, ragdoll=False, **SMALL)
    assert isinstance(env.unwrapped, KinectPoseEnv)
    assert env.unwrapped.candidates == 8
    assert env.spec is not None and env.spec.kwargs["k"] == 8
    env.close()


def test_registration_is_idempotent_and_lazy() -> None:
    import importlib
    import subprocess
    import sys

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "Overriding environment" warning
        importlib.reload(fpg_gym)
    assert gym.spec(ENV_ID).entry_point == "fpg_gym.env:KinectPoseEnv"
    code = "import sys, fpg_gym; print('fpg_gym.env' in sys.modules, 'pybullet' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_spaces_and_observation_layout(cache_dir: Path) -> None:
    env = make(cache_dir, latent_dim=6)
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (6,), np.float32)
    layout = env.observation_layout
    assert env.observation_space.shape == (ObservationLayout(6, 8).size,)
    # Slices tile the vector in order, with the documented shapes.
    stops = [*[sl.start for sl in layout.values()][1:], env.layout.size]
    assert [sl.stop for sl in layout.values()] == stops
    assert env.layout.shapes["latent_basis"] == (6, 60)
    assert env.layout.shapes["z_candidates"] == (8, 6)
    obs, _ = env.reset(seed=1)
    assert obs.dtype == np.float32 and obs in env.observation_space
    parts = env.split_observation(obs)
    problem = env.problem
    assert isinstance(problem, SearchProblem)
    np.testing.assert_allclose(parts["kinect"], problem.kinect_pose, atol=1e-6)
    np.testing.assert_allclose(parts["reliability"], problem.reliability, atol=1e-6)
    np.testing.assert_allclose(parts["reliability_terms"][2], problem.tracking, atol=1e-6)
    np.testing.assert_allclose(parts["bone_lengths"], problem.lengths, atol=1e-6)
    np.testing.assert_allclose(parts["latent_basis"][: problem.dim], problem.basis, atol=1e-6)
    assert parts["latent_mask"].sum() == problem.dim == 6
    assert parts["candidate_mask"].sum() == len(problem.nodes)
    assert parts["context"][0] == 1.0  # first frame: no prediction, no previous pose
    assert parts["context"][2] == 0.0 and not parts["prediction"].any()
    # A batch splits too.
    batch = env.split_observation(np.stack([obs, obs]))
    assert batch["kinect"].shape == (2, 20, 3)
    with pytest.raises(ValueError, match="expected shape"):
        env.split_observation(obs[:-1])
    env.close()


def test_latent_parts_are_the_actions_that_select_those_points(cache_dir: Path) -> None:
    env = make(cache_dir)
    env.reset(seed=2)
    obs, *_ = env.step(np.zeros(20, np.float32))  # frame 1 has a prediction
    parts = env.split_observation(obs)
    problem = env.problem
    assert problem is not None and problem.z_prediction is not None
    d = problem.dim
    for name, z in (("z_kinect", problem.z_kinect), ("z_prediction", problem.z_prediction)):
        inside = np.abs(env.action_for(z)) < LATENT_LIMIT
        np.testing.assert_allclose(
            parts[name][:d][inside[:d]], env.action_for(z)[:d][inside[:d]], rtol=1e-5, atol=1e-5
        )
    z_nodes = problem.encode(problem.node_poses)
    action = env.action_for(z_nodes[0])
    if np.all(np.abs(action) <= 1.0):  # the best candidate reachable: the step decodes it
        np.testing.assert_allclose(env.latent_point(action), z_nodes[0], atol=1e-9)
    np.testing.assert_allclose(parts["x0"][:d], np.clip(problem.x0 / 3.0, -10, 10), atol=1e-5)
    env.close()


def test_observations_stay_finite_and_inside_bounds_over_an_episode(cache_dir: Path) -> None:
    env = make(cache_dir)
    obs, _ = env.reset(seed=3)
    env.action_space.seed(3)
    terminated = False
    while not terminated:
        obs, reward, terminated, _, _ = env.step(env.action_space.sample())
        assert np.all(np.isfinite(obs)) and obs in env.observation_space
        assert np.isfinite(reward)
    assert env.problem is None
    with pytest.raises(RuntimeError, match="reset"):
        env.step(env.action_space.sample())
    env.close()


# --------------------------------------------------------------------------- actions


def test_padding_axes_beyond_the_frame_dimension_are_ignored(cache_dir: Path) -> None:
    env_a, env_b = make(cache_dir, k=5), make(cache_dir, k=5)
    obs_a, _ = env_a.reset(seed=4)
    env_b.reset(seed=4)
    assert env_a.problem is not None and env_a.problem.dim == 4  # K - 1 < latent_dim = 20
    parts = env_a.split_observation(obs_a)
    assert parts["latent_mask"].sum() == 4 and not parts["latent_basis"][4:].any()
    rng = np.random.default_rng(0)
    for _ in range(5):
        action = rng.uniform(-1, 1, 20).astype(np.float32)
        other = action.copy()
        other[4:] = rng.uniform(-1, 1, 16)
        out_a = env_a.step(action)
        out_b = env_b.step(other)
        np.testing.assert_array_equal(out_a[0], out_b[0])
        assert out_a[1] == out_b[1]
    env_a.close()
    env_b.close()


def test_zero_action_is_x0_in_delta_mode_and_the_mean_in_absolute_mode(cache_dir: Path) -> None:
    env = make(cache_dir)
    env.reset(seed=5)
    env.step(np.zeros(20, np.float32))
    problem = env.problem
    assert problem is not None
    np.testing.assert_array_equal(env.latent_point(np.zeros(20)), problem.x0)
    _, _, _, _, info = env.step(np.zeros(20, np.float32))
    assert info["energy"] == pytest.approx(info["energy_x0"], rel=1e-12)
    absolute = make(cache_dir, action_mode="absolute", action_scale=2.0)
    absolute.reset(seed=5)
    np.testing.assert_array_equal(absolute.latent_point(np.zeros(20)), np.zeros(7))  # d = K - 1
    np.testing.assert_allclose(absolute.latent_point(np.full(20, 0.5)), np.full(7, 1.0))
    env.close()
    absolute.close()


def test_out_of_bound_actions_are_clipped_unless_disabled(cache_dir: Path) -> None:
    env = make(cache_dir)
    env.reset(seed=6)
    problem = env.problem
    assert problem is not None
    big = np.full(20, 4.0)
    np.testing.assert_allclose(env.latent_point(big), problem.x0 + 3.0)
    _, _, _, _, info = env.step(big.astype(np.float32))
    assert info["action_clipped"] is True
    loose = make(cache_dir, clip_actions=False)
    loose.reset(seed=6)
    assert loose.problem is not None
    np.testing.assert_allclose(loose.latent_point(big), loose.problem.x0 + 12.0)
    # An ExactAction is never clipped, whatever clip_actions says (and it stays set).
    exact = ExactAction(big)
    assert env.problem is not None and env.clip_actions is True
    np.testing.assert_allclose(env.latent_point(exact), env.problem.x0 + 12.0)
    np.testing.assert_allclose(env.latent_point(np.asarray(exact)), env.problem.x0 + 3.0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(20, np.nan, np.float32))
    with pytest.raises(ValueError, match="expected shape"):
        env.step(np.zeros(3, np.float32))
    env.close()
    loose.close()


@pytest.mark.parametrize(("dtype", "rel"), [("float64", 1e-9), ("float32", 1e-5)])
def test_problem_is_public_and_an_optimiser_point_is_reconstructed_exactly(
    cache_dir: Path, dtype: str, rel: float
) -> None:
    env = make(cache_dir, clip_actions=False, reconstructor_options={"energy_dtype": dtype})
    env.reset(seed=7)
    env.step(np.zeros(20, np.float32))
    problem = env.problem
    assert isinstance(problem, SearchProblem) and env.reconstructor.config.max_evaluations == 2000
    found = env.reconstructor.search("local-search", np.random.default_rng(0))
    assert 0 < problem.evaluations == found.evaluations <= 2000
    action = env.action_for(found.x, exact=True)
    assert isinstance(action, ExactAction)
    np.testing.assert_array_equal(action, env.action_for(found.x))
    _, reward, _, _, info = env.step(action)
    assert info["evaluations"] == problem.evaluations
    # the search's fused rows and the record's terms round differently (float32: 1e-5)
    assert info["energy"] == pytest.approx(found.energy, rel=rel)
    assert reward == pytest.approx(-found.energy, rel=rel)
    assert env.problem is not problem
    env.close()


# --------------------------------------------------------------------------- rewards and info


@pytest.mark.parametrize("mode", ["energy", "error", "combined"])
def test_reward_modes_and_info_terms(cache_dir: Path, mode: str) -> None:
    env = make(cache_dir, reward_mode=mode, error_weight=2.0, energy_weights=(1.0, 0.5, 2.0, 0.3))
    _, info0 = env.reset(seed=8)
    assert info0["has_ground_truth"] and info0["clip"] == "walk"
    rng = np.random.default_rng(1)
    for _ in range(4):
        _, reward, _, _, info = env.step(rng.uniform(-0.3, 0.3, 20).astype(np.float32))
    terms = [info[k] for k in ("reward_control", "reward_style", "reward_bone", "reward_temporal")]
    assert sum(terms) == pytest.approx(-info["energy"], rel=1e-9)
    assert all(t <= 0 for t in terms)
    assert info["reward_temporal"] < 0  # Em exists from the third frame on
    truth = env.recording.ground_truth  # type: ignore[union-attr]
    assert info["frame_error"] == pytest.approx(
        float(frame_error(truth[info["frame"]], info["pose"])[0])
    )
    assert info["raw_frame_error"] > 0
    expected = {
        "energy": -info["energy"],
        "error": -info["frame_error"],
        "combined": -(info["energy"] + 2.0 * info["frame_error"]),
    }[mode]
    assert reward == pytest.approx(expected, rel=1e-12)
    assert info["pose"].shape == (20, 3) and info["nodes"].shape == (8,)
    assert isinstance(info["timings"], StageTimes) and info["timings"]["env_step"] > 0
    env.close()


def test_step_errors_are_frame_error_to_the_bit(cache_dir: Path) -> None:
    # The env keeps the truth's bone vectors per episode: its errors and the "smooth" reward's
    # acceleration are those of frame_error and acceleration on the step's poses, to the bit.
    env = make(cache_dir, reward_mode="smooth")
    env.reset(seed=3)
    recording = env.recording
    assert recording is not None and recording.ground_truth is not None
    truth, rng, outputs = recording.ground_truth, np.random.default_rng(2), []
    for _ in range(12):
        t = env.frame
        _, reward, _, _, info = env.step(rng.uniform(-0.5, 0.5, 20).astype(np.float32))
        errors = frame_error(truth[[t, t]], np.stack([info["pose"], recording.positions[t]]))
        assert info["frame_error"] == float(errors[0])
        assert info["raw_frame_error"] == float(errors[1])
        outputs.append(info["pose"].astype(np.float64))
        expected = 0.0
        if len(outputs) >= 3:
            stamps = recording.timestamps[t - 2 : t + 1]
            expected = float(acceleration(np.stack(outputs[-3:]), timestamps=stamps).mean())
        assert info["acceleration"] == expected
        assert reward == -(info["frame_error"] + 0.002 * expected)
    env.close()


def test_error_rewards_need_ground_truth(cache_dir: Path) -> None:
    blind = walk_recording(truth=False)
    with pytest.raises(ValueError, match="ground truth"):
        make(cache_dir, clips=None, scenarios=None, recordings=[blind], reward_mode="error")
    env = make(
        cache_dir, clips=None, scenarios=None, recordings=[walk_recording()], reward_mode="combined"
    )
    with pytest.raises(ValueError, match="ground truth"):
        env.reset(options={"recording": blind})
    energy = make(cache_dir, clips=None, scenarios=None, recordings=[blind])
    _, info = energy.reset(seed=0)
    assert info["has_ground_truth"] is False
    _, _, _, _, info = energy.step(np.zeros(20, np.float32))
    assert "frame_error" not in info and info["energy"] > 0
    env.close()
    energy.close()


def test_ragdoll_counts_in_info(cache_dir: Path) -> None:
    env = make(cache_dir, ragdoll=True)
    env.reset(seed=9)
    _, _, _, _, info = env.step(np.zeros(20, np.float32))
    assert info["ragdoll_builds"] == 1 and info["ragdoll_resets"] == 1
    assert info["timings"]["ragdoll"] > 0
    resets = builds = 0
    terminated = False
    while not terminated:
        _, _, terminated, _, info = env.step(np.zeros(20, np.float32))
        resets += info["ragdoll_resets"]
        builds += info["ragdoll_builds"]
        # A step's count, not the stream's running total: at most one divergence per frame
        # (each one resets the body to the target, see Ragdoll.track).
        assert info["ragdoll_divergences"] in (0, 1)
    assert resets == builds  # every (re)build places the body on the target, nothing else does
    env.close()


def test_stage_times_compare_by_stage_names() -> None:
    a, b = StageTimes({"x": 1.0, "y": 2.0}), StageTimes({"x": 5.0, "y": 0.5})
    assert a == b and a != StageTimes({"x": 1.0}) and dict(a) != dict(b)
    assert a["y"] == 2.0 and list(a) == ["x", "y"] and len(a) == 2


# --------------------------------------------------------------------------- episodes and options


def test_reset_options_pick_the_named_recording(cache_dir: Path, tmp_path: Path) -> None:
    first, second = walk_recording(1, frames=10), walk_recording(2, frames=12)
    path = write_recording(tmp_path / "second.npz", second)
    env = make(cache_dir, clips=None, scenarios=None, recordings=[first, path])
    assert env.episode_names == ["walk-1", "second.npz"]
    _, info = env.reset(seed=0, options={"recording": "second.npz"})
    assert info["recording"] == "second.npz" and info["num_frames"] == 12
    np.testing.assert_array_equal(env.recording.positions, second.positions)  # type: ignore[union-attr]
    _, info = env.reset(options={"recording": 0})
    assert info["recording"] == "walk-1" and env.recording is first
    with pytest.raises(ValueError, match="unknown recording"):
        env.reset(options={"recording": "nope"})
    with pytest.raises(ValueError, match="apply to clip episodes"):
        env.reset(options={"clip": "walk"})
    with pytest.raises(ValueError, match="unknown key"):
        env.reset(options={"speed": 2})
    env.close()


def test_reset_options_pick_clip_scenario_and_seed(cache_dir: Path) -> None:
    env = make(cache_dir, clips=("walk", "kick"), scenarios=("front-many", "left45-many"))
    _, info = env.reset(seed=0, options={"clip": "kick", "scenario": "left45-many", "seed": 11})
    assert (info["clip"], info["scenario"], info["seed"]) == ("kick", "left45-many", 11)
    # The planner's seeding rule: the stream compare simulates for kick/left45-many/seed 11.
    sim_seed = plan_episode("kick", "left45-many", 11).sim_seed
    expected = simulate(load_default_clips(["kick"])[0], "left45-many", seed=sim_seed)
    np.testing.assert_array_equal(env.recording.positions, expected.positions)  # type: ignore[union-attr]
    # Options do not change the random stream: the next unseeded episode is the same.
    _, after_options = env.reset()
    env.reset(seed=0)
    _, after_plain = env.reset()
    assert after_options["recording"] == after_plain["recording"]
    with pytest.raises(ValueError, match="not one of"):
        env.reset(options={"scenario": "front-few"})
    with pytest.raises(ValueError, match="recording name"):
        env.reset(options={"recording": "walk"})
    given = walk_recording(4, frames=6)
    _, info = env.reset(options={"recording": given})  # any env plays a given Recording
    assert env.recording is given and info["recording"] == "walk-4" and info["num_frames"] == 6
    env.close()


def test_simulator_seeds_bound_the_seeds_and_cache_the_streams(cache_dir: Path) -> None:
    env = make(cache_dir, clips=("walk", "kick"), simulator_seeds=2)
    seeds = {env.reset(seed=i)[1]["seed"] for i in range(8)}
    assert seeds <= {0, 1} and len(seeds) == 2
    env.reset(options={"clip": "kick", "seed": 1})
    first = env.recording
    env.reset(options={"clip": "kick", "seed": 1})
    assert env.recording is first  # cached, not simulated again
    env.reset(options={"clip": "kick", "seed": 7})  # outside range(2): simulated, not kept
    kept = env.recording
    env.reset(options={"clip": "kick", "seed": 7})
    assert env.recording is not kept
    np.testing.assert_array_equal(env.recording.positions, kept.positions)  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="simulator_seeds"):
        make(cache_dir, simulator_seeds=0)
    env.close()


def test_episode_terminates_at_the_end_and_truncates_at_the_limit(cache_dir: Path) -> None:
    short = walk_recording(frames=5)
    env = make(cache_dir, clips=None, scenarios=None, recordings=[short])
    env.reset(seed=0)
    flags = [env.step(np.zeros(20, np.float32))[2:4] for _ in range(5)]
    assert flags == [(False, False)] * 4 + [(True, False)]
    limited = make(cache_dir, clips=None, scenarios=None, recordings=[short], max_episode_steps=3)
    limited.reset(seed=0)
    flags = [limited.step(np.zeros(20, np.float32))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]
    wrapped = gym.make(
        ENV_ID, recordings=[short], k=8, ragdoll=False, cache_dir=cache_dir, max_episode_steps=2
    )
    wrapped.reset(seed=0)
    assert wrapped.step(np.zeros(20, np.float32))[3] is False
    assert wrapped.step(np.zeros(20, np.float32))[3] is True
    for e in (env, limited, wrapped):
        e.close()


def test_same_seed_same_actions_identical_over_50_steps(cache_dir: Path) -> None:
    """Ragdoll on; episodes end and restart within the 50 steps (walk has 38 frames)."""

    def run(env: KinectPoseEnv) -> tuple[list[np.ndarray], list[float], list[dict[str, Any]]]:
        obs, _ = env.reset(seed=21)
        rng = np.random.default_rng(5)
        observations, rewards, infos = [obs], [], []
        for _ in range(50):
            obs, reward, terminated, truncated, info = env.step(
                rng.uniform(-1, 1, 20).astype(np.float32)
            )
            observations.append(obs)
            rewards.append(float(reward))
            infos.append(info)
            if terminated or truncated:
                obs, _ = env.reset()
                observations.append(obs)
        return observations, rewards, infos

    a = run(make(cache_dir, ragdoll=True, clips=("walk", "kick")))
    b_env = make(cache_dir, ragdoll=True, clips=("walk", "kick"))
    b = run(b_env)
    c = run(b_env)  # the same env again: earlier episodes leave no trace
    for other in (b, c):
        assert len(a[0]) == len(other[0]) > 51
        for x, y in zip(a[0], other[0], strict=True):
            np.testing.assert_array_equal(x, y)
        assert a[1] == other[1]
        for x, y in zip(a[2], other[2], strict=True):
            assert data_equivalence(x, y, exact=True)
    d_env = make(cache_dir, ragdoll=True, clips=("walk", "kick"))
    d_obs, _ = d_env.reset(seed=22)
    assert not np.array_equal(d_obs, a[0][0])
    b_env.close()
    d_env.close()


# --------------------------------------------------------------------------- checkers


@pytest.mark.parametrize("mode", ["vector", "dict"])
def test_gymnasium_check_env_passes_without_warnings(cache_dir: Path, mode: str) -> None:
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(ENV_ID, k=8, cache_dir=cache_dir, observation_mode=mode)
        # Rendering is checked below (human mode warns on a machine without a display).
        check_env(env.unwrapped, skip_render_check=True)
        env.close()


@pytest.mark.parametrize("mode", ["vector", "dict"])
def test_sb3_check_env_passes_without_warnings(cache_dir: Path, mode: str) -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(ENV_ID, k=8, cache_dir=cache_dir, observation_mode=mode)
        check_env(env)
        env.close()


# --------------------------------------------------------------------------- vector use, pickling


def test_sync_vector_envs(cache_dir: Path) -> None:
    fns = [partial(make, cache_dir) for _ in range(2)]
    venv = gym.vector.SyncVectorEnv(fns)
    obs, info = venv.reset(seed=[0, 1])
    assert obs.shape == (2, venv.single_observation_space.shape[0])  # type: ignore[index]
    assert not np.array_equal(obs[0], obs[1])
    for _ in range(40):  # walk has 38 frames: the sub-envs reset themselves
        obs, reward, _, _, info = venv.step(venv.action_space.sample())
    assert obs.shape[0] == 2 and reward.shape == (2,)
    assert info["nodes"].shape == (2, 8) and info["pose"].shape == (2, 20, 3)
    venv.close()
    sb3 = pytest.importorskip("stable_baselines3.common.vec_env")
    dummy = sb3.DummyVecEnv(fns)
    dummy.seed(0)
    obs = dummy.reset()
    ends = 0
    for _ in range(40):
        obs, reward, done, infos = dummy.step(np.zeros((2, 20), np.float32))
        ends += int(done.sum())
        for i in np.flatnonzero(done):
            assert infos[i]["terminal_observation"].shape == obs.shape[1:]
    assert obs.shape[0] == 2 and ends == 2
    dummy.close()


def test_async_and_subprocess_vector_envs(cache_dir: Path) -> None:
    fns = [partial(make, cache_dir) for _ in range(2)]
    context = "fork" if "fork" in multiprocessing.get_all_start_methods() else None
    venv = gym.vector.AsyncVectorEnv(fns, context=context)
    obs, _ = venv.reset(seed=[0, 1])
    sync = gym.vector.SyncVectorEnv(fns)
    expected, _ = sync.reset(seed=[0, 1])
    np.testing.assert_array_equal(obs, expected)
    actions = np.zeros((2, 20), np.float32)
    np.testing.assert_array_equal(venv.step(actions)[0], sync.step(actions)[0])
    venv.close()
    sync.close()
    sb3 = pytest.importorskip("stable_baselines3.common.vec_env")
    sub = sb3.SubprocVecEnv(fns, start_method=context)
    obs = sub.reset()
    obs, reward, _, _ = sub.step(actions)
    assert obs.shape == expected.shape and np.all(np.isfinite(reward))
    sub.close()


def test_pickle_and_deepcopy_recreate_the_env(cache_dir: Path) -> None:
    env = make(cache_dir, k=6, reward_mode="error")
    obs, _ = env.reset(seed=3)
    env.step(np.zeros(20, np.float32))
    for clone in (pickle.loads(pickle.dumps(env)), copy.deepcopy(env)):
        assert clone.candidates == 6 and clone.reward_mode == "error"
        assert clone.problem is None  # state is not carried over: reset first
        clone_obs, _ = clone.reset(seed=3)
        np.testing.assert_array_equal(clone_obs, obs)
        clone.close()
    env.close()


# --------------------------------------------------------------------------- rendering


def test_rgb_array_rendering(cache_dir: Path) -> None:
    env = make(cache_dir, render_mode="rgb_array")
    env.reset(seed=0)
    before = env.render()
    assert before is not None and before.shape == (320, 640, 3) and before.dtype == np.uint8
    assert (before[:, 320:] < 250).sum() < (before[:, :320] < 250).sum()  # no output yet
    env.step(np.zeros(20, np.float32))
    after = env.render()
    assert after is not None
    right = (after[40:300, 330:] < 200).any(axis=2).sum()
    assert right > 200  # the reconstruction is drawn
    env.close()


def test_human_rendering_without_a_display_warns(cache_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    env = make(cache_dir, render_mode="human")
    with pytest.warns(UserWarning, match="display"):
        env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once only
        env.step(np.zeros(20, np.float32))
        assert env.render() is None
    env.close()
    env.close()  # idempotent


# --------------------------------------------------------------------------- arguments


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"reward_mode": "speed"}, "reward_mode"),
        ({"action_mode": "relative"}, "action_mode"),
        ({"observation_mode": "image"}, "observation_mode"),
        ({"render_mode": "ansi"}, "render_mode"),
        ({"action_scale": 0.0}, "action_scale"),
        ({"latent_dim": 0}, "latent_dim"),
        ({"clips": ("walk", "moonwalk")}, "moonwalk"),
        ({"scenarios": ("front-nowhere",)}, "front-nowhere"),
        ({"recordings": ["x.npz"]}, "not both"),
        ({"energy_weights": (1.0, 2.0)}, "4 or 5 weights"),
        ({"energy_weights": {"speed": 1.0}}, "energy_weights"),
        ({"reconstructor_options": {"k": 3}}, "keyword arguments"),
    ],
)
def test_bad_arguments_are_named(cache_dir: Path, kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make(cache_dir, **kwargs)


def test_energy_weights_reach_the_problem(cache_dir: Path) -> None:
    env = make(cache_dir, energy_weights={"control": 2.0, "motion": 0.0})
    env.reset(seed=0)
    assert env.problem is not None
    assert (env.problem.weights.control, env.problem.weights.motion) == (2.0, 0.0)
    env.close()


def test_float32_energy_reaches_the_env(cache_dir: Path) -> None:
    """``reconstructor_options={"energy_dtype": ...}``: the same actions give the same poses
    (the actions' points do not read the energy) and rewards equal to float32's rounding."""
    actions = np.random.default_rng(2).uniform(-0.3, 0.3, (6, 20)).astype(np.float32)
    poses, rewards = {}, {}
    for dtype in ("float64", "float32"):
        env = make(cache_dir, reconstructor_options={"energy_dtype": dtype})
        env.reset(seed=3)
        steps = [env.step(action) for action in actions]
        assert env.problem is not None and env.problem.energy.dtype == np.dtype(dtype)
        poses[dtype] = np.stack([info["pose"] for *_, info in steps])
        rewards[dtype] = np.array([reward for _, reward, *_ in steps])
        env.close()
    np.testing.assert_array_equal(poses["float32"], poses["float64"])
    np.testing.assert_allclose(rewards["float32"], rewards["float64"], rtol=1e-5)
