"""The ragdoll's safeguards: the glide toward a teleported target and the divergence checks.

Both are per-frame arithmetic of :class:`fpg_gym.physics.ragdoll.Ragdoll.track` (the ragdoll's
docstring describes them); neither calls pybullet.
"""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np

__all__ = ["divergence", "glide"]


def glide(
    offset: np.ndarray,
    velocity: np.ndarray,
    *,
    dt: float,
    recovery_frequency: float,
    acceleration: float,
) -> tuple[np.ndarray, np.ndarray]:
    """One frame (``dt`` s) of the glide that closes a teleport's root ``offset`` (m).

    The offset decays at a rate of ``recovery_frequency`` (1/s) but changes its ``velocity``
    (m/s) by at most ``acceleration × dt``; returns the new offset and velocity (both zero once
    the offset is under 0.1 mm).
    """
    distance = float(np.sqrt(offset @ offset))
    if distance > 0.0:
        # Approach speed: exponential near the end, never faster than the speed from which
        # half the available acceleration can still stop the body in time.
        speed = min(recovery_frequency * distance, math.sqrt(2.0 * acceleration * distance))
        change = -offset * (speed / distance) - velocity
        limit = acceleration * dt
        norm = float(np.sqrt(change @ change))
        if norm > limit:
            change *= limit / norm
        velocity = velocity + change
        offset = offset + dt * velocity
        if distance < 1e-4:
            offset = np.zeros(3)
            velocity = np.zeros(3)
    return offset, velocity


def divergence(
    output: np.ndarray,
    target: np.ndarray,
    offset: np.ndarray,
    last_output: np.ndarray,
    joint_gap: float,
    *,
    frame_rate: float,
    max_speed: float,
    max_distance: float,
    max_joint_gap: float,
    kernels: ModuleType | None,
) -> str:
    """Why a frame's ``output`` pose counts as a divergence, or "" when it does not: non-finite,
    a joint farther than ``max_distance`` (m) from ``target + offset`` (the goal) or faster than
    ``max_speed`` (m/s) since ``last_output``, or the joints ``joint_gap`` (m) apart, more than
    ``max_joint_gap``. ``kernels``: :mod:`fpg_gym.physics.compiled_ragdoll`, or None for numpy.
    """
    # Distances against the goal (the target shifted by a teleport glide's remaining
    # offset) and the last output.
    if kernels is not None:
        finite, distance, moved = kernels.divergence_measures(output, target, offset, last_output)
    else:
        finite = bool(np.all(np.isfinite(output)))
        distance = float(np.max(np.linalg.norm(output - (target + offset), axis=-1)))
        moved = float(np.max(np.linalg.norm(output - last_output, axis=-1)))
    if not (finite and math.isfinite(joint_gap)):
        return "non-finite joint positions"
    if distance > max_distance:
        return f"a joint is {distance:.3g} m from its target (max_distance {max_distance})"
    if moved * frame_rate > max_speed:
        speed = moved * frame_rate
        return f"a joint moves at {speed:.3g} m/s (max_speed {max_speed})"
    if joint_gap > max_joint_gap:
        return f"joint constraints {joint_gap:.3g} m apart (max_joint_gap {max_joint_gap})"
    return ""
