"""The one episode planner (:mod:`fpg_gym.simulate.episodes`): its seeding rule, its order, and
that the env, compare, bench and training simulate the same stream for the same episode."""

from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np
import pytest

from fpg_gym.experiments import bench as bench_module
from fpg_gym.experiments import plan_episodes as plan_compare_episodes
from fpg_gym.io import Clip, load_default_clips
from fpg_gym.simulate import (
    EpisodeSimulator,
    episode_seed,
    get_scenario,
    plan_episode,
    plan_episodes,
    simulate,
    simulate_clips,
    simulate_plan,
    unique_names,
)
from policies.training import simulate_episodes


@pytest.fixture(scope="module")
def clips() -> dict[str, Clip]:
    return {c.name: c for c in load_default_clips(("walk", "kick"))}


def rule(seed: int, *names: str) -> int:
    """The documented rule, written out: SeedSequence([seed, crc32(name), ...]), first word."""
    words = [seed] + [zlib.crc32(name.encode("utf-8")) for name in names]
    return int(np.random.SeedSequence(words).generate_state(1, dtype=np.uint32)[0])


def assert_same_stream(a: object, b: object) -> None:
    for field in ("positions", "states", "ground_truth", "timestamps"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


# --------------------------------------------------------------------------- the rule and the plan


def test_seeding_rule_is_the_documented_one() -> None:
    for seed, clip, scenario in [(0, "walk", "front-many"), (7, "kick", "left45-many")]:
        expected = rule(seed, clip, scenario)
        assert plan_episode(clip, scenario, seed).sim_seed == expected
        assert episode_seed(seed, clip, scenario) == expected
    assert episode_seed(3, "rec") == rule(3, "rec")  # a recording file: its stem alone
    # Every part of the episode matters, and the order of the names too.
    seeds = {
        episode_seed(0, "walk", "front-many"),
        episode_seed(1, "walk", "front-many"),
        episode_seed(0, "kick", "front-many"),
        episode_seed(0, "walk", "left45-many"),
        episode_seed(0, "front-many", "walk"),
    }
    assert len(seeds) == 5
    with pytest.raises(ValueError, match="seed: expected an integer >= 0"):
        episode_seed(-1, "walk")


def test_plan_order_and_independence_of_the_lists() -> None:
    plan = plan_episodes(["walk", "kick"], ["front-many", "left45-many"], [0, 1])
    assert [(e.seed, e.clip, e.scenario) for e in plan] == [
        (seed, clip, scenario)
        for seed in (0, 1)
        for clip in ("walk", "kick")
        for scenario in ("front-many", "left45-many")
    ]
    # Reordering or shortening the lists does not change an episode's seed.
    alone = plan_episodes(["kick"], ["left45-many"], [1])
    assert alone == [e for e in plan if (e.clip, e.scenario, e.seed) == ("kick", "left45-many", 1)]
    assert len({e.sim_seed for e in plan}) == len(plan)


def test_unique_names() -> None:
    assert unique_names(["walk", "kick", "walk", "walk"]) == ["walk", "kick", "walk#1", "walk#2"]


# --------------------------------------------------------------------------- simulating a plan


def test_simulate_plan_is_simulate_with_the_planned_seed(clips: dict[str, Clip]) -> None:
    plan = plan_episodes(["walk", "kick"], ["front-many"], [2])
    recordings = simulate_plan(plan, clips, max_frames=12)
    assert [r.num_frames for r in recordings] == [12, 12]
    for episode, recording in zip(plan, recordings, strict=True):
        expected = simulate(clips[episode.clip], episode.scenario, seed=episode.sim_seed)
        assert_same_stream(recording, expected.head(12))
    with pytest.raises(KeyError, match="dance"):
        simulate_plan(plan_episodes(["dance"], ["front-many"], [0]), clips)


def test_episode_simulator_reuses_one_simulator_per_scenario(clips: dict[str, Clip]) -> None:
    first, second = plan_episodes(["walk", "kick"], ["front-few"], [0])
    with EpisodeSimulator() as simulator:
        simulator.simulate(clips["walk"], first, 5)
        engine = simulator.simulator("front-few")
        again = simulator.simulate(clips["kick"], second, 5)
        assert simulator.simulator("front-few") is engine  # reused, not rebuilt per episode
    # Reuse leaks nothing from one episode into the next.
    assert_same_stream(again, simulate(clips["kick"], "front-few", seed=second.sim_seed).head(5))


def test_episode_simulator_uses_given_scenarios_and_refuses_clashing_names(
    clips: dict[str, Clip],
) -> None:
    base = get_scenario("front-many")
    far = replace(base, distance=3.5)
    episode = plan_episode("walk", "front-many", 0)
    with EpisodeSimulator([far]) as simulator:
        given = simulator.simulate(clips["walk"], episode, 5)
    with EpisodeSimulator() as simulator:
        named = simulator.simulate(clips["walk"], episode, 5)
    # The camera of the given scenario stands 1 m further away from the body.
    depth = float(np.mean(given.ground_truth[..., 2] - named.ground_truth[..., 2]))
    assert depth == pytest.approx(1.0, abs=0.05)
    with pytest.raises(ValueError, match="two different scenarios are named 'front-many'"):
        EpisodeSimulator([base, far])
    EpisodeSimulator([base, "front-many"]).close()  # the same scenario twice is fine


def test_simulate_clips_keeps_same_named_clips_apart(clips: dict[str, Clip]) -> None:
    walk = clips["walk"]
    other = replace(clips["kick"], name="walk")
    recordings = simulate_clips([walk, other], ["front-few"], [0], max_frames=6)
    expected_first = simulate(walk, "front-few", seed=episode_seed(0, "walk", "front-few"))
    expected_second = simulate(other, "front-few", seed=episode_seed(0, "walk#1", "front-few"))
    assert_same_stream(recordings[0], expected_first.head(6))
    assert_same_stream(recordings[1], expected_second.head(6))


# --------------------------------------------------------------------------- one rule everywhere


def test_compare_and_training_use_the_planner(clips: dict[str, Clip]) -> None:
    compared = plan_compare_episodes(["walk", "kick"], ["front-many", "left45-many"], [0, 3])
    planned = plan_episodes(["walk", "kick"], ["front-many", "left45-many"], [0, 3])
    assert [e.planned for e in compared] == planned
    # A recording file: the optimisers' seed is the rule on the user's seed and the file stem.
    files = plan_compare_episodes([], [], [2], ["in/one.npz", "in/two.npz"])
    assert [e.sim_seed for e in files] == [episode_seed(2, "one"), episode_seed(2, "two")]
    trained = simulate_episodes([clips["kick"]], ["left45-many"], [3], max_frames=8)
    episode = plan_episode("kick", "left45-many", 3)
    expected = simulate(clips["kick"], "left45-many", seed=episode.sim_seed).head(8)
    assert_same_stream(trained[0], expected)


def test_bench_episodes_cycle_clips_and_scenarios_with_the_planner_seed() -> None:
    settings = bench_module.BenchSettings(episodes=2, max_frames=7)
    data = bench_module._load_data(settings, progress=False)
    recordings = bench_module._episodes(data, settings)
    assert len(recordings) == 2
    scenarios = bench_module.DEFAULT_EPISODE_SCENARIOS
    for i, recording in enumerate(recordings):
        clip = data.episode_clips[i]
        seed = episode_seed(i, clip.name, scenarios[i])
        assert_same_stream(recording, simulate(clip, scenarios[i], seed=seed).head(7))
