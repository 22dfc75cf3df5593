"""fpg-gym: Kinect pose reconstruction (Shum 2013, Filtered Pose Graph 2016) as a Gymnasium env.

Importing the package costs gymnasium's import (about 70 ms beyond numpy); the env module, the
graph and pybullet load on use. The optimiser layer (:mod:`optimizers`) does not import it.
Importing it registers the environment ``fpg_gym/KinectPose-v0`` (:mod:`fpg_gym.env`) with
Gymnasium, so that ``gymnasium.make("fpg_gym/KinectPose-v0")`` works after ``import fpg_gym``, and
its vector mode (:mod:`fpg_gym.vector_env`), so that ``gymnasium.make_vec("fpg_gym/KinectPose-v0",
num_envs=N)`` gives N envs in one process whose frame searches run batched.
"""

from __future__ import annotations

from gymnasium.envs import registration as _registration

__version__ = "0.1.0"

__all__ = ["__version__"]


def _register_envs() -> None:
    """Register ``fpg_gym/KinectPose-v0`` (once; the env modules themselves load on ``make``).

    ``gym.make`` builds :class:`fpg_gym.env.KinectPoseEnv`; ``gym.make_vec`` builds
    :class:`fpg_gym.vector_env.KinectPoseVectorEnv` (its vector entry point), or Gymnasium's
    own ``SyncVectorEnv``/``AsyncVectorEnv`` with ``vectorization_mode="sync"``/``"async"``.
    """
    if "fpg_gym/KinectPose-v0" not in _registration.registry:
        _registration.register(
            id="fpg_gym/KinectPose-v0",
            entry_point="fpg_gym.env:KinectPoseEnv",
            vector_entry_point="fpg_gym.vector_env:KinectPoseVectorEnv",
        )


_register_envs()
