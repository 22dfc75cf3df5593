"""The sensor fusion compiled (numba): the sensor's trust and the fused bones around numpy's
exponential, joint frames, product and solve; imported only when ``fpg-gym[fast]`` is
installed.

The numpy code of :class:`~fpg_gym.reconstruct.fusion.SensorTrust` and
:class:`~fpg_gym.reconstruct.fusion.SensorFusion` is their definition; the tests compare them
to the bit. Module-level functions so that numba's disk cache (``cache=True``) finds them in a
new process.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core.compiled import JIT_OPTIONS
from fpg_gym.core.compiled_poses import (
    bone_lengths_pose,
    scalar_maximum,
    scalar_minimum,
    unit_and_norm,
)

__all__ = [
    "fusion_bone_terms",
    "fusion_bones",
    "held_directions",
    "sensor_trust",
    "trust_exponents",
]


@numba.njit(**JIT_OPTIONS)
def trust_exponents(states, run_start, timestamp, flicker, half_life, inferred_state):
    """:class:`SensorTrust <fpg_gym.reconstruct.fusion.SensorTrust>`'s inferred runs: each
    inferred joint's run start (``run_start`` ``(20,)`` updated in place, NaN out of a run) and
    the exponent of its decay, ``max(lost - flicker, 0) / half_life`` (the caller raises 0.5 to
    it: numpy's power)."""
    joints = states.shape[0]
    exponents = np.empty(joints)
    for j in range(joints):
        lost = 0.0
        if states[j] == inferred_state:
            if np.isnan(run_start[j]):
                run_start[j] = timestamp
            lost = timestamp - run_start[j]
        else:
            run_start[j] = np.nan
        exponents[j] = scalar_maximum(lost - flicker, 0.0) / half_life
    return exponents


@numba.njit(**JIT_OPTIONS)
def sensor_trust(
    positions,
    states,
    decay,
    ever_tracked,
    length_sum,
    length_count,
    tolerance,
    span,
    tracked_state,
    inferred_state,
    bones,
    order,
    parents,
):
    """:meth:`SensorTrust.update <fpg_gym.reconstruct.fusion.SensorTrust.update>` after the
    decay of the inferred joints (``decay`` ``(20,)``): the trust ``(20,)`` of one pose
    ``(20, 3)`` float64, the state (``ever_tracked``, the trusted lengths' sums and counts)
    updated in place; ``order`` the joints by depth, root first (the numpy code's operations)."""
    joints = states.shape[0]
    trust = np.empty(joints)
    for j in range(joints):
        ever_tracked[j] = ever_tracked[j] or states[j] == tracked_state
        if states[j] == tracked_state:
            trust[j] = 1.0
        elif states[j] == inferred_state:
            trust[j] = decay[j] if ever_tracked[j] else 1.0
        else:
            trust[j] = 0.0
    lengths = bone_lengths_pose(positions, bones)
    for b in range(bones.shape[0]):
        reference = length_sum[b] / length_count[b] if length_count[b] > 0 else lengths[b]
        deviation = abs(lengths[b] - reference) / scalar_maximum(reference, 1e-3)
        bone_trust = 1.0 - scalar_minimum(scalar_maximum((deviation - tolerance) / span, 0.0), 1.0)
        child = bones[b, 1]
        trust[child] = scalar_minimum(trust[child], bone_trust)
    for k in range(order.shape[0]):  # an inferred joint hangs off its parent
        j = order[k]
        if parents[j] >= 0 and states[j] == inferred_state:
            trust[j] = scalar_minimum(trust[j], trust[parents[j]])
    for b in range(bones.shape[0]):
        good = trust[bones[b, 0]] > 0.9 and trust[bones[b, 1]] > 0.9
        length_sum[b] += lengths[b] if good else 0.0
        length_count[b] += 1.0 if good else 0.0
    return trust


@numba.njit(**JIT_OPTIONS)
def fusion_bone_terms(
    trust, database, sensor_bones, bones, length_sum, length_count, disagreement, keep
):
    """:meth:`SensorFusion.update <fpg_gym.reconstruct.fusion.SensorFusion.update>` up to the
    settling of the lengths (the numpy code's operations): each bone's trust ``(19,)``, the
    lengths' estimate ``(19,)``, the database's and the sensor's unit bones ``(19, 3)``; the
    seen lengths' sums and counts and the running ``disagreement`` (``keep`` its decay over
    the step) updated in place."""
    count = bones.shape[0]
    bone_trust = np.empty(count)
    estimate = np.empty(count)
    database_units = np.empty((count, 3))
    sensor_units = np.empty((count, 3))
    for b in range(count):
        parent, child = bones[b, 0], bones[b, 1]
        bone_trust[b] = scalar_minimum(trust[parent], trust[child])
        seen = bone_trust[b] > 0.9
        database_norm, d0, d1, d2 = unit_and_norm(
            database[child, 0] - database[parent, 0],
            database[child, 1] - database[parent, 1],
            database[child, 2] - database[parent, 2],
        )
        sensor_norm, s0, s1, s2 = unit_and_norm(
            sensor_bones[b, 0], sensor_bones[b, 1], sensor_bones[b, 2]
        )
        database_units[b, 0], database_units[b, 1], database_units[b, 2] = d0, d1, d2
        sensor_units[b, 0], sensor_units[b, 1], sensor_units[b, 2] = s0, s1, s2
        length_sum[b] += sensor_norm if seen else 0.0
        length_count[b] += 1.0 if seen else 0.0
        if length_count[b] > 0:
            estimate[b] = length_sum[b] / scalar_maximum(length_count[b], 1.0)
        else:
            estimate[b] = database_norm
        gap = np.sqrt(((d0 - s0) * (d0 - s0) + (d1 - s1) * (d1 - s1)) + (d2 - s2) * (d2 - s2))
        if np.isnan(disagreement[b]):
            mixed = gap
        else:
            mixed = keep * disagreement[b] + (1.0 - keep) * gap
        if seen:
            disagreement[b] = mixed
    return bone_trust, estimate, database_units, sensor_units


@numba.njit(**JIT_OPTIONS)
def fusion_bones(parent_frames, held, database_units, sensor_units, share, bone_trust, lengths):
    """:meth:`SensorFusion.update <fpg_gym.reconstruct.fusion.SensorFusion.update>`'s bone
    vectors ``V(b)`` ``(19, 3)`` (the numpy code's operations): the ``held`` directions
    turned by their ``parent_frames`` ``(19, 3, 3)`` (``np.einsum``'s order of the sum), the
    database's where none is held, mixed by ``share`` into the lost bone, and the sensor's
    and the lost bone at ``lengths``, weighted by ``bone_trust``."""
    count = held.shape[0]
    out = np.empty((count, 3))
    turned = np.empty(3)
    for b in range(count):
        for i in range(3):
            value = (
                parent_frames[b, i, 0] * held[b, 0] + parent_frames[b, i, 2] * held[b, 2]
            ) + parent_frames[b, i, 1] * held[b, 1]
            turned[i] = database_units[b, i] if np.isnan(value) else value
        l0 = share[b] * database_units[b, 0] + (1.0 - share[b]) * turned[0]
        l1 = share[b] * database_units[b, 1] + (1.0 - share[b]) * turned[1]
        l2 = share[b] * database_units[b, 2] + (1.0 - share[b]) * turned[2]
        _, l0, l1, l2 = unit_and_norm(l0, l1, l2)
        weight = bone_trust[b]
        out[b, 0] = weight * (sensor_units[b, 0] * lengths[b]) + (1.0 - weight) * (l0 * lengths[b])
        out[b, 1] = weight * (sensor_units[b, 1] * lengths[b]) + (1.0 - weight) * (l1 * lengths[b])
        out[b, 2] = weight * (sensor_units[b, 2] * lengths[b]) + (1.0 - weight) * (l2 * lengths[b])
    return out


@numba.njit(**JIT_OPTIONS)
def held_directions(pose, parent_frames, bones, bone_trust, held):
    """:meth:`SensorFusion.update <fpg_gym.reconstruct.fusion.SensorFusion.update>`'s memory
    of each seen bone's unit direction in its parent's frame ``(19, 3, 3)`` (``np.einsum``'s
    order of the sum), written into ``held`` ``(19, 3)``."""
    for b in range(bones.shape[0]):
        if not bone_trust[b] > 0.9:
            continue
        parent, child = bones[b, 0], bones[b, 1]
        _, u0, u1, u2 = unit_and_norm(
            pose[child, 0] - pose[parent, 0],
            pose[child, 1] - pose[parent, 1],
            pose[child, 2] - pose[parent, 2],
        )
        for i in range(3):
            held[b, i] = (
                parent_frames[b, 0, i] * u0 + parent_frames[b, 1, i] * u1
            ) + parent_frames[b, 2, i] * u2
