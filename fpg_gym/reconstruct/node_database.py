"""The graph's node poses for selection: retargeting, a C-contiguous layout, fast scores.

Weighted squared distances are inner products in disguise (Shum Eq. 9): with per-joint weights
``w_j`` and ``d_j = ||x(j) - q(j)||``,

``sum_j w_j d_j^2 = <[|x(j)|^2, x], [w, -2 w * q]> + sum_j w_j |q(j)|^2``

so :class:`NodeDatabase` keeps every node's *augmented* vector ``[|x(j)|^2 (20), x (60)]`` and
scores all nodes against one or more weighted queries with one matrix-vector (or small matrix)
product. The table is float32 (selection reads every node each frame, so bytes are time); each
value comes with a rigorous bound on its rounding error, and the selectors re-score the few
nodes within that bound of the cut exactly (:func:`fpg_gym.reconstruct.selection.shum_best_k`),
so the selected nodes are exactly those of the direct scores.
"""

from __future__ import annotations

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.poses import as_poses, bone_directions

__all__ = ["AUGMENTED_SIZE", "NodeDatabase", "augmented_queries"]

JOINTS = skeleton.NUM_JOINTS
POSE_SIZE = 3 * JOINTS
#: Length of a node's augmented vector ``[|x(j)|^2, x]``.
AUGMENTED_SIZE = JOINTS + POSE_SIZE
#: float32 unit roundoff.
_U32 = float(np.finfo(np.float32).eps) / 2


def augmented_queries(
    joint_weights: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Query vectors and constants of weighted squared distances (Eq. 9 as an inner product).

    Parameters
    ----------
    joint_weights : ndarray, shape (m, 20)
        Per-joint weights ``w`` of each of ``m`` queries.
    points : ndarray, shape (m, 60)
        Query poses ``q`` (flat).

    Returns
    -------
    vectors : ndarray, shape (80, m) float64
        ``[w, -2 w * q]`` as columns.
    constants : ndarray, shape (m,)
        ``sum_j w_j |q(j)|^2``.
    """
    w = np.asarray(joint_weights, dtype=np.float64)
    q = np.asarray(points, dtype=np.float64)
    wq = np.repeat(w, 3, axis=1) * q
    vectors = np.concatenate([w, -2.0 * wq], axis=1).T
    return np.ascontiguousarray(vectors), np.einsum("mi,mi->m", wq, q)


def _read_only(array: np.ndarray) -> np.ndarray:
    """A read-only view of ``array``."""
    view = array.view()
    view.flags.writeable = False
    return view


class NodeDatabase:
    """The graph's node poses, retargetable to the user's bone lengths.

    Stores each node's root and unit bone directions so that a subset of nodes can be given any
    bone lengths with one matrix product (:data:`fpg_gym.core.skeleton.PATH_MATRIX`). Poses are
    returned C-contiguous ``(M, 20, 3)`` (what the scores read row by row).

    Parameters
    ----------
    poses : array_like, shape (N, 20, 3)
        Normalised node poses.
    refresh_tolerance_m : float
        :meth:`all_poses` (and :meth:`augmented`) recompute their cached retargeted copy of the
        whole database when a bone length moved by more than this since the cache was made.
    """

    def __init__(self, poses: np.ndarray, refresh_tolerance_m: float = 0.005) -> None:
        self.poses = np.ascontiguousarray(as_poses(poses, "poses", ndim=3))
        if len(self.poses) == 0:
            raise ValueError("poses: the database is empty (0 nodes)")
        self._directions = bone_directions(self.poses).astype(np.float32)
        self._roots = self.poses[:, skeleton.ROOT].copy()
        self._directions_view = _read_only(self._directions)
        self._roots_view = _read_only(self._roots)
        self._path = skeleton.PATH_MATRIX.astype(np.float32)
        self.refresh_tolerance_m = refresh_tolerance_m
        self._cache_lengths: np.ndarray | None = None
        self._cache: np.ndarray | None = None
        self._cache_key = b""
        self._augmented: dict[bool, np.ndarray] = {}
        self._column_max: dict[bool, np.ndarray] = {}
        self.refreshes = 0

    def __len__(self) -> int:
        return len(self.poses)

    def poses_for(self, nodes: np.ndarray, lengths: np.ndarray | None) -> np.ndarray:
        """Poses of ``nodes`` ``(M, 20, 3)`` float32, C-contiguous, retargeted to ``lengths``
        when given."""
        nodes = np.asarray(nodes, dtype=np.intp)
        if lengths is None:
            return self.poses[nodes]
        compiled = compiled_module("fpg_gym.core.compiled_poses")
        if compiled is not None:  # the same poses in one call
            out: np.ndarray = compiled.assemble_nodes(
                self._directions,
                self._roots,
                nodes,
                np.asarray(lengths, dtype=np.float64),  # rounded to float32 by the kernel
                skeleton.BONES,
            )
            return out
        vectors = self._directions[nodes] * np.asarray(lengths, dtype=np.float32)[:, None]
        # joint = root + PATH_MATRIX @ bone vectors, as one GEMM ((M*3, 19) x (19, 20)); the
        # sum is copied into the C-contiguous (M, 20, 3) layout the scores read.
        joints = np.tensordot(vectors, self._path, axes=([1], [1])).transpose(0, 2, 1)
        out = np.empty(joints.shape, dtype=np.float32)
        np.add(joints, self._roots[nodes, None, :], out=out)
        return out

    @property
    def directions(self) -> np.ndarray:
        """Unit bone directions ``(N, 19, 3)`` float32 (read-only view)."""
        return self._directions_view

    @property
    def roots(self) -> np.ndarray:
        """Root positions ``(N, 3)`` float32 (read-only view)."""
        return self._roots_view

    def clear_cache(self) -> None:
        """Forget the cached retargeted database (a new stream starts from scratch)."""
        self._cache = None
        self._cache_lengths = None
        self._cache_key = b""
        self._augmented.pop(True, None)

    def all_poses(self, lengths: np.ndarray | None) -> np.ndarray:
        """Every node's pose, retargeted to ``lengths`` (cached; see ``refresh_tolerance_m``)."""
        if lengths is None:
            return self.poses
        lengths = np.asarray(lengths, dtype=np.float64)
        if self._cache is not None and lengths.tobytes() == self._cache_key:
            return self._cache  # the same lengths as last time (settled), no arithmetic
        if (
            self._cache is None
            or self._cache_lengths is None
            or np.max(np.abs(self._cache_lengths - lengths)) > self.refresh_tolerance_m
        ):
            self._cache = self.poses_for(np.arange(len(self)), lengths)
            self._cache_lengths = lengths.copy()
            self._augmented.pop(True, None)
            self.refreshes += 1
        self._cache_key = lengths.tobytes()
        return self._cache

    def augmented(self, lengths: np.ndarray | None) -> np.ndarray:
        """``[|x(j)|^2, x]`` ``(N, 80)`` float32 of :meth:`all_poses` (cached with it)."""
        poses = self.all_poses(lengths)
        key = lengths is not None
        table = self._augmented.get(key)
        if table is None:
            table = np.empty((len(poses), AUGMENTED_SIZE), dtype=np.float32)
            squared = np.einsum("njc,njc->nj", poses, poses, dtype=np.float64)
            table[:, :JOINTS] = squared
            table[:, JOINTS:] = poses.reshape(len(poses), POSE_SIZE)
            self._augmented[key] = table
            self._column_max[key] = np.abs(table).max(axis=0).astype(np.float64)
        return table

    def weighted_squared_distances(
        self, joint_weights: np.ndarray, points: np.ndarray, lengths: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``sum_j w_j ||x(j) - q(j)||^2`` of every node for ``m`` queries, with an error bound.

        One float32 product of the augmented table with ``[w, -2 w * q]``.

        Parameters
        ----------
        joint_weights : ndarray, shape (m, 20)
            Non-negative per-joint weights.
        points : ndarray, shape (m, 60)
        lengths : ndarray, shape (19,) or None
            Retarget the nodes to these bone lengths (see :meth:`all_poses`).

        Returns
        -------
        values : ndarray, shape (N, m) float64
        error : ndarray, shape (m,)
            ``|values - exact| <= error`` for every node: float32 rounding of the table (its
            ``|x(j)|^2`` column), of the query and of an ``80``-term sum, bounded with the
            table's column maxima (Higham's ``gamma_n`` bound, doubled for safety).
        """
        table = self.augmented(lengths)
        vectors, constants = augmented_queries(joint_weights, points)
        values = (table @ vectors.astype(np.float32)).astype(np.float64)
        values += constants
        magnitude = np.abs(vectors).T @ self._column_max[lengths is not None] + np.abs(constants)
        terms = AUGMENTED_SIZE + 3
        error = 2.0 * terms * _U32 / (1.0 - terms * _U32) * magnitude
        return values, error
