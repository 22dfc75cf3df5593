"""Kinect simulator: clean mocap clip -> Kinect-like recording with ground truth.

See :mod:`fpg_gym.simulate.simulator` for the steps, :mod:`fpg_gym.simulate.episodes` for the
episode planner and its one seeding rule, :mod:`fpg_gym.simulate.models` for the
error models and their sources, :mod:`fpg_gym.simulate.scenarios` for the named scenarios.

Examples
--------
>>> from fpg_gym.io import load_default_clips
>>> from fpg_gym.simulate import simulate
>>> recording = simulate(load_default_clips()[0], "front-many", seed=1)  # doctest: +SKIP
>>> recording.ground_truth.shape == recording.positions.shape  # doctest: +SKIP
True
"""

from __future__ import annotations

from fpg_gym.simulate.camera import Camera
from fpg_gym.simulate.episodes import (
    EpisodeSimulator,
    PlannedEpisode,
    episode_seed,
    plan_episode,
    plan_episodes,
    simulate_clips,
    simulate_plan,
    unique_names,
)
from fpg_gym.simulate.models import NoiseModel, OcclusionModel
from fpg_gym.simulate.scenarios import SCENARIOS, Scenario, get_scenario, scenario_names
from fpg_gym.simulate.scene import Box, RayCaster, TraceResult
from fpg_gym.simulate.simulator import KinectSimulator, Placement, place, simulate

__all__ = [
    "SCENARIOS",
    "Box",
    "Camera",
    "EpisodeSimulator",
    "KinectSimulator",
    "NoiseModel",
    "OcclusionModel",
    "Placement",
    "PlannedEpisode",
    "RayCaster",
    "Scenario",
    "TraceResult",
    "episode_seed",
    "get_scenario",
    "place",
    "plan_episode",
    "plan_episodes",
    "scenario_names",
    "simulate",
    "simulate_clips",
    "simulate_plan",
    "unique_names",
]
