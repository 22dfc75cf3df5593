"""KinectPoseVectorEnv: gym.make_vec's vector mode, SyncVectorEnv semantics, batched search equal
to run_episode alone, argument errors."""

from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import fpg_gym  # noqa: F401  (registers the env and its vector mode)
from fpg_gym.env import ENV_ID, ExactAction, KinectPoseEnv
from fpg_gym.episodes import run_episode
from fpg_gym.reconstruct.kernels import available_kernels
from fpg_gym.vector_env import KinectPoseVectorEnv
from tests.test_env import walk_recording

#: Small and fast: 8 candidates, no ragdoll, 300 evaluations a frame; the session's graph cache.
SMALL: dict[str, Any] = {
    "k": 8,
    "clips": ("walk",),
    "scenarios": ("front-many",),
    "ragdoll": False,
    "max_evaluations": 300,
}


def make_env(recording: Any, wrap: bool = False) -> gym.Env[Any, Any]:
    kwargs = {**SMALL, "clips": None, "scenarios": None, "recordings": [recording]}
    kwargs["reward_mode"] = "error"
    return gym.make(ENV_ID, **kwargs) if wrap else KinectPoseEnv(**kwargs)


def test_make_vec_gives_the_vector_env_and_sync_still_works() -> None:
    venv = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", **SMALL)
    assert isinstance(venv, KinectPoseVectorEnv) and venv.num_envs == 2
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert venv.spec is not None and venv.spec.kwargs["num_envs"] == 2
    assert repr(venv) == f"KinectPoseVectorEnv({ENV_ID}, num_envs=2)"
    bases = venv.bases
    assert bases[0].graph is bases[1].graph  # loaded once, shared
    assert venv.action_space.shape == (2, 20)
    assert venv.observation_space.shape == (2, *venv.single_observation_space.shape)  # type: ignore[misc]
    # Left out, the mode is the vector entry point too.
    default = gym.make_vec(ENV_ID, num_envs=2, **SMALL)
    assert isinstance(default, KinectPoseVectorEnv)
    default.close()

    sync = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="sync", **SMALL)
    assert type(sync) is SyncVectorEnv
    expected, _ = sync.reset(seed=5)
    obs, infos = venv.reset(seed=5)  # seed + i, as SyncVectorEnv
    np.testing.assert_array_equal(obs, expected)
    assert not np.array_equal(obs[0], obs[1])
    assert infos["frame"].tolist() == [0, 0] and infos["_frame"].all()
    actions = np.zeros((2, 20), np.float32)
    for _ in range(2):
        got, expected_step = venv.step(actions), sync.step(actions)
        np.testing.assert_array_equal(got[0], expected_step[0])
        np.testing.assert_array_equal(got[1], expected_step[1])
        np.testing.assert_array_equal(got[4]["pose"], expected_step[4]["pose"])
    assert got[4]["pose"].shape == (2, 20, 3) and got[4]["_pose"].all()
    sync.close()
    venv.close()


@pytest.mark.parametrize("wrap", [False, True])
def test_each_sub_env_equals_its_episode_driven_alone(wrap: bool) -> None:
    # Two streams of different lengths: the shorter one ends first, and the next step resets it
    # (NEXT_STEP autoreset) while the other goes on.
    recordings = [walk_recording(seed=1, frames=4), walk_recording(seed=2, frames=6)]
    seeds = [11, 12]
    venv = KinectPoseVectorEnv(env_fns=[partial(make_env, r, wrap) for r in recordings])
    venv.reset(seed=seeds)
    steps: list[list[dict[str, Any]]] = [[], []]
    rewards: list[list[float]] = [[], []]
    done = np.zeros(2, dtype=bool)
    for t in range(7):
        searching = venv.searching
        actions = venv.search("local-search")
        assert isinstance(actions, ExactAction) and actions.shape == (2, 20)
        if t == 4:  # stream 0 ended at t = 3: not searched, its row ignored by the autoreset
            assert searching.tolist() == [False, True] and not actions[0].any()
        _, reward, terminated, truncated, infos = venv.step(actions)
        for i in range(2):
            if done[i]:
                continue
            assert infos["_pose"][i]
            steps[i].append({key: infos[key][i] for key in ("pose", "energy", "evaluations")})
            rewards[i].append(float(reward[i]))
            done[i] = terminated[i] or truncated[i]
        if t == 4:  # the autoreset step: stream 0 restarted, its info is the reset's
            assert not infos["_pose"][0] and infos["_frame"][0] and infos["frame"][0] == 0
    assert done.all() and [len(s) for s in steps] == [4, 6]
    venv.close()

    bit_equal = "numba" in available_kernels()  # the stacked kernel is the same arithmetic
    for i, (recording, seed) in enumerate(zip(recordings, seeds, strict=True)):
        env = make_env(recording, wrap)
        alone = run_episode(env, "local-search", seed=seed)
        env.close()
        poses = np.stack([s["pose"] for s in steps[i]])
        energies = [s["energy"] for s in steps[i]]
        assert [s["evaluations"] for s in steps[i]] == alone.evaluations.tolist()
        assert alone.evaluations.min() > 0
        if bit_equal:
            np.testing.assert_array_equal(poses, alone.poses)
            np.testing.assert_array_equal(rewards[i], alone.rewards)
            np.testing.assert_array_equal(energies, alone.energies)
        np.testing.assert_allclose(poses, alone.poses, atol=1e-6)
        np.testing.assert_allclose(rewards[i], alone.rewards, rtol=1e-9, atol=1e-12)
    # Another seed searches otherwise: the equality is not vacuous.
    other = run_episode(make_env(recordings[0]), "local-search", seed=99)
    assert np.abs(other.poses - np.stack([s["pose"] for s in steps[0]])).max() > 1e-5


def test_search_generators_and_budget() -> None:
    venv = KinectPoseVectorEnv(2, **SMALL)
    with pytest.raises(RuntimeError, match="call reset"):
        venv.search()
    venv.reset(seed=[3, 3])  # the same stream twice: the same seed gives the same search
    first = venv.search("random-search")
    assert np.array_equal(first[0], first[1])
    # Given generators are used instead of the env's own (and seeds start new ones each call).
    again = venv.search("random-search", rngs=[np.random.default_rng(3), 3])
    np.testing.assert_array_equal(again, first)
    assert not np.array_equal(venv.search("random-search"), first)  # the own ones went on

    # The budget: each env's max_evaluations (300), or the argument.
    def spent() -> np.ndarray:
        return np.array([p.evaluations for p in venv.problems if p is not None])

    before = spent()
    venv.search("local-search", max_evaluations=40)
    assert (spent() - before).tolist() == [40, 40]
    before = spent()
    venv.search("local-search")
    assert (spent() - before).tolist() == [300, 300]
    venv.close()


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="num_envs"):
        KinectPoseVectorEnv(0, **SMALL)
    fns = [partial(KinectPoseEnv, **SMALL)]
    with pytest.raises(ValueError, match="env_kwargs"):
        KinectPoseVectorEnv(env_fns=fns, k=8)
    with pytest.raises(ValueError, match="num_envs"):
        KinectPoseVectorEnv(2, env_fns=fns)
    with pytest.raises(ValueError, match="env_fns"):
        KinectPoseVectorEnv(env_fns=[])
    with pytest.raises(TypeError, match=r"env_fns\[0\]"):
        KinectPoseVectorEnv(env_fns=[partial(gym.make, "CartPole-v1")])
    venv = KinectPoseVectorEnv(2, **SMALL)
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=[1, 2, 3])
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="actions"):
        venv.step(np.zeros((3, 20), np.float32))
    with pytest.raises(ValueError, match="rngs"):
        venv.search(rngs=[1])
    with pytest.raises(ValueError, match="rngs"):
        venv.search(rngs=1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_evaluations"):
        venv.search(max_evaluations=-1)
    with pytest.raises(ValueError, match="optimizer"):
        venv.search(optimizer=42)  # type: ignore[arg-type]
    venv.close()


def test_same_step_autoreset_and_reset_mask() -> None:
    recordings = [walk_recording(seed=1, frames=2), walk_recording(seed=2, frames=3)]
    venv = KinectPoseVectorEnv(
        env_fns=[partial(make_env, r) for r in recordings], autoreset_mode="SameStep"
    )
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    venv.reset(seed=0)
    venv.step(venv.search("none"))
    _, _, terminated, _, infos = venv.step(venv.search("none"))
    assert terminated.tolist() == [True, False] and infos["_final_obs"].tolist() == [True, False]
    assert venv.searching.all()  # stream 0 already started over
    venv.close()

    venv = KinectPoseVectorEnv(
        env_fns=[partial(make_env, r) for r in recordings], autoreset_mode="Disabled"
    )
    venv.reset(seed=0)
    for _ in range(2):
        _, _, terminated, _, _ = venv.step(venv.search("none"))
    assert terminated.tolist() == [True, False] and venv.searching.tolist() == [False, True]
    venv.reset(options={"reset_mask": np.array([True, False])})
    assert venv.searching.all()
    venv.close()
