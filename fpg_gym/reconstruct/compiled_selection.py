"""Candidate selection's compiled (numba) kernels; imported only when ``fpg-gym[fast]`` is
installed (:mod:`fpg_gym.reconstruct.selection` falls back to numpy without it).

Each kernel scores a set of nodes in one pass, without materialising their poses (the graph
walk retargets each node on the fly), keeps the ``k``-th smallest score in a small max-heap and
returns the ``k`` best ordered by (score, node id). Scores are float64 sums of the same terms as
the numpy scores (Shum Eq. 9; FPG Eq. 5-7), so they agree with numpy's to a few units in the
last place. The FPG kernels lay a block of nodes out joint-major and vectorise across nodes,
summing each node's joints in order; the Eq. 9 kernel lets LLVM reassociate the 60-term sum of
a node (``fastmath`` ``reassoc``/``contract``), the same code for every node. Either way a
node's score depends on its pose only, not on its position in a batch (unlike a BLAS product),
so identical poses tie exactly and are ordered by node id.

Module-level functions so that numba's disk cache (``cache=True``) finds them in a new process.
"""

from __future__ import annotations

import numba
import numpy as np

from fpg_gym.core.compiled import JIT_OPTIONS

__all__ = ["fpg_walk_best", "neighbourhood", "shum_full_best"]

_FAST = {"reassoc", "contract"}


@numba.njit(**JIT_OPTIONS)
def _heap_push(heap, size, k, value):
    """Keep the ``k`` smallest values seen in the max-heap ``heap[:size]``; new size."""
    if size < k:  # sift up
        i = size
        heap[i] = value
        while i > 0:
            parent = (i - 1) // 2
            if heap[parent] >= heap[i]:
                break
            heap[parent], heap[i] = heap[i], heap[parent]
            i = parent
        return size + 1
    if value >= heap[0]:
        return size
    heap[0] = value  # replace the largest, sift down
    i = 0
    while True:
        left = 2 * i + 1
        if left >= k:
            break
        child = left
        if left + 1 < k and heap[left + 1] > heap[left]:
            child = left + 1
        if heap[child] <= heap[i]:
            break
        heap[child], heap[i] = heap[i], heap[child]
        i = child
    return size


@numba.njit(**JIT_OPTIONS)
def _kth(scores, k):
    """The ``k``-th smallest of ``scores`` (NaN counts as +inf; +inf when ``k >= len``), from a
    max-heap of the ``k`` smallest seen in one pass."""
    count = scores.shape[0]
    if count <= k:
        return np.inf
    heap = np.empty(k, dtype=np.float64)
    for i in range(k):
        value = scores[i]
        _heap_push(heap, i, k, value if value == value else np.inf)
    for i in range(k, count):
        if scores[i] < heap[0]:  # False for NaN
            _heap_push(heap, k, k, scores[i])
    return heap[0]


@numba.njit(**JIT_OPTIONS)
def _best(nodes, scores, k):
    """The ``k`` nodes of least score, ordered by (score, node id); ``(nodes, scores, tied)``.

    The nodes at or below the ``k``-th score (:func:`_kth`; NaN last) are sorted by (score,
    node id). ``tied`` (and empty arrays) when more than ``k`` of them are: a tie across the
    cut, where the numpy path keeps whichever tied nodes its partition leaves, so the caller
    runs it then.
    """
    kth = _kth(scores, k)
    count = scores.shape[0]
    taken = 0
    for i in range(count):
        if scores[i] <= kth or kth == np.inf:
            taken += 1
    if taken > k:  # the caller runs the numpy path (and no quadratic sort of a large tie)
        return np.empty(0, dtype=np.int64), np.empty(0, dtype=np.float64), True
    out = np.empty(taken, dtype=np.int64)
    kept = np.empty(taken, dtype=np.float64)
    taken = 0
    for i in range(count):
        if scores[i] <= kth or kth == np.inf:
            out[taken] = nodes[i]
            kept[taken] = scores[i]
            taken += 1
    for i in range(1, taken):  # insertion sort by (score, node), NaN last: few nodes
        node = out[i]
        value = kept[i]
        key = value if value == value else np.inf
        j = i - 1
        while j >= 0:
            other = kept[j] if kept[j] == kept[j] else np.inf
            if other < key or (other == key and out[j] < node):
                break
            out[j + 1] = out[j]
            kept[j + 1] = kept[j]
            j -= 1
        out[j + 1] = node
        kept[j + 1] = value
    return out, kept, False


@numba.njit(**JIT_OPTIONS)
def neighbourhood(previous, indptr, indices, marks):
    """The ``previous`` nodes and their CSR neighbours, unique, in visiting order (FPG §6.2).
    ``marks`` (one bool per node) is all False on entry and on return."""
    total = previous.shape[0]
    for p in previous:
        total += indptr[p + 1] - indptr[p]
    pool = np.empty(total, dtype=np.int64)
    count = 0
    for p in previous:
        if not marks[p]:
            marks[p] = True
            pool[count] = p
            count += 1
        for e in range(indptr[p], indptr[p + 1]):
            v = np.int64(indices[e])
            if not marks[v]:
                marks[v] = True
                pool[count] = v
                count += 1
    for i in range(count):
        marks[pool[i]] = False
    return pool[:count]


#: Nodes per block of the FPG kernels: their joints are laid out joint-major (``(20, BLOCK)``
#: per coordinate) so that the per-joint distances vectorise across nodes.
BLOCK = 128


@numba.njit(**JIT_OPTIONS)
def _fpg_block(xs, ys, zs, m, q, pred, ws, wc, has_prediction, scores, offset):
    """FPG §6.2 ``S = Ss + Sc`` of ``m`` nodes whose joints are ``xs, ys, zs`` ``(20, BLOCK)``
    float64, into ``scores[offset:offset + m]``: Eq. 5 ``Ss = sum_j ws_j ||p_d(j) - p_k(j)||``
    and Eq. 6 ``Sc = sum_j wc_j ||p_d(j) - p_pred(j)||`` (``ws = R / 20``, ``wc = (1 - R) /
    20``), summed over joints in order for every node (no reassociation: a node's score does
    not depend on its block)."""
    acc = np.zeros(m)
    for j in range(xs.shape[0]):
        qx, qy, qz = q[j, 0], q[j, 1], q[j, 2]
        a = ws[j]
        if has_prediction:
            px, py, pz = pred[j, 0], pred[j, 1], pred[j, 2]
            c = wc[j]
            for t in range(m):
                dx = xs[j, t] - qx
                dy = ys[j, t] - qy
                dz = zs[j, t] - qz
                ex = xs[j, t] - px
                ey = ys[j, t] - py
                ez = zs[j, t] - pz
                acc[t] += a * np.sqrt(dx * dx + dy * dy + dz * dz) + c * np.sqrt(
                    ex * ex + ey * ey + ez * ez
                )
        else:
            for t in range(m):
                dx = xs[j, t] - qx
                dy = ys[j, t] - qy
                dz = zs[j, t] - qz
                acc[t] += a * np.sqrt(dx * dx + dy * dy + dz * dz)
    for t in range(m):
        scores[offset + t] = acc[t]


@numba.njit(**JIT_OPTIONS)
def _gather_block(poses, nodes, start, m, xs, ys, zs):
    """Joints of ``nodes[start:start + m]`` from ``poses`` ``(N, 20, 3)``, joint-major float64."""
    for t in range(m):
        pose = poses[nodes[start + t]]
        for j in range(pose.shape[0]):
            xs[j, t] = pose[j, 0]
            ys[j, t] = pose[j, 1]
            zs[j, t] = pose[j, 2]


@numba.njit(**JIT_OPTIONS)
def _retarget_block(directions, roots, lengths, bones, nodes, start, m, xs, ys, zs):
    """Joints of ``nodes[start:start + m]`` retargeted in float64: the root plus the unit bone
    ``directions`` times ``lengths`` (rounded to float32, as ``NodeDatabase.poses_for`` takes
    them), summed from the root along ``bones`` ((parent, child), parents first),
    joint-major."""
    for t in range(m):
        node = nodes[start + t]
        xs[0, t] = roots[node, 0]
        ys[0, t] = roots[node, 1]
        zs[0, t] = roots[node, 2]
    for b in range(bones.shape[0]):  # bone by bone, the nodes side by side
        parent = bones[b, 0]
        child = bones[b, 1]
        length = np.float64(np.float32(lengths[b]))  # the float32 lengths of poses_for
        for t in range(m):
            node = nodes[start + t]
            xs[child, t] = xs[parent, t] + np.float64(directions[node, b, 0]) * length
            ys[child, t] = ys[parent, t] + np.float64(directions[node, b, 1]) * length
            zs[child, t] = zs[parent, t] + np.float64(directions[node, b, 2]) * length


@numba.njit(**JIT_OPTIONS)
def _fpg_weights(reliability, has_prediction):
    """FPG Eq. 5-6's joint weights ``R / 20`` and ``(1 - R) / 20`` (zeros without a
    prediction) as :func:`fpg_gym.reconstruct.selection.fpg_score` forms them from float32
    poses: ``R`` rounded to float32, the arithmetic in float32; float64 out."""
    joints = reliability.shape[0]
    ws = np.empty(joints)
    wc = np.zeros(joints)
    count = np.float32(joints)
    for j in range(joints):
        r = np.float32(reliability[j])
        ws[j] = np.float64(r / count)
        if has_prediction:
            wc[j] = np.float64((np.float32(1.0) - r) / count)
    return ws, wc


@numba.njit(**JIT_OPTIONS)
def fpg_walk_best(
    pool,
    poses,
    directions,
    roots,
    lengths,
    bones,
    retarget,
    pose,
    prediction,
    reliability,
    has_prediction,
    k,
):
    """FPG's score of the ``pool`` nodes (the graph walk's neighbourhood, or every node); the
    ``k`` best (:func:`_best`).

    ``pose`` and ``prediction`` ``(20, 3)`` are the sensor pose ``p_k`` and ``p_l + v_l dt``
    (read in float64), ``reliability`` ``(20,)`` ``R`` (:func:`_fpg_weights`). With
    ``retarget``, a node's pose is retargeted on the fly to ``lengths`` ``(19,)``
    (:func:`_retarget_block`), otherwise read from ``poses``; neither is stored.
    """
    count = pool.shape[0]
    scores = np.empty(count, dtype=np.float64)
    joints = poses.shape[1]
    ws, wc = _fpg_weights(reliability, has_prediction)
    xs = np.empty((joints, BLOCK))
    ys = np.empty((joints, BLOCK))
    zs = np.empty((joints, BLOCK))
    for start in range(0, count, BLOCK):
        m = min(BLOCK, count - start)
        if retarget:
            _retarget_block(directions, roots, lengths, bones, pool, start, m, xs, ys, zs)
        else:
            _gather_block(poses, pool, start, m, xs, ys, zs)
        _fpg_block(xs, ys, zs, m, pose, prediction, ws, wc, has_prediction, scores, start)
    return _best(pool, scores, k)


@numba.njit(**JIT_OPTIONS, fastmath=_FAST)
def _shum_scores(poses, q, reliability, scores):
    """Shum Eq. 9 ``D = sum_j R(j) ||p_d(j) - p_k(j)||^2`` of every node of ``poses``
    ``(N, 20, 3)`` against ``q`` ``(20, 3)`` float64."""
    flat = q.reshape(-1)
    w = np.empty(flat.shape[0])
    for j in range(reliability.shape[0]):
        w[3 * j] = w[3 * j + 1] = w[3 * j + 2] = reliability[j]
    rows = poses.reshape(poses.shape[0], -1)
    for i in range(rows.shape[0]):
        row = rows[i]
        s = 0.0
        for c in range(row.shape[0]):
            d = np.float64(row[c]) - flat[c]
            s += w[c] * d * d
        scores[i] = s


@numba.njit(**JIT_OPTIONS)
def shum_full_best(poses, q, reliability, k):
    """Shum Eq. 9 of every node of ``poses`` ``(N, 20, 3)`` (C-contiguous); the ``k`` best
    (:func:`_best`)."""
    n = poses.shape[0]
    scores = np.empty(n, dtype=np.float64)
    _shum_scores(poses, q, reliability, scores)
    return _best(np.arange(n), scores, k)
