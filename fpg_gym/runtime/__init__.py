"""How work runs, beside the core: :mod:`~fpg_gym.runtime.threads` (the per-frame linear algebra
on one BLAS thread) and :mod:`~fpg_gym.runtime.ray_session` (Ray, ``fpg-gym[distributed]``, for
work sent past one machine). This package's ``__init__`` imports nothing.
"""
