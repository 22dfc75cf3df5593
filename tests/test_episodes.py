"""run_episode with optimisers, policies and callables; measure_env_throughput."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import fpg_gym  # noqa: F401  (registers the env)
from fpg_gym.env import ENV_ID, KinectPoseEnv
from fpg_gym.episodes import EpisodeResult, measure_env_throughput, run_episode
from fpg_gym.reconstruct import Reconstructor, TemporalConfig

EPISODE = {"clip": "walk", "scenario": "front-many", "seed": 3}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fpg-cache")


def make(cache_dir: Path, **kwargs: Any) -> KinectPoseEnv:
    options: dict[str, Any] = {
        "k": 8,
        "clips": ("walk",),
        "scenarios": ("front-many",),
        "ragdoll": False,
        "reward_mode": "error",
        "cache_dir": cache_dir,
    }
    options.update(kwargs)
    return KinectPoseEnv(**options)


class ZeroPolicy:
    """Stands in for an SB3 model: ``predict`` returns the zero action."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.calls: list[bool] = []

    def predict(self, obs: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, None]:
        self.calls.append(deterministic)
        return np.zeros(self.size, np.float32), None


@pytest.mark.parametrize("optimizer", ["none", "local-search"])
def test_optimiser_episode_equals_the_reconstructor(cache_dir: Path, optimizer: str) -> None:
    env = make(cache_dir)
    result = run_episode(env, optimizer, seed=4, options=EPISODE)
    recording = env.recording
    assert recording is not None and result.steps == recording.num_frames
    assert result.terminated and not result.truncated and result.agent == optimizer
    # The env's per-frame problem: the papers' energy, no output stage (issue 15).
    reference = Reconstructor(env.graph, k=8, temporal=TemporalConfig.off()).reconstruct(
        recording, optimizer, rng=4
    )
    np.testing.assert_allclose(result.poses, reference.poses, atol=1e-6)
    np.testing.assert_allclose(
        result.energies, [r.energy for r in reference.records], rtol=1e-9, atol=1e-12
    )
    assert np.all(result.evaluations == [r.evaluations for r in reference.records])
    env.close()


class ClipWatch(gym.Wrapper[Any, Any, Any, Any]):
    """Records, at every step, the env's ``clip_actions`` and the kind of action it is given."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.seen: list[tuple[bool, str]] = []

    def step(self, action: Any) -> Any:
        self.seen.append((self.env.unwrapped.clip_actions, type(action).__name__))  # type: ignore[attr-defined]
        return self.env.step(action)


def test_optimiser_steps_exact_actions_without_touching_clip_actions(cache_dir: Path) -> None:
    env = ClipWatch(make(cache_dir))
    result = run_episode(env, "local-search", seed=4, options=EPISODE, max_steps=6)
    assert result.steps == 6
    # clip_actions stays True all along; the exact point travels in the action itself.
    assert env.seen == [(True, "ExactAction")] * 6
    env.close()


def test_search_lowers_the_energy_and_policies_and_callables_act(cache_dir: Path) -> None:
    env = make(cache_dir)
    searched = run_episode(env, "local-search", seed=0, options=EPISODE)
    policy = ZeroPolicy(20)
    zero = run_episode(env, policy, seed=0, options=EPISODE)
    assert policy.calls and all(policy.calls)  # deterministic=True by default
    baseline = run_episode(env, "none", seed=0, options=EPISODE)
    # The zero action in delta mode is x0: the same reconstruction as no search.
    np.testing.assert_array_equal(zero.poses, baseline.poses)
    assert zero.agent == "ZeroPolicy" and np.all(zero.evaluations == 0)
    assert np.mean(searched.energies) < np.mean(baseline.energies)
    assert np.all(searched.evaluations > 0) and np.all(searched.evaluations <= 2000)
    sampled = run_episode(env, lambda obs: env.action_space.sample(), seed=0, max_steps=5)
    assert sampled.steps == 5 and not sampled.terminated
    summary = searched.summary()
    assert summary["mean_error"] == pytest.approx(float(np.mean(searched.frame_errors)))  # type: ignore[arg-type]
    assert summary["steps"] == searched.steps and summary["frames_per_second"] > 0
    raw = searched.raw_frame_errors
    assert raw is not None and raw.shape == (searched.steps,)
    assert summary["raw_mean_error"] == pytest.approx(float(np.mean(raw)))
    assert summary["raw_err02"] == pytest.approx(float(np.mean(raw >= 0.2)))  # Err0.2
    env.close()


def test_wrapped_env_and_infos(cache_dir: Path) -> None:
    env = gym.make(
        ENV_ID,
        k=8,
        clips=("walk",),
        scenarios=("front-many",),
        ragdoll=False,
        reward_mode="error",
        cache_dir=cache_dir,
        max_episode_steps=6,
    )
    result = run_episode(env, "random-search", seed=1, keep_infos=True)
    assert isinstance(result, EpisodeResult)
    assert result.steps == 6 and result.truncated and len(result.infos) == 6
    assert result.infos[-1]["frame"] == 5
    np.testing.assert_array_equal(result.rewards, [-i["frame_error"] for i in result.infos])
    env.close()


def test_energy_only_episode_has_no_errors(cache_dir: Path) -> None:
    env = make(cache_dir, reward_mode="energy")
    result = run_episode(env, "none", seed=2, max_steps=4)
    assert result.frame_errors is not None  # simulated: ground truth exists
    np.testing.assert_allclose(result.rewards, -result.energies)
    env.close()


def test_bad_agents_are_rejected(cache_dir: Path) -> None:
    from optimizers import OptimizerNotFound

    env = make(cache_dir)
    with pytest.raises(OptimizerNotFound, match="available"):
        run_episode(env, "gradient-descent")
    with pytest.raises(TypeError, match="agent"):
        run_episode(env, 42)
    env.close()


def test_measure_env_throughput(cache_dir: Path) -> None:
    report = measure_env_throughput(
        steps=45, ragdoll=True, env_kwargs={"k": 8, "clips": ("walk",), "cache_dir": cache_dir}
    )
    assert report["steps"] == 45 and report["resets"] == 1  # walk has 38 frames
    assert report["steps_per_second"] > 0
    assert report["step_only_per_second"] >= report["steps_per_second"]
    assert report["stage_ms"]["ragdoll"] > 0 and report["ragdoll_builds"] >= 2
    assert report["observation_size"] == 344 + 65 * 20 + 8 * 20 + 2 * 8


def test_method_names_as_agents(cache_dir: Path) -> None:
    """Issue 11: reference filters and pipeline method names run through run_episode."""
    from fpg_gym.core import metrics
    from fpg_gym.filters import make_filter

    env = make(cache_dir)
    holt = run_episode(env, "holt:smoothed", seed=4, options=EPISODE, max_steps=20)
    recording = env.recording
    assert recording is not None and recording.ground_truth is not None
    expected = make_filter("holt:smoothed").filter_sequence(
        recording.positions[:20], recording.states[:20], recording.timestamps[:20]
    )
    np.testing.assert_allclose(holt.poses, expected, atol=1e-6)
    assert holt.frame_errors is not None
    np.testing.assert_allclose(
        holt.frame_errors, metrics.frame_error(recording.ground_truth[:20], expected), atol=1e-6
    )
    assert holt.truncated and np.isnan(holt.rewards).all()

    by_method = run_episode(env, "fpg:none", seed=4, options=EPISODE)
    by_optimizer = run_episode(env, "none", seed=4, options=EPISODE)
    np.testing.assert_array_equal(by_method.poses, by_optimizer.poses)
    with pytest.raises(ValueError, match="selector='brute-force'"):
        run_episode(env, "shum:none", seed=4, options=EPISODE)
    with pytest.raises(ValueError, match="ragdoll=True"):
        run_episode(env, "fpg:none+ragdoll", seed=4, options=EPISODE)
