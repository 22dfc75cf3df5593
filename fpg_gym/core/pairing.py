"""Pair a sensor stream with a simultaneous reference recording: time lag and rigid transform.

Two systems that recorded the same motion at the same time (a Kinect and a Vicon) are segmented
separately and measure in different spaces. :func:`pair_session` finds, for every repetition of
a session (one camera placement), the lag that best aligns the reference with the sensor, and
one rigid transform (rotation and translation, no scale: both sides are in metres) for the whole
session that maps the reference into the sensor's space (Kabsch on every paired frame). Lags and
transform are refined alternately.

Examples
--------
>>> import numpy as np
>>> from fpg_gym.core.pairing import kabsch, apply_rigid
>>> rng = np.random.default_rng(0)
>>> points = rng.normal(size=(50, 3))
>>> rotation, shift = kabsch(points, points + [1.0, 2.0, 3.0])
>>> bool(np.allclose(apply_rigid(points, rotation, shift), points + [1.0, 2.0, 3.0]))
True
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["SessionPairing", "apply_rigid", "best_lag", "kabsch", "overlap", "pair_session"]


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rigid transform ``target ≈ source @ R.T + t`` of least squared error (Kabsch).

    Parameters
    ----------
    source, target : ndarray, shape (..., 3)
        Paired points (any leading shape, the same for both).

    Returns
    -------
    rotation : ndarray, shape (3, 3)
        A proper rotation (determinant +1).
    shift : ndarray, shape (3,)
    """
    a = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(target, dtype=np.float64).reshape(-1, 3)
    if a.shape != b.shape or len(a) < 3:
        raise ValueError(
            f"kabsch: expected two equal arrays of >= 3 points, got {a.shape}, {b.shape}"
        )
    mean_a, mean_b = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - mean_a).T @ (b - mean_b))
    sign = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return rotation, mean_b - mean_a @ rotation.T


def apply_rigid(points: np.ndarray, rotation: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``points @ rotation.T + shift`` for points ``(..., 3)``."""
    return np.asarray(points, dtype=np.float64) @ np.asarray(rotation).T + np.asarray(shift)


def overlap(sensor_frames: int, reference_frames: int, lag: int) -> tuple[int, int]:
    """Sensor frames ``[start, stop)`` that have a reference frame ``i + lag``."""
    start = max(0, -lag)
    stop = min(sensor_frames, reference_frames - lag)
    return start, max(start, stop)


def best_lag(
    sensor: np.ndarray,
    reference: np.ndarray,
    lags: Sequence[int],
    *,
    min_overlap: float = 0.6,
) -> tuple[int, float]:
    """The lag (reference frame ``i + lag`` for sensor frame ``i``) of least mean joint distance.

    Parameters
    ----------
    sensor, reference : ndarray, shape (T, J, 3) and (U, J, 3)
        Both in the same space.
    lags : sequence of int
        Candidate lags.
    min_overlap : float
        A lag is considered only when it pairs at least this share of the shorter stream.

    Returns
    -------
    lag : int
    distance : float
        Mean joint distance (metres) at that lag; inf when no lag has enough overlap.
    """
    need = max(1, int(np.ceil(min_overlap * min(len(sensor), len(reference)))))
    best, best_distance = 0, float("inf")
    for lag in lags:
        start, stop = overlap(len(sensor), len(reference), int(lag))
        if stop - start < need:
            continue
        distance = float(
            np.linalg.norm(sensor[start:stop] - reference[start + lag : stop + lag], axis=-1).mean()
        )
        if distance < best_distance:
            best, best_distance = int(lag), distance
    return best, best_distance


@dataclass(frozen=True)
class SessionPairing:
    """The pairing of one session.

    Attributes
    ----------
    rotation, shift : ndarray
        Reference space -> sensor space: ``sensor ≈ reference @ rotation.T + shift``.
    lags : list of int
        Per repetition: reference frame ``i + lag`` pairs with sensor frame ``i``.
    distances : list of float
        Per repetition: mean joint distance (metres) after the transform, over paired frames.
    """

    rotation: np.ndarray
    shift: np.ndarray
    lags: list[int]
    distances: list[float]

    @property
    def mean_distance(self) -> float:
        """Mean over repetitions of :attr:`distances` (the session's alignment error)."""
        return float(np.mean(self.distances))


def pair_session(
    sensors: Sequence[np.ndarray],
    references: Sequence[np.ndarray],
    *,
    max_lag: int = 15,
    iterations: int = 3,
) -> SessionPairing:
    """Lags per repetition and one rigid transform for a session (see the module docstring).

    Parameters
    ----------
    sensors, references : sequences of ndarray, shapes (T_i, J, 3) and (U_i, J, 3)
        Repetitions of one session, at the same frame rate.
    max_lag : int
        Lags from ``-max_lag`` to ``max_lag`` frames are searched.
    iterations : int
        Rounds of (fit the transform on the paired frames, search the lags).
    """
    if len(sensors) != len(references) or not sensors:
        raise ValueError("pair_session: expected as many references as sensor streams (>= 1)")
    lags = [0] * len(sensors)
    lag_range = range(-max_lag, max_lag + 1)
    rotation, shift = np.eye(3), np.zeros(3)
    distances = [float("inf")] * len(sensors)
    for _ in range(max(1, iterations)):
        paired_s, paired_r = [], []
        for sensor, reference, lag in zip(sensors, references, lags, strict=True):
            start, stop = overlap(len(sensor), len(reference), lag)
            paired_s.append(sensor[start:stop])
            paired_r.append(reference[start + lag : stop + lag])
        rotation, shift = kabsch(np.concatenate(paired_r), np.concatenate(paired_s))
        for i, (sensor, reference) in enumerate(zip(sensors, references, strict=True)):
            lags[i], distances[i] = best_lag(
                sensor, apply_rigid(reference, rotation, shift), lag_range
            )
    return SessionPairing(rotation, shift, list(lags), list(distances))
