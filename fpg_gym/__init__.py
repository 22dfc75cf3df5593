"""fpg-gym: Kinect pose reconstruction (Shum 2013, Filtered Pose Graph 2016) as a Gymnasium env.

Importing the package is cheap; heavy parts (pybullet, the graph, the environment) load on use.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
