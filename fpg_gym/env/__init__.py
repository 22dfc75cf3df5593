"""``KinectPoseEnv``: Kinect pose reconstruction as a Gymnasium env (``fpg_gym/KinectPose-v0``).

One step reconstructs one Kinect frame (Shum 2013, FPG 2016): the action is a point of the
frame's natural posture space, the whitened local PCA of the K poses that the Filtered Pose Graph
selected; the env back-projects it, scores it with the paper's energy, sends it through the PD
ragdoll and prepares the next frame. See :class:`KinectPoseEnv` for the full description.

The env is registered as ``fpg_gym/KinectPose-v0`` when :mod:`fpg_gym` is imported::

    import gymnasium as gym
    import fpg_gym  # noqa: F401  (registers the env)

    env = gym.make("fpg_gym/KinectPose-v0", k=30, reward_mode="error")
    obs, info = env.reset(seed=0, options={"clip": "walk", "scenario": "front-many"})
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

The package: :mod:`.kinect_pose` (the env), :mod:`.settings` (its modes and arguments),
:mod:`.step_types` (:class:`ExactAction`, :class:`StageTimes`), :mod:`.ragdoll` (the ragdoll that
counts); its observation is :mod:`fpg_gym.env_observation`, its episodes
:mod:`fpg_gym.env_episodes`.
"""

from __future__ import annotations

from fpg_gym.env.kinect_pose import ENV_ID, KinectPoseEnv
from fpg_gym.env.settings import ACTION_MODES, OBSERVATION_MODES, REWARD_MODES, EnvSettings
from fpg_gym.env.step_types import ExactAction, StageTimes
from fpg_gym.env_episodes import RESET_OPTIONS

__all__ = [
    "ACTION_MODES",
    "ENV_ID",
    "OBSERVATION_MODES",
    "RESET_OPTIONS",
    "REWARD_MODES",
    "EnvSettings",
    "ExactAction",
    "KinectPoseEnv",
    "StageTimes",
]
