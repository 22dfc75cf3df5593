"""The reliability's frame compiled (numba): Shum's reliability terms up to their two matrix
products, the sorted window of the reference lengths' ratios and their medians, and the
neutral-pose check; imported only when ``fpg-gym[fast]`` is installed.

The numpy code of :class:`~fpg_gym.reconstruct.reliability.ReliabilityEstimator` is their
definition; the tests compare them to the bit. Module-level functions so that numba's disk
cache (``cache=True``) finds them in a new process.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core.compiled import JIT_OPTIONS
from fpg_gym.core.compiled_poses import (
    bone_lengths_pose,
    facing_yaw_pose,
    place_pose,
    scalar_maximum,
    scalar_minimum,
    vector_angles,
)

__all__ = [
    "merge_sorted",
    "neutral_pose",
    "newest_minimum",
    "reliability_frame",
    "remove_sorted",
]


@numba.njit(**JIT_OPTIONS)
def merge_sorted(values, new):
    """The sorted values of ``values`` and ``new`` (both sorted, float64); a value of ``new``
    equal to one of ``values`` goes before it (``np.searchsorted``'s left side)."""
    out = np.empty(values.shape[0] + new.shape[0])
    i = j = 0
    for k in range(out.shape[0]):
        if j < new.shape[0] and (i >= values.shape[0] or new[j] <= values[i]):
            out[k] = new[j]
            j += 1
        else:
            out[k] = values[i]
            i += 1
    return out


@numba.njit(**JIT_OPTIONS)
def remove_sorted(values, old):
    """``values`` (sorted) without one occurrence of each value of ``old`` (sorted; each one
    present)."""
    out = np.empty(max(values.shape[0] - old.shape[0], 0))
    j = k = 0
    for i in range(values.shape[0]):
        if j < old.shape[0] and values[i] == old[j]:
            j += 1
        elif k < out.shape[0]:
            out[k] = values[i]
            k += 1
        else:
            break
    if j != old.shape[0]:
        raise ValueError("remove_sorted: a value to remove is not in the window")
    return out


@numba.njit(**JIT_OPTIONS)
def _median_of(values):
    """The median of sorted finite values (NaN when there are none): the middle value, or the
    mean of the two middle ones (:meth:`SortedWindow.median
    <fpg_gym.reconstruct.reliability.SortedWindow.median>`)."""
    n = values.shape[0]
    if n == 0:
        return np.nan
    middle = n // 2
    if n % 2:
        return values[middle]
    return (values[middle - 1] + values[middle]) / 2.0


@numba.njit(**JIT_OPTIONS)
def _select(values, k):
    """The ``k``-th smallest of ``values`` (float64, no NaN), which are reordered in place so
    that the ``k`` before it are not larger (Hoare's selection: the value ``np.partition``
    finds, in a few lines that compile fast)."""
    low, high = 0, values.shape[0] - 1
    while low < high:
        pivot = values[(low + high) // 2]
        i, j = low, high
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            high = j
        elif k >= i:
            low = i
        else:
            break
    return values[k]


@numba.njit(**JIT_OPTIONS)
def _column_medians(rows, finite_only, out):
    """Per column of ``rows`` ``(n, 19)``: ``np.median(rows, axis=0)`` into ``out`` (NaN where a
    column holds one), or with ``finite_only`` ``np.nanmedian`` of the columns that hold a finite
    value (the others left as they are): the middle value, or the mean of the two middle
    ones."""
    count, width = rows.shape
    column = np.empty(count)
    for b in range(width):
        n = 0
        missing = False
        for i in range(count):
            if np.isfinite(rows[i, b]):
                column[n] = rows[i, b]
                n += 1
            else:
                missing = True
        if finite_only and n == 0:
            continue
        if n == 0 or (missing and not finite_only):
            out[b] = np.nan
            continue
        middle = n // 2
        upper = _select(column[:n], middle)
        if n % 2:
            out[b] = upper
        else:
            lower = column[0]
            for i in range(1, middle):
                lower = max(lower, column[i])
            out[b] = (lower + upper) / 2.0


@numba.njit(**JIT_OPTIONS)
def neutral_pose(
    pose, cos_tolerance, root, facing, degenerate, bones, rest, body_bones, arm_bones, sideways
):
    """:func:`fpg_gym.reconstruct.reliability.is_neutral_pose` of one pose ``(20, 3)`` float64
    (the cosine of the tolerance given): normalised as :func:`fpg_gym.core.poses.normalise`
    does it (float32; ``facing`` the hips' and shoulders' joints), then each checked bone's
    direction against its rest direction (the dot products summed in ``np.einsum``'s order) or,
    for the arms, sideways (``sideways`` ``(2, 3)``, the left arm's and the right's, along X)."""
    yaw = facing_yaw_pose(pose, facing[0], facing[1], facing[2], facing[3], degenerate)
    placed = place_pose(pose, pose[root], yaw, np.bool_(False))
    count = bones.shape[0]
    directions = np.empty((count, 3))
    for b in range(count):
        s = 0.0
        for c in range(3):
            v = np.float64(np.float32(placed[bones[b, 1], c])) - np.float64(
                np.float32(placed[bones[b, 0], c])
            )
            directions[b, c] = v
            s += v * v
        norm = np.sqrt(s)
        if norm < 1e-6:
            return False
        for c in range(3):
            directions[b, c] /= norm
    for i in range(body_bones.shape[0]):
        b = body_bones[i]
        dot = (directions[b, 0] * rest[b, 0] + directions[b, 2] * rest[b, 2]) + (
            directions[b, 1] * rest[b, 1]
        )
        if dot < cos_tolerance:
            return False
    for side in range(arm_bones.shape[0]):
        down = True
        out = True
        for i in range(arm_bones.shape[1]):
            b = arm_bones[side, i]
            dot = (directions[b, 0] * rest[b, 0] + directions[b, 2] * rest[b, 2]) + (
                directions[b, 1] * rest[b, 1]
            )
            down = down and dot >= cos_tolerance
            along = directions[b, 0] * sideways[side, 0]  # the sideways axes are +-X
            out = out and along >= cos_tolerance
        if not (down or out):
            return False
    return True


@numba.njit(**JIT_OPTIONS)
def _sorted_ratios(row, prior):
    """The finite values of ``row / prior``, sorted (what :class:`SortedWindow
    <fpg_gym.reconstruct.reliability.SortedWindow>` adds or removes for a row)."""
    out = np.empty(row.shape[0])
    n = 0
    for b in range(row.shape[0]):
        ratio = row[b] / prior[b]
        if np.isfinite(ratio):
            i = n  # insertion sort: a row is short (and np.sort is slow to compile)
            while i > 0 and out[i - 1] > ratio:
                out[i] = out[i - 1]
                i -= 1
            out[i] = ratio
            n += 1
    return out[:n]


@numba.njit(**JIT_OPTIONS)
def _update_reference(
    positions,
    states,
    lengths,
    counts,
    neutral,
    tracked_rows,
    window,
    reference,
    prior,
    tracked_median,
    cos_tolerance,
    prior_height,
    tracked_state,
    root,
    calibration_joints,
    facing,
    degenerate,
    bones,
    rest,
    body_bones,
    arm_bones,
    sideways,
):
    """:meth:`ReliabilityEstimator._update_reference
    <fpg_gym.reconstruct.reliability.ReliabilityEstimator._update_reference>` of one frame (see
    :func:`reliability_frame`): returns the sorted window's successor and whether the frame
    was a calibration frame."""
    joints = positions.shape[0]
    count = bones.shape[0]
    cap = neutral.shape[0]
    calibration = True
    for i in range(calibration_joints.shape[0]):
        if states[calibration_joints[i]] < tracked_state:
            calibration = False
    if calibration:
        calibration = neutral_pose(
            positions,
            cos_tolerance,
            root,
            facing,
            degenerate,
            bones,
            rest,
            body_bones,
            arm_bones,
            sideways,
        )
    if calibration:
        for b in range(count):
            neutral[counts[2] % cap, b] = lengths[b]
        counts[2] += 1
    both = np.empty(count, dtype=np.bool_)
    seen = False
    for b in range(count * (counts[2] == 0)):
        both[b] = (
            states[bones[b, 0]] >= tracked_state
            and states[bones[b, 1]] >= tracked_state
            and lengths[b] > 1e-6
        )
        seen = seen or both[b]
    if seen:
        slot = counts[3] % cap
        if counts[3] >= cap:  # the ring's oldest row leaves the window
            window = remove_sorted(window, _sorted_ratios(tracked_rows[slot], prior))
        for b in range(count):
            tracked_rows[slot, b] = lengths[b] if both[b] else np.nan
        window = merge_sorted(window, _sorted_ratios(tracked_rows[slot], prior))
        counts[3] += 1
    if counts[2]:
        if calibration or counts[4] != 1:  # else the same rows, the same median
            _column_medians(neutral[: min(counts[2], cap)], np.bool_(False), reference)
        counts[4] = 1
    elif counts[3]:
        scale = _median_of(window)
        for b in range(count):
            reference[b] = prior[b] * scale
        counts[4] = 2
        if tracked_median:
            _column_medians(tracked_rows[: min(counts[3], cap)], np.bool_(True), reference)
            counts[4] = 3
    else:
        low = high = positions[0, 1]
        for j in range(1, joints):
            low = scalar_minimum(low, positions[j, 1])
            high = scalar_maximum(high, positions[j, 1])
        scale = (high - low) / prior_height
        scale = scalar_minimum(scalar_maximum(scale, 0.5), 1.5) if scale > 1e-3 else 1.0
        for b in range(count):
            reference[b] = prior[b] * scale
        counts[4] = 4
    return window, calibration


@numba.njit(**JIT_OPTIONS)
def _behaviour(positions, recent, angles, counts, root, min_displacement, theta_floor, theta_span):
    """The behaviour term ``Rb`` ``(20,)`` of one frame and its motion history (see
    :func:`reliability_frame`)."""
    joints = positions.shape[0]
    # Behaviour (Shum §IV-A): root-relative displacements, the root's own in camera space.
    local = np.empty((joints, 3))
    for j in range(joints):
        for c in range(3):
            local[j, c] = positions[j, c] - positions[root, c]
    for c in range(3):
        local[root, c] = positions[root, c]
    frames = angles.shape[0]
    if counts[0] == 2:
        moved = np.empty((joints, 3))
        before = np.empty((joints, 3))
        for j in range(joints):
            for c in range(3):
                moved[j, c] = local[j, c] - recent[1, j, c]
                before[j, c] = recent[1, j, c] - recent[0, j, c]
        angle = vector_angles(moved, before, min_displacement)
        row = counts[1]
        if row == frames:  # the oldest leaves
            row = frames - 1
            for i in range(row):
                for j in range(joints):
                    angles[i, j] = angles[i + 1, j]
        else:
            counts[1] += 1
        for j in range(joints):
            angles[row, j] = angle[j]
        for j in range(joints):
            for c in range(3):
                recent[0, j, c] = recent[1, j, c]
                recent[1, j, c] = local[j, c]
    else:
        for j in range(joints):
            for c in range(3):
                recent[counts[0], j, c] = local[j, c]
        counts[0] += 1
    behaviour = np.empty(joints)
    kept = counts[1]
    for j in range(joints):
        mean = 0.0
        if kept:
            total = angles[0, j]
            for i in range(1, kept):
                total += angles[i, j]
            mean = total / kept
        behaviour[j] = (
            1.0 - scalar_minimum(scalar_maximum(mean - theta_floor, 0.0), theta_span) / theta_span
        )
    return behaviour


@numba.njit(**JIT_OPTIONS)
def reliability_frame(
    positions,
    states,
    recent,
    angles,
    counts,
    neutral,
    tracked_rows,
    window,
    reference,
    prior,
    fixed,
    tracked_median,
    min_displacement,
    theta_floor,
    theta_span,
    cos_tolerance,
    prior_height,
    tracked_state,
    root,
    calibration_joints,
    facing,
    degenerate,
    bones,
    rest,
    body_bones,
    arm_bones,
    sideways,
):
    """One frame of :meth:`ReliabilityEstimator.update
    <fpg_gym.reconstruct.reliability.ReliabilityEstimator.update>` up to its two matrix
    products (the joints' mean of the bones' deviations and the Gaussian filter, BLAS's): the
    reference bone lengths (``_update_reference``), the behaviour term ``Rb`` with its motion
    history, the bones' relative length deviations and ``Rt`` (Shum §IV, FPG §5), the numpy
    code's operations in its order.

    The stream's state is updated in place: ``recent`` ``(2, 20, 3)`` (the last root-relative
    frames, oldest first), ``angles`` ``(f_b, 20)`` (oldest first), ``counts`` (frames in
    ``recent`` and ``angles``, calibration frames, tracked frames, the reference's source:
    1 neutral, 2 scaled prior, 3 tracked median, 4 prior height), the rings ``neutral`` and
    ``tracked_rows`` ``(cap, 19)`` and ``reference`` ``(19,)`` (left as it is when ``fixed``).

    Returns ``Rb`` ``(20,)``, the deviations ``(19,)``, ``Rt`` ``(20,)``, the sorted window of
    tracked length ratios (``window``'s successor), whether the frame was a calibration frame
    and whether a body was in view.
    """
    joints = positions.shape[0]
    count = bones.shape[0]
    lengths = bone_lengths_pose(positions, bones)
    calibration = False
    if not fixed:
        window, calibration = _update_reference(
            positions,
            states,
            lengths,
            counts,
            neutral,
            tracked_rows,
            window,
            reference,
            prior,
            tracked_median,
            cos_tolerance,
            prior_height,
            tracked_state,
            root,
            calibration_joints,
            facing,
            degenerate,
            bones,
            rest,
            body_bones,
            arm_bones,
            sideways,
        )

    # Behaviour (Shum §IV-A), with its motion history.
    behaviour = _behaviour(
        positions, recent, angles, counts, root, min_displacement, theta_floor, theta_span
    )
    deviation = np.empty(count)
    for b in range(count):
        deviation[b] = scalar_minimum(
            abs(lengths[b] - reference[b]) / scalar_maximum(reference[b], 1e-6), 1.0
        )
    tracking = np.empty(joints)
    body = False
    for j in range(joints):
        tracking[j] = 1.0 if states[j] >= tracked_state else 0.0
        body = body or states[j] > 0
    if not body:  # nothing enters the motion history
        counts[0] = 0
        counts[1] = 0
    return behaviour, deviation, tracking, window, calibration, body


@numba.njit(**JIT_OPTIONS)
def newest_minimum(behaviour, mean_deviation, tracking, minima, kept):
    """``Rk = 1 - mean_deviation`` (the joints' mean of their bones' deviations, BLAS's
    product) and ``min(Rb, Rk, Rt)`` ``(20,)``, which enters ``minima`` ``(S, 20)`` (newest
    first, ``kept`` rows after it) as its first row: :meth:`ReliabilityEstimator.update
    <fpg_gym.reconstruct.reliability.ReliabilityEstimator.update>` before its filter."""
    joints = behaviour.shape[0]
    for i in range(kept - 1, 0, -1):
        for j in range(joints):
            minima[i, j] = minima[i - 1, j]
    kinematic = np.empty(joints)
    minimum = np.empty(joints)
    for j in range(joints):
        kinematic[j] = 1.0 - mean_deviation[j]
        minimum[j] = scalar_minimum(scalar_minimum(behaviour[j], kinematic[j]), tracking[j])
        minima[0, j] = minimum[j]
    return kinematic, minimum
