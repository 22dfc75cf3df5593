"""Per-joint reference filters: what a Kinect user would use instead of pose reconstruction.

=========  ================================================================================
name       method
=========  ================================================================================
``raw``    the input as is (:class:`RawFilter`)
``holt``   the Kinect SDK joint filter, Holt double-exponential smoothing with jitter and
           max-deviation clamps (:class:`HoltFilter`; presets in :data:`HOLT_PRESETS`)
``kalman`` constant-velocity Kalman filter per joint (:class:`KalmanFilter`)
``one-euro`` speed-adaptive low-pass filter per joint (:class:`OneEuroFilter`, Casiez et al.
           2012; used as the reconstruction's optional output stage)
=========  ================================================================================

Make one by name with :func:`make_filter`; a preset may follow the name after a colon, as on the
command line (``"holt:very-smoothed"``). Every filter has ``reset()``, ``update(positions (20, 3),
states (20,), timestamp)`` and ``filter_sequence(positions (T, 20, 3), states (T, 20),
timestamps (T,))``; states are the Kinect values 0 not tracked, 1 inferred, 2 tracked and
timestamps are seconds.

Examples
--------
>>> import numpy as np
>>> from fpg_gym.filters import make_filter
>>> holt = make_filter("holt:smoothed")
>>> clip = np.ones((10, 20, 3), dtype=np.float32)
>>> holt.filter_sequence(clip).shape
(10, 20, 3)
"""

from __future__ import annotations

from typing import Any, Final

from fpg_gym.filters.base import (
    DEFAULT_DT,
    INFERRED,
    NOT_TRACKED,
    TRACKED,
    JointFilter,
    RawFilter,
)
from fpg_gym.filters.holt import HOLT_PRESETS, HoltFilter, HoltParams, holt_preset
from fpg_gym.filters.kalman import (
    DEFAULT_KALMAN,
    KALMAN_PRESETS,
    KalmanFilter,
    KalmanParams,
    fit_noise,
)
from fpg_gym.filters.one_euro import ONE_EURO_PRESETS, OneEuroFilter, OneEuroParams

_FILTERS: Final[dict[str, type[JointFilter]]] = {
    "raw": RawFilter,
    "holt": HoltFilter,
    "kalman": KalmanFilter,
    "one-euro": OneEuroFilter,
}

#: Preset names per filter (``make_filter(name, preset=...)`` or ``"name:preset"``).
PRESETS: Final[dict[str, tuple[str, ...]]] = {
    "raw": (),
    "holt": tuple(HOLT_PRESETS),
    "kalman": tuple(KALMAN_PRESETS),
    "one-euro": tuple(ONE_EURO_PRESETS),
}


def available_filters() -> tuple[str, ...]:
    """Names accepted by :func:`make_filter`: ``("raw", "holt", "kalman")``."""
    return tuple(_FILTERS)


def available_presets(name: str) -> tuple[str, ...]:
    """Preset names of the filter ``name`` (empty for ``raw``)."""
    return PRESETS[_check_name(name)]


def _check_name(name: str) -> str:
    key = name.strip().lower()
    if key not in _FILTERS:
        raise ValueError(f"filter: unknown filter {name!r}; expected one of {list(_FILTERS)}")
    return key


def make_filter(name: str, **params: Any) -> JointFilter:
    """A new filter by name.

    Parameters
    ----------
    name
        ``"raw"``, ``"holt"`` or ``"kalman"``, optionally followed by ``":preset"``
        (``"holt:default"``, ``"holt:smoothed"``, ``"holt:very-smoothed"``, ``"holt:sample"``,
        ``"holt:none"``; ``"kalman:default"``, ``"kalman:fast"``).
    **params
        Parameters of the filter: ``preset`` and the :class:`HoltParams` fields for ``holt``,
        the :class:`KalmanParams` fields for ``kalman``; ``raw`` takes none.

    Returns
    -------
    JointFilter
        A fresh filter (its state is reset).

    Raises
    ------
    ValueError
        Unknown name or preset, or a parameter out of range.
    TypeError
        A parameter the filter does not have.
    """
    base, _, preset = name.partition(":")
    key = _check_name(base)
    if preset:
        if "preset" in params:
            raise ValueError(
                f"filter: preset given twice ({name!r} and preset={params['preset']!r})"
            )
        params = {**params, "preset": preset}
    if key == "raw":
        if "preset" in params:
            raise ValueError(f"preset: the raw filter has no presets, got {params['preset']!r}")
        if params:
            raise TypeError(f"raw filter takes no parameters, got {sorted(params)}")
    return _FILTERS[key](**params)


__all__ = [
    "DEFAULT_DT",
    "DEFAULT_KALMAN",
    "HOLT_PRESETS",
    "INFERRED",
    "KALMAN_PRESETS",
    "NOT_TRACKED",
    "ONE_EURO_PRESETS",
    "PRESETS",
    "TRACKED",
    "HoltFilter",
    "HoltParams",
    "JointFilter",
    "KalmanFilter",
    "KalmanParams",
    "OneEuroFilter",
    "OneEuroParams",
    "RawFilter",
    "available_filters",
    "available_presets",
    "fit_noise",
    "holt_preset",
    "make_filter",
]
