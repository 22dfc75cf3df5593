"""A frame's set-up and output compiled (numba): the local PCA, the energy's tables and the
terms of a few points, the continuity and output poses, the left/right labelling costs and the
bones' settling step; imported only when ``fpg-gym[fast]`` is installed. The reliability's
kernels are in :mod:`fpg_gym.reconstruct.compiled_reliability`, the fusion's in
:mod:`fpg_gym.reconstruct.compiled_fusion`.

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

from fpg_gym.core.compiled import JIT_OPTIONS
from fpg_gym.core.compiled_poses import (
    place_pose,
    retarget_pose,
    scalar_maximum,
    scalar_minimum,
)
from fpg_gym.filters.compiled_filters import kalman_step

__all__ = [
    "best_labelling",
    "centre_poses",
    "continuity_poses",
    "energy_setup",
    "finish_pose",
    "labelling_costs",
    "latent_terms",
    "restore_output",
    "settle_lengths",
    "smooth_output",
    "whitened_axes",
]


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
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
    ranks = values.shape[0]  # np.sqrt(np.maximum(values[::-1], 0.0)), element by element
    singular = np.empty(ranks)
    for a in range(ranks):
        singular[a] = np.sqrt(scalar_maximum(values[ranks - 1 - a], 0.0))
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


@numba.njit(**JIT_OPTIONS)
def _row_squares(rows):
    """Each row's sum of squares, summed in column order; the rows side by side (independent
    sums, so that they overlap instead of each waiting for its last addition)."""
    sums = np.zeros(rows.shape[0])
    for c in range(rows.shape[1]):
        for n in range(rows.shape[0]):
            sums[n] += rows[n, c] * rows[n, c]
    return sums


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
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
    # A = C diag(wc R) C^T: each entry sums over c in order; whole rows (the loop over b
    # vectorises without a ragged tail: 10 % faster), the upper triangle kept and mirrored.
    row = np.empty(d)
    for a in range(d):
        for b in range(d):
            row[b] = 0.0
        for c in range(size):
            v = scaled[a, c]
            for b in range(d):
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


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
def finish_pose(local, lengths, root, yaw, bones, rest_directions):
    """:func:`fpg_gym.reconstruct.pending.output_pose`: the normalised pose ``local`` ``(20, 3)``
    retargeted to ``lengths`` (``retarget_pose``, float32), then put back at ``root`` and
    ``yaw`` in float64 (``place_pose``) and returned as float32 (the numpy code's operations)."""
    retargeted = retarget_pose(local, lengths, bones, rest_directions)
    placed = place_pose(retargeted.astype(np.float64), root, yaw, np.bool_(True))  # not Literal
    return placed.astype(np.float32)


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
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


@numba.njit(**JIT_OPTIONS)
def settle_lengths(estimate, lengths, low, high, rate, spread):
    """:meth:`BoneSettler.update <fpg_gym.reconstruct.bones.BoneSettler.update>` after settling:
    each bone of ``lengths`` ``(19,)`` moves toward ``estimate`` by at most ``rate`` and keeps
    its range since settling (``low``, ``high``, updated in place) within ``spread`` (the numpy
    code's operations). Returns the new lengths, the largest change (``np.max`` of its
    magnitudes) and the bones that moved more than 1e-9 m (ascending)."""
    count = estimate.shape[0]
    moved = np.empty(count)
    largest = 0.0
    changed = np.empty(count, dtype=np.int64)
    number = 0
    for b in range(count):
        step = scalar_minimum(scalar_maximum(estimate[b] - lengths[b], -rate), rate)
        value = scalar_minimum(scalar_maximum(lengths[b] + step, high[b] - spread), low[b] + spread)
        moved[b] = value
        low[b] = scalar_minimum(low[b], value)
        high[b] = scalar_maximum(high[b], value)
        change = abs(value - lengths[b])
        largest = scalar_maximum(largest, change)
        if change > 1e-9:
            changed[number] = b
            number += 1
    return moved, largest, changed[:number]
