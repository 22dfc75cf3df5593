"""Private machinery behind :meth:`fpg_gym.graph.FilteredPoseGraph.build` (FPG §4.2, Alg. 1–4).

Every decision uses the exact FPG Eq. 1 distance (:func:`fpg_gym.core.poses.pose_distance`,
float64); the spatial index only proposes candidate pairs. ``cKDTree`` on the 60-vector with the
Chebyshev norm (``p=inf``) is a conservative prefilter: ``max_j ||a(j) - b(j)|| <= r`` implies
``max_{j,c} |a(j,c) - b(j,c)| <= r``, and the prefilter radius is widened by a relative 1e-6 so
that rounding can never hide a pair. The results therefore equal the naive loop-based algorithms
exactly (``tests/test_graph.py`` checks it).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from fpg_gym.core import skeleton
from fpg_gym.core.poses import pose_distance

#: Pairs whose exact distance is computed at once (bounds the float64 temporaries, ~32 MiB each).
_PAIR_CHUNK = 1 << 16
#: Relative widening of prefilter radii, far above float64 rounding of Eq. 1.
_PREFILTER_SLACK = 1e-6

#: Adaptive batch sizes of the inter-clip filter (see :func:`inter_clip_filter`).
_MIN_BATCH, _MAX_BATCH, _TARGET_SURVIVORS = 256, 2048, 256

Progress = Callable[[int], object]


def _noop(_: int) -> None:
    return None


def _prefilter_radius(threshold: float) -> float:
    return float(threshold) * (1.0 + _PREFILTER_SLACK) + 1e-12


def pair_distances(flat: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Eq. 1 distances between rows ``first[k]`` and ``second[k]`` of ``flat`` (M, 60), chunked."""
    out = np.empty(len(first), dtype=np.float64)
    shape = (-1, skeleton.NUM_JOINTS, 3)
    for start in range(0, len(first), _PAIR_CHUNK):
        stop = start + _PAIR_CHUNK
        out[start:stop] = pose_distance(
            flat[first[start:stop]].reshape(shape), flat[second[start:stop]].reshape(shape)
        )
    return out


# --------------------------------------------------------------------------- Alg. 1


def intra_clip_filter(
    poses: np.ndarray,
    offsets: np.ndarray,
    thres1: float,
    *,
    block: int = 8,
    progress: Progress = _noop,
) -> tuple[np.ndarray, np.ndarray]:
    """FPG Alg. 1 for every clip at once.

    In each clip the first frame is kept; a later frame is kept when its Eq. 1 distance to the
    last kept frame exceeds ``thres1``, and that distance is recorded. The scan is sequential
    within a clip but vectorised across clips: each step compares every clip's last kept frame
    with its next ``block`` frames and jumps to the first one beyond ``thres1``.

    Parameters
    ----------
    poses : ndarray, shape (M, 20, 3)
        The frames of all clips, concatenated.
    offsets : ndarray, shape (C + 1,)
        Clip ``c`` is ``poses[offsets[c]:offsets[c + 1]]`` (every clip non-empty).
    thres1 : float
    block : int
        Frames compared per clip and step (only affects speed).
    progress : callable
        Called with the number of frames newly scanned.

    Returns
    -------
    kept : ndarray (K,), int64
        Indices into ``poses`` of the kept frames, ascending (clip order, then frame order).
    recorded : ndarray (K,), float64
        For each kept frame, its distance to the previous kept frame of its clip; NaN for the
        first frame of a clip.
    """
    starts = np.asarray(offsets[:-1], dtype=np.int64)
    ends = np.asarray(offsets[1:], dtype=np.int64)
    last = starts.copy()
    pointer = starts + 1
    new_kept: list[np.ndarray] = [starts]
    new_dist: list[np.ndarray] = [np.full(len(starts), np.nan)]
    steps = np.arange(block, dtype=np.int64)
    active = np.flatnonzero(pointer < ends)
    progress(len(starts))
    while active.size:
        frames = pointer[active, None] + steps
        end = ends[active, None]
        valid = frames < end
        distance = pose_distance(poses[last[active]][:, None], poses[np.minimum(frames, end - 1)])
        exceed = valid & (distance > thres1)  # Alg. 1: keep when dist > thres1
        found = exceed.any(axis=1)
        first = exceed.argmax(axis=1)
        rows = np.flatnonzero(found)
        chosen = frames[rows, first[rows]]
        new_kept.append(chosen)
        new_dist.append(distance[rows, first[rows]])
        before = pointer[active].copy()
        hit = active[rows]
        last[hit] = chosen
        pointer[hit] = chosen + 1
        pointer[active[~found]] += block
        np.minimum(pointer, ends, out=pointer)
        progress(int((pointer[active] - before).sum()))
        active = active[pointer[active] < ends[active]]
    kept = np.concatenate(new_kept)
    recorded = np.concatenate(new_dist)
    order = np.argsort(kept, kind="stable")
    return kept[order], recorded[order]


def compute_thres2(recorded: np.ndarray) -> float:
    """``thres2 = mean + 2·std`` of the distances recorded by Alg. 1 (population std).

    Raises
    ------
    ValueError
        If no distance was recorded (every clip reduced to its first frame).
    """
    values = recorded[np.isfinite(recorded)]
    if values.size == 0:
        raise ValueError(
            "thres2: cannot be computed, the intra-clip filter recorded no distance (every clip "
            "kept only its first frame); pass thres2 explicitly or lower thres1"
        )
    return float(np.mean(values) + 2.0 * np.std(values))


# --------------------------------------------------------------------------- Alg. 3


class _GrowingIndex:
    """A set of points supporting insertion and radius queries: a logarithmic family of
    ``cKDTree`` blocks (Bentley–Saxe), so that n insertions cost O(n log² n)."""

    def __init__(self, flat: np.ndarray) -> None:
        self._flat = flat
        self._blocks: list[tuple[cKDTree, np.ndarray]] = []

    def add(self, rows: np.ndarray) -> None:
        if rows.size == 0:
            return
        while self._blocks and len(self._blocks[-1][1]) <= len(rows):
            rows = np.concatenate([self._blocks.pop()[1], rows])
        self._blocks.append((cKDTree(self._flat[rows]), rows))

    def near_any(self, rows: np.ndarray, threshold: float, radius: float) -> np.ndarray:
        """Mask over ``rows``: is some stored row within Eq. 1 distance ``threshold``?

        Per block, the Chebyshev-nearest stored row decides most rows at once (no neighbour
        within ``radius``: certainly far; nearest within ``threshold``: near); only the rest
        enumerate their whole Chebyshev ball.
        """
        near = np.zeros(len(rows), dtype=bool)
        for tree, stored in self._blocks:
            open_ = np.flatnonzero(~near)
            if open_.size == 0:
                break
            points = self._flat[rows[open_]]
            _, nearest = tree.query(points, k=1, p=np.inf, distance_upper_bound=radius, workers=-1)
            has = nearest < len(stored)
            candidates = open_[has]
            close = pair_distances(self._flat, rows[candidates], stored[nearest[has]]) <= threshold
            near[candidates[close]] = True
            undecided = candidates[~close]
            if undecided.size == 0:
                continue
            balls = tree.query_ball_point(
                self._flat[rows[undecided]], radius, p=np.inf, workers=-1, return_sorted=False
            )
            counts = np.fromiter((len(b) for b in balls), dtype=np.int64, count=len(balls))
            first = np.repeat(undecided, counts)
            second = stored[np.concatenate([np.asarray(b, dtype=np.int64) for b in balls])]
            close = pair_distances(self._flat, rows[first], second) <= threshold
            near[first[close]] = True
        return near


def inter_clip_filter(
    flat: np.ndarray,
    thres1: float,
    *,
    batch: int | None = None,
    progress: Progress = _noop,
) -> np.ndarray:
    """FPG Alg. 3, greedy in input order: row ``i`` of ``flat`` is kept unless its Eq. 1
    distance to some row kept before it is ``<= thres1``.

    Exactly the naive double loop, computed in batches: each batch is first checked against the
    rows kept so far (a growing KD-tree index), then the survivors' conflicts inside the batch
    are resolved in order (a survivor is kept unless an earlier kept survivor is within thres1).

    Parameters
    ----------
    flat : ndarray, shape (M, 60), float64
        Candidate poses in processing order.
    batch : int, optional
        Fixed batch size. By default it adapts so that about ``_TARGET_SURVIVORS`` rows of a
        batch survive the index (the in-batch resolution is quadratic in the survivors).
        Only affects speed.

    Returns
    -------
    ndarray (K,), int64
        Ascending indices of the kept rows.
    """
    radius = _prefilter_radius(thres1)
    index = _GrowingIndex(flat)
    kept_parts: list[np.ndarray] = []
    size = batch or _MIN_BATCH
    start = 0
    while start < len(flat):
        stop = min(start + size, len(flat))
        dropped = index.near_any(np.arange(start, stop), thres1, radius)
        survivors = np.flatnonzero(~dropped)
        keep = _resolve_in_order(flat, start + survivors, thres1, radius)
        new_rows = start + survivors[keep]
        kept_parts.append(new_rows)
        index.add(new_rows)
        progress(stop - start)
        if batch is None:
            rate = max(len(survivors), 1) / (stop - start)
            size = int(np.clip(_TARGET_SURVIVORS / rate, _MIN_BATCH, _MAX_BATCH))
        start = stop
    return np.concatenate(kept_parts) if kept_parts else np.empty(0, np.int64)


def _resolve_in_order(
    flat: np.ndarray, rows: np.ndarray, thres1: float, radius: float
) -> np.ndarray:
    """Greedy among ``rows`` (ascending): a row is kept unless an earlier kept row is within
    thres1. Returns a boolean mask over ``rows``."""
    keep = np.ones(len(rows), dtype=bool)
    if len(rows) < 2:
        return keep
    pairs = cKDTree(flat[rows]).query_pairs(radius, p=np.inf, output_type="ndarray")
    if pairs.size == 0:
        return keep
    pairs = pairs[pair_distances(flat, rows[pairs[:, 0]], rows[pairs[:, 1]]) <= thres1]
    if pairs.size == 0:
        return keep
    earlier = pairs.min(axis=1)
    later = pairs.max(axis=1)
    order = np.argsort(later, kind="stable")
    earlier, later = earlier[order], later[order]
    bounds = np.flatnonzero(np.diff(later)) + 1
    starts = np.concatenate([[0], bounds])
    stops = np.concatenate([bounds, [len(later)]])
    # Sequential by nature (a row's fate depends on earlier fates); one step per conflicted row.
    for lo, hi in zip(starts.tolist(), stops.tolist(), strict=True):
        keep[later[lo]] = not keep[earlier[lo:hi]].any()
    return keep


# --------------------------------------------------------------------------- Alg. 4


def build_edges(flat: np.ndarray, thres2: float) -> tuple[np.ndarray, np.ndarray]:
    """FPG Alg. 4: an undirected edge joins two nodes whose Eq. 1 distance is ``< thres2``.

    Returns the CSR arrays ``indptr`` (N + 1,) int64 and ``indices`` int32: every edge stored in
    both directions, no self loops, each row sorted ascending.
    """
    n = len(flat)
    if n >= 2:
        pairs = cKDTree(flat).query_pairs(
            _prefilter_radius(thres2), p=np.inf, output_type="ndarray"
        )
    else:
        pairs = np.empty((0, 2), dtype=np.int64)
    if pairs.size:
        pairs = pairs[pair_distances(flat, pairs[:, 0], pairs[:, 1]) < thres2]
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]]).astype(np.int64)
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]]).astype(np.int64)
    order = np.lexsort((cols, rows))
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return indptr, cols[order].astype(np.int32)
