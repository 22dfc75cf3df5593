"""A settling rule for the user's bone lengths: a fast first estimate, then bounded change.

The reliability estimator (:mod:`fpg_gym.reconstruct.reliability`) refines its reference bone
lengths whenever a new calibration frame arrives (the median of the recent calibration frames, or
a scaled prior before the first one). Used as they are, the output's bones change length during
the whole stream (issue 15 measured one bone spanning 62 mm), which a real body never does.

:class:`BoneSettler` sits between that estimate and everything that uses the lengths (candidate
retargeting, ``Ek``, the output's retargeting and the ragdoll, which therefore all see the same
lengths, with or without the ragdoll):

1. **Settling** (the first ``settle_s`` seconds of a stream, 1 s): the lengths follow the
   estimate as it is (fast first estimate).
2. **Settled** (afterwards): each bone may move toward the estimate by at most
   ``max_rate_m_s * dt`` per frame, and its range since the end of settling (largest minus
   smallest length) never exceeds ``max_spread_m`` (4 mm). A user's bones do not grow: a
   later, better calibration can only nudge them.

Every frame's lengths, the end of settling and every later change are reported
(:attr:`BoneSettler.events`, summarised by :meth:`BoneSettler.report`). A stream restart after a
gap keeps the settled lengths (the same user); :meth:`reset` forgets them.

A stage after the reconstruction that moves joints (a definition map, a learned output
correction) changes the lengths again; :class:`OutputLengths` settles them by the same rule: the
output passes unchanged for the first ``settle_s`` seconds while the mean of its lengths is
gathered, then it is retargeted to lengths that start at that mean and follow the running mean
within :class:`BoneSettler`'s bounds (:func:`settled_output_lengths` for whole streams).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.metrics import TIME_TOLERANCE_S

__all__ = ["BoneSettler", "BoneSettlingConfig", "OutputLengths", "settled_output_lengths"]


@dataclass(frozen=True)
class BoneSettlingConfig:
    """Parameters of :class:`BoneSettler`.

    Attributes
    ----------
    enabled : bool
        Apply the rule (True); False passes the estimate through (the papers' behaviour).
    settle_s : float
        Seconds from the stream's start during which the lengths follow the estimate (1.0).
    max_spread_m : float
        Largest range of a bone's length after settling, metres (0.004).
    max_rate_m_s : float
        Largest speed of that change, metres per second (0.002).
    """

    enabled: bool = True
    settle_s: float = 1.0
    max_spread_m: float = 0.004
    max_rate_m_s: float = 0.002

    def __post_init__(self) -> None:
        for name in ("settle_s", "max_spread_m", "max_rate_m_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name}: expected a finite value >= 0, got {value!r}")


class BoneSettler:
    """Applies the settling rule to a stream of bone-length estimates (module docstring).

    Parameters
    ----------
    config : BoneSettlingConfig, optional
    """

    def __init__(self, config: BoneSettlingConfig | None = None) -> None:
        self.config = config or BoneSettlingConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the user: the next frame starts settling again."""
        self._start: float | None = None
        self._last_time: float | None = None
        self._lengths: np.ndarray | None = None
        self._settled: np.ndarray | None = None
        self._low, self._high = np.zeros(skeleton.NUM_BONES), np.zeros(skeleton.NUM_BONES)
        self.settled_at: float | None = None
        self.events: list[dict[str, Any]] = []

    @property
    def lengths(self) -> np.ndarray | None:
        """The current lengths ``(19,)`` (None before the first frame)."""
        return None if self._lengths is None else self._lengths.copy()

    @property
    def settled(self) -> bool:
        """Whether the settling period is over."""
        return self._settled is not None

    def update(self, estimate: np.ndarray, timestamp: float) -> np.ndarray:
        """The lengths to use in the frame at ``timestamp`` (seconds), given the estimate.

        Returns
        -------
        ndarray, shape (19,), float64
        """
        estimate = np.asarray(estimate, dtype=np.float64)
        if estimate.shape != (skeleton.NUM_BONES,):
            raise ValueError(f"estimate: expected shape (19,), got {estimate.shape}")
        timestamp = float(timestamp)
        cfg = self.config
        if not cfg.enabled:
            self._lengths = estimate.copy()
            return estimate.copy()
        if self._start is None or self._lengths is None:
            self._start = timestamp
            self._lengths = estimate.copy()
            self._last_time = timestamp
            return estimate.copy()
        dt = max(timestamp - (self._last_time if self._last_time is not None else timestamp), 0.0)
        self._last_time = timestamp
        if self._settled is None:
            if timestamp - self._start < cfg.settle_s:
                self._lengths = estimate.copy()
                return estimate.copy()
            self._settled = self._lengths.copy()
            self._low, self._high = self._settled.copy(), self._settled.copy()
            self.settled_at = timestamp
            self.events.append(
                {"time_s": timestamp, "kind": "settled", "lengths_m": self._settled.tolist()}
            )
        rate = cfg.max_rate_m_s * dt
        compiled = compiled_module("fpg_gym.reconstruct.compiled_frame")
        if compiled is not None:  # one call, the same arithmetic (low and high in place)
            moved, largest, changed = compiled.settle_lengths(
                estimate, self._lengths, self._low, self._high, rate, cfg.max_spread_m
            )
        else:
            # np.clip's rule, min(max(x, low), high), without its wrapper's cost.
            step = np.minimum(np.maximum(estimate - self._lengths, -rate), rate)
            moved = np.minimum(
                np.maximum(self._lengths + step, self._high - cfg.max_spread_m),
                self._low + cfg.max_spread_m,
            )
            self._low, self._high = np.minimum(self._low, moved), np.maximum(self._high, moved)
            change = np.abs(moved - self._lengths)
            largest = change.max()
            changed = np.flatnonzero(change > 1e-9)
        if len(changed):
            self.events.append(
                {
                    "time_s": timestamp,
                    "kind": "changed",
                    "max_change_mm": float(1000.0 * largest),
                    "bones": changed.tolist(),
                }
            )
        self._lengths = moved
        return moved.copy()

    def report(self) -> dict[str, Any]:
        """When the lengths settled and how much they moved afterwards.

        ``settled_at_s`` (None while settling), ``changes_after_settling`` (frames in which a
        bone moved), ``max_spread_mm`` (largest range of a bone's length since settling),
        ``settled_lengths_m`` and ``lengths_m`` (current).
        """
        spread = None if self._settled is None else float(1000.0 * (self._high - self._low).max())
        return {
            "enabled": self.config.enabled,
            "settled_at_s": self.settled_at,
            "changes_after_settling": sum(1 for e in self.events if e["kind"] == "changed"),
            "max_spread_mm": spread,
            "settled_lengths_m": None if self._settled is None else self._settled.tolist(),
            "lengths_m": None if self._lengths is None else self._lengths.tolist(),
        }


class OutputLengths:
    """The settling rule for an output whose lengths a later stage changed (module docstring).

    Parameters
    ----------
    config : BoneSettlingConfig, optional
        ``settle_s`` and the bounds; disabled: the output passes unchanged.
    """

    def __init__(self, config: BoneSettlingConfig | None = None) -> None:
        self.config = config or BoneSettlingConfig()
        # Settles at once on the mean gathered before it is used.
        self._settler = BoneSettler(replace(self.config, settle_s=0.0))
        self.reset()

    def reset(self) -> None:
        """A new stream: gather its mean afresh."""
        self._settler.reset()
        self._sum = np.zeros(skeleton.NUM_BONES)
        self._count = 0
        self._start: float | None = None

    def lengths(self, lengths: np.ndarray, timestamp: float) -> np.ndarray | None:
        """The lengths ``(19,)`` the frame at ``timestamp`` gets, given its own ``lengths``;
        None while the stream settles (or with the rule disabled): the frame keeps its own."""
        self._sum += lengths
        self._count += 1
        if self._start is None:
            self._start = float(timestamp)
        settling = timestamp - self._start < self.config.settle_s - TIME_TOLERANCE_S
        if not self.config.enabled or settling:
            return None
        return self._settler.update(self._sum / self._count, timestamp)

    def settle(self, pose: np.ndarray, timestamp: float) -> np.ndarray:
        """The pose ``(20, 3)`` with settled lengths (unchanged while settling)."""
        lengths = self.lengths(pose_utils.bone_lengths(pose), timestamp)
        return pose if lengths is None else pose_utils.retarget(pose, lengths)


def settled_output_lengths(
    lengths: np.ndarray,
    streams: np.ndarray,
    timestamps: np.ndarray,
    config: BoneSettlingConfig | None = None,
) -> np.ndarray:
    """:class:`OutputLengths` over whole streams: each frame's settled lengths ``(n, 19)``, NaN
    while its stream settles (the frame keeps its own), for frames' own ``lengths``
    ``(n, 19)``, ``streams`` ``(n,)`` (consecutive frames with the same label are one stream)
    and ``timestamps`` (seconds)."""
    lengths = np.asarray(lengths, dtype=np.float64)
    labels = np.asarray(streams)
    out = np.full_like(lengths, np.nan)
    rule = OutputLengths(config)
    for t in range(len(lengths)):
        if t == 0 or labels[t] != labels[t - 1]:
            rule.reset()
        settled = rule.lengths(lengths[t], float(timestamps[t]))
        if settled is not None:
            out[t] = settled
    return out
