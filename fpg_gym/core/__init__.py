"""The core every layer builds on (numpy only; numba for the compiled twins).

:mod:`~fpg_gym.core.skeleton` (Kinect-20 joints, bones, mirror pairs), :mod:`~fpg_gym.core.poses`
(Eq. 1 distance, normalise, bone lengths, retarget), :mod:`~fpg_gym.core.rotations`,
:mod:`~fpg_gym.core.metrics` (Eq. 13 error, MPJPE, jitter, lag), :mod:`~fpg_gym.core.statistics`
(bootstrap interval, robust z-scores), :mod:`~fpg_gym.core.errors`,
:mod:`~fpg_gym.core.validation`, :mod:`~fpg_gym.core.seeding` (the one seeding rule),
:mod:`~fpg_gym.core.compiled` (the optional numba kernels) and the small helpers the layers above
share. This package's ``__init__`` imports nothing: import the module you need.
"""
