"""A frame's set-up compiled (numba): the local PCA, the energy's tables and the terms of a few
points, the sorted window of the reliability's reference lengths and the left/right labelling
costs; imported only when ``fpg-gym[fast]`` is installed.

The same maths as the numpy code they stand for (:meth:`LatentSpace.fit
<fpg_gym.reconstruct.latent.LatentSpace.fit>`, :class:`~fpg_gym.reconstruct.energy.EnergyModel`'s
tables and working arrays, its :meth:`~fpg_gym.reconstruct.energy.EnergyModel.terms`) in one call
each instead of some forty numpy calls: the arithmetic is a few tens of thousands of
multiply-adds, so what the numpy code spends is dispatch. Results agree with the numpy path to
floating-point rounding (the sums run in another order); the tests compare them.

Module-level functions so that numba's disk cache (``cache=True``) finds them in a new process.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core.compiled_poses import (
    bone_lengths_pose,
    facing_yaw_pose,
    place_pose,
    retarget_pose,
    vector_angles,
)
from fpg_gym.filters.compiled_filters import kalman_step

__all__ = [
    "best_labelling",
    "centre_poses",
    "continuity_poses",
    "energy_setup",
    "finish_pose",
    "fusion_bone_terms",
    "fusion_bones",
    "held_directions",
    "labelling_costs",
    "latent_terms",
    "merge_sorted",
    "neutral_pose",
    "newest_minimum",
    "reliability_frame",
    "remove_sorted",
    "restore_output",
    "sensor_trust",
    "settle_lengths",
    "smooth_output",
    "trust_exponents",
    "whitened_axes",
]


@numba.njit(cache=True, nogil=True)
def centre_poses(poses):
    """Poses ``(K, 20, 3)`` float32 as float64 60-vectors: their mean ``(60,)`` and the centred
    poses ``(K, 60)`` (numpy's ``data.mean(axis=0)`` and ``data - mean``, to the bit: the rows
    summed in order, then divided by K), and whether every value is finite."""
    count = poses.shape[0]
    size = poses.shape[1] * poses.shape[2]
    flat = poses.reshape(count, size)
    mean = np.empty(size)
    finite = True
    for c in range(size):
        mean[c] = np.float64(flat[0, c])
    for i in range(1, count):
        for c in range(size):
            mean[c] += np.float64(flat[i, c])
    for c in range(size):
        finite = finite and np.isfinite(mean[c])
        mean[c] /= count
    centred = np.empty((count, size))
    for i in range(count):
        for c in range(size):
            centred[i, c] = np.float64(flat[i, c]) - mean[c]
    return mean, centred, finite


@numba.njit(cache=True, nogil=True)
def whitened_axes(centred, values, vectors, dim, min_std, max_condition):
    """The whitened axes of centred poses ``(K, 60)`` from their Gram matrix's eigenpairs
    (``np.linalg.eigh``'s ``values``, ascending, and ``vectors``), ``1 <= dim <= K - 1``.

    Returns ``basis (dim, 60)`` (each row's largest-magnitude entry positive), ``std (dim,)``
    floored at ``min_std``, ``degenerate (dim,)``, the explained variance ratio and whether the
    Gram matrix was usable (``s_1 / s_dim <= max_condition``; when it was not, the caller takes
    the SVD): :meth:`LatentSpace.fit <fpg_gym.reconstruct.latent.LatentSpace.fit>` after the
    eigen-decomposition, which stays numpy's (LAPACK compiled into numba costs seconds of
    compilation).
    """
    count, size = centred.shape
    singular = np.sqrt(np.maximum(values[::-1], 0.0))
    if not (singular[dim - 1] > 0.0 and singular[0] <= max_condition * singular[dim - 1]):
        return np.zeros((dim, size)), np.zeros(dim), np.zeros(dim, dtype=np.bool_), 0.0, False
    basis = np.zeros((dim, size))
    for a in range(dim):  # the eigenvectors' combinations of the poses (loops: no BLAS to compile)
        for i in range(count):
            weight = vectors[i, count - 1 - a]
            for c in range(size):
                basis[a, c] += weight * centred[i, c]
    for a in range(dim):  # element loops: array-wide ops compile numba's shape-error messages
        for c in range(size):
            basis[a, c] /= singular[a]
        best = 0  # sign: the largest-magnitude entry positive
        for c in range(1, size):
            if abs(basis[a, c]) > abs(basis[a, best]):
                best = c
        if basis[a, best] < 0.0:
            for c in range(size):
                basis[a, c] *= -1.0
    std = np.empty(dim)
    degenerate = np.empty(dim, dtype=np.bool_)
    scale = np.sqrt(count - 1.0)
    kept_sum = 0.0
    for a in range(dim):
        spread = singular[a] / scale
        degenerate[a] = spread < min_std
        std[a] = max(spread, min_std)
        kept_sum += singular[a] * singular[a]
    total = 0.0
    for a in range(count):
        total += singular[a] * singular[a]
    ratio = kept_sum / total if total > 0.0 else 1.0
    return basis, std, degenerate, ratio, True


@numba.njit(cache=True, nogil=True)
def _row_squares(rows):
    """Each row's sum of squares, summed in column order; the rows side by side (independent
    sums, so that they overlap instead of each waiting for its last addition)."""
    sums = np.zeros(rows.shape[0])
    for c in range(rows.shape[1]):
        for n in range(rows.shape[0]):
            sums[n] += rows[n, c] * rows[n, c]
    return sums


@numba.njit(cache=True, nogil=True)
def _neighbour_coordinates(mean, basis, neighbours):
    """Es (Eq. 12): the neighbours' squared distances to the mean ``(K,)``, their coordinates
    ``y (K, d)`` in the space, ``|y_n|^2`` and the squared residuals outside the space ``(K,)``."""
    d, size = basis.shape
    k = neighbours.shape[0]
    centred = np.empty((k, size))
    for n in range(k):
        for c in range(size):
            centred[n, c] = neighbours[n, c] - mean[c]
    # Coordinates in the space (loops: no BLAS to compile). Each y[n, a] sums its products in
    # the order of c, the innermost loop running over a so that it vectorises, the
    # neighbours side by side.
    transposed = np.empty((size, d))
    for a in range(d):
        for c in range(size):
            transposed[c, a] = basis[a, c]
    y = np.zeros((k, d))
    for c in range(size):
        for n in range(k):
            v = centred[n, c]
            for a in range(d):
                y[n, a] += v * transposed[c, a]
    residual = centred.copy()
    for n in range(k):
        for a in range(d):
            for c in range(size):
                residual[n, c] -= y[n, a] * basis[a, c]
    return _row_squares(centred), y, _row_squares(y), _row_squares(residual)


@numba.njit(cache=True, nogil=True)
def energy_setup(
    mean, basis, std, sensor, reliability, neighbours, lengths, target, weights, child, parent
):
    """Shum Eq. 10's tables and working arrays for one frame (all float64).

    ``target`` is ``(60,)`` or empty (no motion target: ``Em = 0``); ``weights`` ``(5,)`` are
    ``w_c, w_s, w_k, w_m, w_p``; ``child``/``parent`` the 57 coordinates of the bones' ends.

    Returns ``matrix (d, d + 1 + K + 57)``, ``c0``, ``ycst (K,)``, ``b0 (57,)``, ``wk`` (the
    :class:`~fpg_gym.reconstruct.kernels.EnergyTables`), then ``components (d, 60)``,
    ``joint_weights (60,)``, ``y (K, d)``, ``y_sq (K,)`` and ``r_sq (K,)`` (what
    :func:`latent_terms` takes).
    """
    joints = reliability.shape[0]
    bones = lengths.shape[0]
    d, size = basis.shape
    k = neighbours.shape[0]
    wc, ws, wk, wm, wp = weights[0], weights[1], weights[2], weights[3], weights[4]
    components = np.empty((d, size))
    for a in range(d):
        for c in range(size):
            components[a, c] = basis[a, c] * std[a]
    joint_weights = np.empty(size)
    for j in range(joints):
        for c in range(3):
            joint_weights[3 * j + c] = reliability[j]
    centred_sq, y, y_sq, r_sq = _neighbour_coordinates(mean, basis, neighbours)
    # Ec (Eq. 11) and Em (Eq. 14) as z^T A z + g.z + c.
    weighted = np.empty(size)
    c0 = 0.0
    for c in range(size):
        delta = mean[c] - sensor[c]
        weighted[c] = wc * joint_weights[c] * delta
        c0 += weighted[c] * delta
    has_target = target.shape[0] > 0
    if has_target:
        motion_sq = 0.0
        for c in range(size):
            motion = mean[c] - target[c]
            weighted[c] += wm / joints * motion
            motion_sq += motion * motion
        c0 += wm / joints * motion_sq
    width = d + 1 + k + 3 * bones
    matrix = np.empty((d, width))
    scaled = np.empty((d, size))
    for a in range(d):
        for c in range(size):
            scaled[a, c] = components[a, c] * (wc * joint_weights[c])
    transposed = np.empty((size, d))
    for a in range(d):
        for c in range(size):
            transposed[c, a] = components[a, c]
    # A = C diag(wc R) C^T: each entry sums over c in order (the loop over b vectorises).
    row = np.empty(d)
    for a in range(d):
        for b in range(d):
            row[b] = 0.0
        for c in range(size):
            v = scaled[a, c]
            for b in range(a, d):
                row[b] += v * transposed[c, b]
        for b in range(a, d):
            matrix[a, b] = row[b]
            matrix[b, a] = row[b]
    linear = np.zeros(d)
    for c in range(size):
        v = weighted[c]
        for a in range(d):
            linear[a] += transposed[c, a] * v
    for a in range(d):
        diagonal = ws / joints * std[a] * std[a] + wp / max(d, 1)
        if has_target:
            diagonal += wm / joints * std[a] * std[a]
        matrix[a, a] += diagonal
        matrix[a, d] = 2.0 * linear[a]
        for n in range(k):
            matrix[a, d + 1 + n] = (-2.0 * ws / joints) * (std[a] * y[n, a])
        for b in range(3 * bones):
            matrix[a, d + 1 + k + b] = components[a, child[b]] - components[a, parent[b]]
    ycst = np.empty(k)
    for n in range(k):
        ycst[n] = ws / joints * centred_sq[n]
    b0 = np.empty(3 * bones)
    for b in range(3 * bones):
        b0[b] = mean[child[b]] - mean[parent[b]]
    return matrix, c0, ycst, b0, wk / bones, components, joint_weights, y, y_sq, r_sq


@numba.njit(cache=True, nogil=True)
def latent_terms(
    z,
    mean,
    components,
    sensor,
    joint_weights,
    y,
    y_sq,
    r_sq,
    std,
    lengths,
    target,
    child,
    parent,
    weights,
):
    """``Ec``, ``Es``, ``Ek``, ``Em``, ``Ep`` (Shum Eqs. 11-14 and the latent prior) of points
    ``(n, d)`` and their weighted sum ``E`` (Eq. 10; ``weights`` ``(5,)``, the prior's added
    when its weight is not 0, in :meth:`EnergyModel.total
    <fpg_gym.reconstruct.energy.EnergyModel.total>`'s order), as rows of a ``(6, n)`` float64
    array, from :func:`energy_setup`'s working arrays (in the points' dtype); ``target`` empty
    gives ``Em = 0``."""
    n, d = z.shape
    size = mean.shape[0]
    joints = size // 3
    bones = lengths.shape[0]
    k = y.shape[0]
    x = z @ components
    out = np.zeros((6, n))
    u = np.empty(d, dtype=z.dtype)
    for i in range(n):
        for c in range(size):
            x[i, c] += mean[c]
        ec = 0.0
        for c in range(size):
            diff = x[i, c] - sensor[c]
            ec += diff * diff * joint_weights[c]
        uu = 0.0
        zz = 0.0
        for a in range(d):
            u[a] = z[i, a] * std[a]
            uu += u[a] * u[a]
            zz += z[i, a] * z[i, a]
        best = np.inf
        for m in range(k):
            dot = 0.0
            for a in range(d):
                dot += u[a] * y[m, a]
            dist = uu - 2.0 * dot + y_sq[m] + r_sq[m]
            if dist < best:
                best = dist
        ek = 0.0
        for b in range(bones):
            s = 0.0
            for c in range(3):
                v = x[i, child[3 * b + c]] - x[i, parent[3 * b + c]]
                s += v * v
            diff = np.sqrt(s) - lengths[b]
            ek += diff * diff
        em = 0.0
        if target.shape[0] > 0:
            for c in range(size):
                diff = x[i, c] - target[c]
                em += diff * diff
        out[0, i] = ec  # Eq. 11
        out[1, i] = max(best, 0.0) / joints  # Eq. 12
        out[2, i] = ek / bones  # Eq. 13
        out[3, i] = em / joints  # Eq. 14
        out[4, i] = zz / max(d, 1)  # latent prior (beyond the papers)
        total = weights[0] * out[0, i] + weights[1] * out[1, i]
        total = total + weights[2] * out[2, i] + weights[3] * out[3, i]
        if weights[4] != 0.0:
            total = total + weights[4] * out[4, i]
        out[5, i] = total
    return out


@numba.njit(cache=True, nogil=True)
def continuity_poses(last, before, root, yaw, ratio, damping):
    """:func:`fpg_gym.reconstruct.temporal.continuity` of two previous outputs ``(20, 3)``
    (``before`` with no rows: one output only): each root-relative and turned by ``-yaw``
    (``place_pose``), and the prediction ``previous + (previous - before) * ratio``, its velocity
    scaled by ``damping`` (FPG Eq. 6; the same operations as the numpy code, to the bit)."""
    previous = place_pose(last, last[root], yaw, np.bool_(False))  # not Literal: one signature
    prediction = previous.copy()
    if before.shape[0] == 0:
        return previous, prediction
    turned = place_pose(before, before[root], yaw, np.bool_(False))
    for j in range(previous.shape[0]):
        for c in range(3):
            target = previous[j, c] + (previous[j, c] - turned[j, c]) * ratio
            if damping != 1.0:
                target = previous[j, c] + damping * (target - previous[j, c])
            prediction[j, c] = target
    return previous, prediction


@numba.njit(cache=True, nogil=True)
def finish_pose(local, lengths, root, yaw, bones, rest_directions):
    """:func:`fpg_gym.reconstruct.pending.output_pose`: the normalised pose ``local`` ``(20, 3)``
    retargeted to ``lengths`` (``retarget_pose``, float32), then put back at ``root`` and
    ``yaw`` in float64 (``place_pose``) and returned as float32 (the numpy code's operations)."""
    retargeted = retarget_pose(local, lengths, bones, rest_directions)
    placed = place_pose(retargeted.astype(np.float64), root, yaw, np.bool_(True))  # not Literal
    return placed.astype(np.float32)


@numba.njit(cache=True, nogil=True)
def restore_output(filtered, lengths, root, root_index, bones, rest_directions):
    """:class:`fpg_gym.reconstruct.temporal.OutputSmoother`'s output from its filter's
    root-relative float32 pose ``(20, 3)``: root-relative again, retargeted to ``lengths``
    (``retarget_pose``, float32), put back at ``root`` in float64 and returned as float32 (the
    numpy code's operations, to the bit)."""
    joints = filtered.shape[0]
    local = np.empty((joints, 3))
    for c in range(3):
        origin = np.float64(filtered[root_index, c])
        for j in range(joints):
            local[j, c] = np.float64(filtered[j, c]) - origin
    placed = retarget_pose(local, lengths, bones, rest_directions)
    out = np.empty((joints, 3), dtype=np.float32)
    for j in range(joints):
        for c in range(3):
            out[j, c] = np.float64(placed[j, c]) + root[c]
    return out


@numba.njit(cache=True, nogil=True)
def smooth_output(pose, lengths, root_index, bones, rest_directions, kalman):
    """:class:`fpg_gym.reconstruct.temporal.OutputSmoother`'s update of one pose ``(20, 3)``
    float64 with the Kalman filter in one call: the pose root-relative, the filter's step
    (``kalman_step``; ``kalman`` its arguments after the frame,
    :meth:`~fpg_gym.filters.KalmanFilter.kernel_arguments`, the state updated in place) rounded
    to float32 as ``update_tracked`` returns it, then :func:`restore_output` (the same
    operations)."""
    joints = pose.shape[0]
    root = pose[root_index].copy()
    frame = np.empty((joints, 3))
    for j in range(joints):
        for c in range(3):
            frame[j, c] = pose[j, c] - root[c]
    filtered = kalman_step(frame, *kalman)
    return restore_output(
        filtered.astype(np.float32), lengths, root, root_index, bones, rest_directions
    )


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
def neutral_pose(
    pose, cos_tolerance, root, facing, degenerate, bones, rest, body_bones, arm_bones, sideways
):
    """:func:`fpg_gym.reconstruct.reliability.is_neutral_pose` of one pose ``(20, 3)`` float64
    (the cosine of the tolerance given): normalised as :func:`fpg_gym.core.poses.normalise`
    does it (float32; ``facing`` the hips' and shoulders' joints), then each checked bone's
    direction against its rest direction (the dot products summed in ``np.einsum``'s order) or,
    for the arms, sideways (``sideways`` ``(2, 3)``, the left arm's and the right's, along X)."""
    yaw = facing_yaw_pose(pose, facing[0], facing[1], facing[2], facing[3], degenerate)
    placed = place_pose(pose, pose[root], yaw, False)
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


@numba.njit(cache=True, nogil=True)
def _maximum(a, b):
    """``np.maximum`` of two floats (NaN when either is)."""
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, nogil=True)
def _minimum(a, b):
    """``np.minimum`` of two floats (NaN when either is)."""
    return a if (a <= b or a != a) else b


@numba.njit(cache=True, nogil=True)
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


@numba.njit(cache=True, nogil=True)
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
    if not fixed:  # _update_reference
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
                _column_medians(neutral[: min(counts[2], cap)], False, reference)
            counts[4] = 1
        elif counts[3]:
            scale = _median_of(window)
            for b in range(count):
                reference[b] = prior[b] * scale
            counts[4] = 2
            if tracked_median:
                _column_medians(tracked_rows[: min(counts[3], cap)], True, reference)
                counts[4] = 3
        else:
            low = high = positions[0, 1]
            for j in range(1, joints):
                low = _minimum(low, positions[j, 1])
                high = _maximum(high, positions[j, 1])
            scale = (high - low) / prior_height
            scale = _minimum(_maximum(scale, 0.5), 1.5) if scale > 1e-3 else 1.0
            for b in range(count):
                reference[b] = prior[b] * scale
            counts[4] = 4

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
        behaviour[j] = 1.0 - _minimum(_maximum(mean - theta_floor, 0.0), theta_span) / theta_span
    deviation = np.empty(count)
    for b in range(count):
        deviation[b] = _minimum(abs(lengths[b] - reference[b]) / _maximum(reference[b], 1e-6), 1.0)
    tracking = np.empty(joints)
    body = False
    for j in range(joints):
        tracking[j] = 1.0 if states[j] >= tracked_state else 0.0
        body = body or states[j] > 0
    if not body:  # nothing enters the motion history
        counts[0] = 0
        counts[1] = 0
    return behaviour, deviation, tracking, window, calibration, body


@numba.njit(cache=True, nogil=True)
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
        minimum[j] = _minimum(_minimum(behaviour[j], kinematic[j]), tracking[j])
        minima[0, j] = minimum[j]
    return kinematic, minimum


@numba.njit(cache=True, nogil=True)
def labelling_costs(positions, states, prediction, permutations, tracked, inferred):
    """:func:`fpg_gym.reconstruct.left_right.left_right_costs`: for each row of
    ``permutations`` ``(H, 20)``, the mean distance (weights 1 tracked, 0.5 inferred, 0 not
    tracked) between the relabelled root-relative sensor joints and the root-relative
    prediction; ``(H,)`` float64."""
    count, joints = permutations.shape
    out = np.empty(count)
    for h in range(count):
        total = 0.0
        weight_sum = 0.0
        for j in range(joints):
            source = permutations[h, j]
            state = states[source]
            w = 1.0 if state >= tracked else (0.5 if state == inferred else 0.0)
            s = 0.0
            for c in range(3):
                v = (positions[source, c] - positions[0, c]) - (prediction[j, c] - prediction[0, c])
                s += v * v
            total += w * np.sqrt(s)
            weight_sum += w
        out[h] = total / max(weight_sum, 1e-9)
    return out


@numba.njit(cache=True, nogil=True)
def best_labelling(compared, states, last, before, ratio, margin, permutations, tracked, inferred):
    """:func:`fpg_gym.reconstruct.left_right.best_labelling` in one call: the constant-velocity
    guess of the root-relative previous outputs ``last`` and ``before`` ``(20, 3)`` float64
    (``before`` with no rows: ``last`` itself; ``ratio`` is ``dt / dt_prev``, as
    :func:`~fpg_gym.reconstruct.energy.motion_target`), :func:`labelling_costs` of the sensor
    pose ``compared`` (float64) against it, and the labelling chosen (another than 0 only when
    its cost is under ``margin`` times the reported one's and 3 cm lower)."""
    guess = last
    if before.shape[0] > 0:
        joints = last.shape[0]
        guess = np.empty((joints, 3))
        for j in range(joints):
            for c in range(3):
                previous = last[j, c] - last[0, c]
                guess[j, c] = previous + (previous - (before[j, c] - before[0, c])) * ratio
    costs = labelling_costs(compared, states, guess, permutations, tracked, inferred)
    best = 0
    for h in range(costs.shape[0]):
        if np.isnan(costs[h]):
            return 0  # np.argmin's NaN: never under the margin
        if costs[h] < costs[best]:
            best = h
    if best != 0 and costs[best] < margin * costs[0] and costs[0] - costs[best] > 0.03:
        return best
    return 0


@numba.njit(cache=True, nogil=True)
def settle_lengths(estimate, lengths, low, high, rate, spread):
    """:meth:`BoneSettler.update <fpg_gym.reconstruct.bones.BoneSettler.update>` after settling:
    each bone of ``lengths`` ``(19,)`` moves toward ``estimate`` by at most ``rate`` and keeps
    its range since settling (``low``, ``high``, updated in place) within ``spread`` (the numpy
    code's operations). Returns the new lengths, the largest change (``np.max`` of its
    magnitudes) and whether a bone moved more than 1e-9 m."""
    count = estimate.shape[0]
    moved = np.empty(count)
    largest = 0.0
    changed = False
    for b in range(count):
        step = _minimum(_maximum(estimate[b] - lengths[b], -rate), rate)
        value = _minimum(_maximum(lengths[b] + step, high[b] - spread), low[b] + spread)
        moved[b] = value
        low[b] = _minimum(low[b], value)
        high[b] = _maximum(high[b], value)
        change = abs(value - lengths[b])
        largest = _maximum(largest, change)
        changed = changed or change > 1e-9
    return moved, largest, changed


@numba.njit(cache=True, nogil=True)
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
        exponents[j] = _maximum(lost - flicker, 0.0) / half_life
    return exponents


@numba.njit(cache=True, nogil=True)
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
        deviation = abs(lengths[b] - reference) / _maximum(reference, 1e-3)
        bone_trust = 1.0 - _minimum(_maximum((deviation - tolerance) / span, 0.0), 1.0)
        child = bones[b, 1]
        trust[child] = _minimum(trust[child], bone_trust)
    for k in range(order.shape[0]):  # an inferred joint hangs off its parent
        j = order[k]
        if parents[j] >= 0 and states[j] == inferred_state:
            trust[j] = _minimum(trust[j], trust[parents[j]])
    for b in range(bones.shape[0]):
        good = trust[bones[b, 0]] > 0.9 and trust[bones[b, 1]] > 0.9
        length_sum[b] += lengths[b] if good else 0.0
        length_count[b] += 1.0 if good else 0.0
    return trust


@numba.njit(cache=True, nogil=True)
def _unit_row(x, y, z):
    """A row's norm (numpy's sum of squares, in order) and the row over ``max(norm, 1e-9)``."""
    norm = np.sqrt((x * x + y * y) + z * z)
    scale = _maximum(norm, 1e-9)
    return norm, x / scale, y / scale, z / scale


@numba.njit(cache=True, nogil=True)
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
        bone_trust[b] = _minimum(trust[parent], trust[child])
        seen = bone_trust[b] > 0.9
        database_norm, d0, d1, d2 = _unit_row(
            database[child, 0] - database[parent, 0],
            database[child, 1] - database[parent, 1],
            database[child, 2] - database[parent, 2],
        )
        sensor_norm, s0, s1, s2 = _unit_row(
            sensor_bones[b, 0], sensor_bones[b, 1], sensor_bones[b, 2]
        )
        database_units[b, 0], database_units[b, 1], database_units[b, 2] = d0, d1, d2
        sensor_units[b, 0], sensor_units[b, 1], sensor_units[b, 2] = s0, s1, s2
        length_sum[b] += sensor_norm if seen else 0.0
        length_count[b] += 1.0 if seen else 0.0
        if length_count[b] > 0:
            estimate[b] = length_sum[b] / _maximum(length_count[b], 1.0)
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


@numba.njit(cache=True, nogil=True)
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
        _, l0, l1, l2 = _unit_row(l0, l1, l2)
        weight = bone_trust[b]
        out[b, 0] = weight * (sensor_units[b, 0] * lengths[b]) + (1.0 - weight) * (l0 * lengths[b])
        out[b, 1] = weight * (sensor_units[b, 1] * lengths[b]) + (1.0 - weight) * (l1 * lengths[b])
        out[b, 2] = weight * (sensor_units[b, 2] * lengths[b]) + (1.0 - weight) * (l2 * lengths[b])
    return out


@numba.njit(cache=True, nogil=True)
def held_directions(pose, parent_frames, bones, bone_trust, held):
    """:meth:`SensorFusion.update <fpg_gym.reconstruct.fusion.SensorFusion.update>`'s memory
    of each seen bone's unit direction in its parent's frame ``(19, 3, 3)`` (``np.einsum``'s
    order of the sum), written into ``held`` ``(19, 3)``."""
    for b in range(bones.shape[0]):
        if not bone_trust[b] > 0.9:
            continue
        parent, child = bones[b, 0], bones[b, 1]
        _, u0, u1, u2 = _unit_row(
            pose[child, 0] - pose[parent, 0],
            pose[child, 1] - pose[parent, 1],
            pose[child, 2] - pose[parent, 2],
        )
        for i in range(3):
            held[b, i] = (
                parent_frames[b, 0, i] * u0 + parent_frames[b, 1, i] * u1
            ) + parent_frames[b, 2, i] * u2
