"""fpg-gym: Kinect pose reconstruction (Shum 2013, Filtered Pose Graph 2016) as a Gymnasium env.

Importing the package is cheap; heavy parts (pybullet, the graph, the environment) load on use.
Importing it registers the environment ``fpg_gym/KinectPose-v0`` (:mod:`fpg_gym.env`) with
Gymnasium, so that ``gymnasium.make("fpg_gym/KinectPose-v0")`` works after ``import fpg_gym``.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]


def _register_envs() -> None:
    """Register ``fpg_gym/KinectPose-v0`` (once; the env module itself loads on ``make``)."""
    from gymnasium.envs.registration import register, registry

    if "fpg_gym/KinectPose-v0" not in registry:
        register(id="fpg_gym/KinectPose-v0", entry_point="fpg_gym.env:KinectPoseEnv")


_register_envs()
