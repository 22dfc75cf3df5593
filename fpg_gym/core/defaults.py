"""Defaults shared by the environment, the demo and the benchmarks on the embedded data.

The embedded default database is the 15 DeepMimic clips in the pybullet wheel
(:data:`fpg_gym.io.DEFAULT_CLIP_NAMES`). Accuracy is only measured on clips the graph was not built
from, so the environment and the demo hold the clips below out of the default graph and simulate
Kinect episodes from them. Each held-out clip keeps a related clip in the graph (walk: run,
punch: spinkick and the dances, kick: spinkick, dance_b: dance_a).
"""

from __future__ import annotations

#: Embedded clips held out of the default graph and used for episodes and evaluation.
DEFAULT_HOLDOUT_CLIPS: tuple[str, ...] = ("walk", "punch", "kick", "dance_b")

#: Simulator scenarios drawn for default episodes (FPG Table 1 style occlusion).
DEFAULT_EPISODE_SCENARIOS: tuple[str, ...] = ("front-many", "left45-many", "right45-many")
