"""Candidate selection: the K database poses the latent space is built from.

Two implementations behind one interface (:class:`CandidateSelector`):

* :class:`BruteForceSelector` (Shum 2013, Eq. 9): scores every node with
  ``D = sum_j R(j) ||p_k(j) - p_d(j)||^2`` and keeps the K best. Linear in the database size.
* :class:`GraphSelector` (FPG 2016 §6.2): scores only the previous frame's K nodes and their
  graph neighbours with ``S = Ss + Sc``, where
  ``Ss = mean_j R(j) ||p_k(j) - p_d(j)||`` (FPG Eq. 5) and
  ``Sc = mean_j (1 - R(j)) ||p_l(j) + v_l(j) dt - p_d(j)||`` (FPG Eq. 6; the paper writes a vector
  inside the mean, the evident intent is the joint's distance), ``p_l`` the last reconstruction;
  ``Ss`` alone and a full search on the first frame. Flat in the database size.

Recovery (not in the paper): under a long occlusion the previous nodes can drift into a part of
the graph from which no neighbour matches the sensor any more. When the best graph candidate's
score exceeds ``recovery_factor`` times the running (exponential) average of the best scores of
recent frames, and also ``recovery_min_score`` metres, the graph selector falls back to a full
search over all nodes with the same score ``S`` and records ``recovered=True``.
``recovery_factor=None`` disables the rule (the paper's behaviour).

All candidate poses are *normalised* (root at the origin, facing +Z) and, when reference bone
lengths are given, retargeted to them, so that the sensor pose is compared with database poses of
the user's proportions (:class:`NodeDatabase`).

Compiled kernels (:mod:`fpg_gym.reconstruct.compiled_selection`, with ``fpg-gym[fast]``) run the
full searches and the graph walk in one pass each, without materialising poses (the walk retargets
each node on the fly in float64), and keep the K best by (score, node id). They select what the
numpy paths select: the scores agree to rounding (float64 sums of the same terms on the same float32
poses; for the walk, float64 rather than float32 retargeting, within a bound of float32 rounding
that ``tests/test_fast_selection.py`` states and checks), so the nodes and their order are the same
except between nodes whose scores agree to that rounding. There the numpy order is itself an
artefact of rounding that depends on a node's position in its batch (BLAS products round a row
differently by position: ``poses_for`` of a subset differs in the last bits from the same nodes'
rows of a larger call), while the compiled score depends on the pose alone: identical poses tie
exactly and are ordered by node id; a tie across the K-th place (every node scores 0 when no joint
is reliable and there is no prediction) runs the numpy path, which keeps the tied nodes its
partition leaves, as before. The walk's kernel also gives its K poses, those of
:meth:`NodeDatabase.poses_for`.
Without numba the numpy paths run (the previous implementation, unchanged).
``tests/test_fast_selection.py`` compares both with the reference of
``tests/reference_selection.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from types import ModuleType
from typing import Protocol, runtime_checkable

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.reconstruct.node_database import NodeDatabase

# --------------------------------------------------------------------------- scores


def shum_score(pose: np.ndarray, reliability: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """Shum Eq. 9: ``D = sum_j R(j) ||p_k(j) - p_d(j)||^2`` for each candidate.

    Parameters
    ----------
    pose : ndarray, shape (20, 3)
        Normalised sensor pose ``p_k``.
    reliability : ndarray, shape (20,)
    candidates : ndarray, shape (M, 20, 3)

    Returns
    -------
    ndarray, shape (M,)
    """
    diff = np.asarray(candidates) - np.asarray(pose)
    return np.einsum("mjc,mjc->mj", diff, diff) @ np.asarray(reliability, dtype=diff.dtype)


def fpg_score(
    pose: np.ndarray,
    reliability: np.ndarray,
    candidates: np.ndarray,
    prediction: np.ndarray | None = None,
) -> np.ndarray:
    """FPG Eq. 5-7: ``S = Ss + Sc`` for each candidate (``Ss`` alone without a prediction).

    Parameters
    ----------
    pose : ndarray, shape (20, 3)
        Normalised sensor pose ``p_k``.
    reliability : ndarray, shape (20,)
    candidates : ndarray, shape (M, 20, 3)
    prediction : ndarray, shape (20, 3), optional
        Continuity prediction ``p_l + v_l dt`` in the same frame as ``pose``.

    Returns
    -------
    ndarray, shape (M,)
    """
    candidates = np.asarray(candidates)
    reliability = np.asarray(reliability, dtype=candidates.dtype)
    diff = candidates - np.asarray(pose)
    joints = skeleton.NUM_JOINTS
    score = np.sqrt(np.einsum("mjc,mjc->mj", diff, diff)) @ (reliability / joints)  # Ss, Eq. 5
    if prediction is not None:
        diff = candidates - np.asarray(prediction)
        score = score + np.sqrt(np.einsum("mjc,mjc->mj", diff, diff)) @ (
            (1.0 - reliability) / joints
        )  # Sc, Eq. 6
    return score


def _best_k(scores: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` smallest scores, sorted by (score, index) for determinism."""
    k = min(k, len(scores))
    if k < len(scores):
        part = np.argpartition(scores, k - 1)[:k]
    else:
        part = np.arange(len(scores))
    return part[np.lexsort((part, scores[part]))]


# --------------------------------------------------------------------------- compiled kernels


def _compiled() -> ModuleType | None:
    """The compiled selection kernels, or None without numba (imported once,
    :func:`~fpg_gym.core.compiled.compiled_module`)."""
    return compiled_module("fpg_gym.reconstruct.compiled_selection")


def compiled_available() -> bool:
    """Whether selection runs the compiled kernels (numba installed)."""
    return _compiled() is not None


def _as_joints(pose: np.ndarray) -> np.ndarray:
    """``pose`` as a C-contiguous float64 ``(20, 3)`` array."""
    return np.ascontiguousarray(pose, dtype=np.float64).reshape(skeleton.NUM_JOINTS, 3)


def _walk_query(query: SelectionQuery) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """The query as :func:`~fpg_gym.reconstruct.compiled_selection.fpg_walk_best` reads it:
    the sensor pose, the prediction (zeros without one), ``R`` float64 and whether there is a
    prediction."""
    prediction = query.prediction
    return (
        np.asarray(query.pose),
        _NO_PREDICTION if prediction is None else np.asarray(prediction, dtype=np.float64),
        np.asarray(query.reliability, dtype=np.float64),
        prediction is not None,
    )


# --------------------------------------------------------------------------- interface


@dataclass(frozen=True)
class SelectionQuery:
    """What a selector needs for one frame.

    Attributes
    ----------
    pose : ndarray, shape (20, 3)
        Normalised sensor pose ``p_k``.
    reliability : ndarray, shape (20,)
    prediction : ndarray, shape (20, 3) or None
        Continuity prediction ``p_l + v_l dt`` (None on the first frame or after a gap).
    lengths : ndarray, shape (19,) or None
        Bone lengths to retarget the candidates to (None keeps the database's).
    """

    pose: np.ndarray
    reliability: np.ndarray
    prediction: np.ndarray | None = None
    lengths: np.ndarray | None = None


@dataclass(frozen=True)
class Selection:
    """The K candidates of one frame, best first.

    Attributes
    ----------
    nodes : ndarray, shape (K,), int64
        Node ids, sorted by score (best first).
    poses : ndarray, shape (K, 20, 3), float32
        Their poses (normalised, retargeted).
    scores : ndarray, shape (K,)
        Their scores (lower is better; Eq. 9 or FPG's S).
    num_scored : int
        How many nodes were scored this frame.
    full_search : bool
        Whether every node was scored.
    recovered : bool
        Whether the recovery rule triggered the full search.
    """

    nodes: np.ndarray
    poses: np.ndarray
    scores: np.ndarray
    num_scored: int
    full_search: bool
    recovered: bool = False


@runtime_checkable
class CandidateSelector(Protocol):
    """Picks the K candidate poses of a frame. ``reset()`` starts a new stream."""

    k: int
    database: NodeDatabase

    def select(self, query: SelectionQuery) -> Selection:
        """The K best candidates for ``query``."""
        ...

    def reset(self) -> None:
        """Forget the previous frame (the next call is a first frame)."""
        ...


class BruteForceSelector:
    """Shum 2013 §V: score every node with Eq. 9 and keep the K best.

    Parameters
    ----------
    database : NodeDatabase or array_like (N, 20, 3)
    k : int
        Candidates per frame (30 in both papers).
    score : {"shum", "fpg"}
        ``"shum"`` is Eq. 9 (the paper); ``"fpg"`` uses FPG's ``S = Ss + Sc`` over all nodes (for
        ablations that separate the score from the graph).
    """

    def __init__(self, database: NodeDatabase | np.ndarray, k: int = 30, score: str = "shum"):
        self.database = database if isinstance(database, NodeDatabase) else NodeDatabase(database)
        if k < 1:
            raise ValueError(f"k: expected >= 1, got {k}")
        if score not in ("shum", "fpg"):
            raise ValueError(f"score: expected 'shum' or 'fpg', got {score!r}")
        self.k = k
        self.score = score

    def reset(self) -> None:
        """Nothing to forget: every frame is a full search."""

    def select(self, query: SelectionQuery) -> Selection:
        """Score all nodes and return the K best (exact; see :func:`shum_best_k`,
        :func:`fpg_best_k`)."""
        if self.score == "shum":
            best, scores = shum_best_k(self.database, query, self.k)
        else:
            best, scores = fpg_best_k(self.database, query, self.k)
        return Selection(
            nodes=best.astype(np.int64),
            poses=self.database.all_poses(query.lengths)[best],
            scores=scores,
            num_scored=len(self.database),
            full_search=True,
        )


#: Below this many nodes :func:`shum_best_k` scores every node directly (measured faster).
GEMV_MIN_NODES = 512


def shum_best_k(
    database: NodeDatabase, query: SelectionQuery, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nodes of least Shum Eq. 9 score over the whole database, best first.

    One float32 product of the augmented node table with ``[R, -2 R * p_k]`` (see
    :mod:`fpg_gym.reconstruct.node_database`) scores every node to within a known rounding
    bound ``e``; the nodes within ``2 e`` of the ``k``-th approximate score (a few more than
    ``k``) are re-scored exactly with :func:`shum_score`. The result equals scoring every node
    with :func:`shum_score`: same nodes, same order, same ties. Databases of fewer than
    :data:`GEMV_MIN_NODES` nodes are scored directly. With numba, one compiled pass scores
    every node in float64 and keeps the ``k`` best instead: the same nodes and order up to
    near-ties within rounding (module docstring); on an exact tie across the ``k``-th place the
    numpy path runs.

    Returns
    -------
    nodes : ndarray, shape (k,)
    scores : ndarray, shape (k,) float64
    """
    reliability = np.asarray(query.reliability, dtype=np.float64)
    compiled = _compiled()
    if compiled is not None:  # Shum Eq. 9 of every node
        nodes, scores, tied = compiled.shum_full_best(
            database.all_poses(query.lengths), _as_joints(query.pose), reliability, k
        )
        if not tied:
            return nodes, scores
        # a tie across the cut (e.g. only the root, at the origin in every pose, is reliable):
        # the numpy path below, whose partition picks the tied nodes kept
    if not reliability.any():  # every score is 0: a tie of all nodes, keep the first k
        first = np.arange(min(k, len(database)))
        return first, np.zeros(len(first))
    if len(database) < GEMV_MIN_NODES:  # fewer numpy calls: score every node directly
        scores = shum_score(query.pose, reliability, database.all_poses(query.lengths))
        best = _best_k(scores, k)
        return best, scores[best].astype(np.float64)
    point = np.asarray(query.pose, dtype=np.float64).reshape(1, -1)
    values, error = database.weighted_squared_distances(reliability[None], point, query.lengths)
    approx = values[:, 0]
    if k < len(approx):
        kth = np.partition(approx, k - 1)[k - 1]
        # Any node of the exact best k is within 2 e of the k-th approximate score.
        shortlist = np.flatnonzero(approx <= kth + 2.0 * error[0])
    else:
        shortlist = np.arange(len(approx))
    candidates = database.all_poses(query.lengths)[shortlist]
    scores = shum_score(query.pose, reliability, candidates)
    best = _best_k(scores, k)
    return shortlist[best], scores[best].astype(np.float64)


def fpg_best_k(
    database: NodeDatabase, query: SelectionQuery, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nodes of least FPG score ``S = Ss + Sc`` over the whole database, best first.

    Scores every node with :func:`fpg_score` (with numba: one compiled pass, module
    docstring). (``S`` sums joint distances, not squares, so it is no inner product; a
    shortlist from bounds by weighted squared distances, ``sqrt(sum a^2 d^2) <= sum a d <=
    sqrt(sum a) sqrt(sum a d^2)``, was measured: the bounds differ by up to ``sqrt(20)`` and
    kept nearly every node, 0.5-0.9x the direct score.)

    Returns
    -------
    nodes : ndarray, shape (k,)
    scores : ndarray, shape (k,) float64
    """
    poses = database.all_poses(query.lengths)
    compiled = _compiled()
    if compiled is not None:
        # FPG Eq. 5-7 of every node: the walk's kernel with the walk's argument types (one
        # compiled specialisation for both), reading ``poses`` (not retargeting)
        nodes, scores, tied = compiled.fpg_walk_best(
            np.arange(len(poses)),
            poses,
            database.directions,
            database.roots,
            _UNIT_LENGTHS,
            _BONES,
            False,
            *_walk_query(query),
            k,
        )
        if not tied:
            return nodes, scores
    # without numba, or a tie across the cut (e.g. no reliable joint and no prediction: every
    # node scores 0): the numpy path, whose partition picks the tied nodes kept
    scores = fpg_score(query.pose, query.reliability, poses, query.prediction)
    best = _best_k(scores, k)
    return best, scores[best].astype(np.float64)


#: Cost of walking (retargeting and scoring) one neighbourhood node, in units of scoring one
#: node of the full search (cached poses): measured 1.6-3x on this project's 2-core machine.
WALK_NODE_COST = 2.5
#: Fixed cost of a walk (the neighbourhood union), in the same units.
WALK_FIXED_COST = 200.0
#: The same two costs for the compiled kernels: a walked node (random access, retargeted on
#: the fly) cost 3-4x a node of the compiled full search (sequential, cached poses) on a
#: 99k-node graph (about 300 vs 77 ns); the fixed cost is the union and the Python around it.
COMPILED_WALK_NODE_COST = 3.5
COMPILED_WALK_FIXED_COST = 500.0

_BONES = np.ascontiguousarray(skeleton.BONES, dtype=np.int64)
_UNIT_LENGTHS = np.ones(skeleton.NUM_BONES)  # unused when not retargeting
_NO_PREDICTION = np.zeros((skeleton.NUM_JOINTS, 3))  # unused without a prediction


def walk_cost(pool_size: int, compiled: bool) -> float:
    """Estimated cost of a graph walk over ``pool_size`` nodes, in full-search node units (the
    ``auto`` strategy searches every node when this is at least the database size)."""
    if compiled:
        return COMPILED_WALK_NODE_COST * pool_size + COMPILED_WALK_FIXED_COST
    return WALK_NODE_COST * pool_size + WALK_FIXED_COST


class GraphSelector:
    """FPG 2016 §6.2: search the graph from the previous frame's K nodes.

    Parameters
    ----------
    graph : FilteredPoseGraph-like
        Needs ``poses`` (N, 20, 3) and ``neighbors_of(nodes) -> ndarray`` (or CSR ``indptr`` /
        ``indices``).
    k : int
        Candidates per frame (30).
    recovery_factor : float or None
        Full search when the best score exceeds this multiple of the running average of the best
        scores (3.0); None disables recovery.
    recovery_min_score : float
        ... and exceeds this absolute score in metres (0.05).
    recovery_smoothing : float
        Weight of the newest frame in the running average (0.1).
    database : NodeDatabase, optional
        Share one database between selectors.
    strategy : {"walk", "auto"}
        ``"walk"`` (FPG): score the neighbourhood. ``"auto"``: score the neighbourhood unless
        a full search costs less by the estimate :func:`walk_cost` of the neighbourhood
        against ``|nodes|`` (deterministic, from sizes only); the full
        search then gives the best K of all nodes by the same score (``full_search=True``).
        Dense graphs (a large mean degree) and small ones favour the full search.
    """

    def __init__(
        self,
        graph: object,
        k: int = 30,
        *,
        recovery_factor: float | None = 3.0,
        recovery_min_score: float = 0.05,
        recovery_smoothing: float = 0.1,
        database: NodeDatabase | None = None,
        strategy: str = "walk",
    ) -> None:
        if k < 1:
            raise ValueError(f"k: expected >= 1, got {k}")
        if strategy not in ("walk", "auto"):
            raise ValueError(f"strategy: expected 'walk' or 'auto', got {strategy!r}")
        self.strategy = strategy
        if recovery_factor is not None and recovery_factor <= 1.0:
            raise ValueError(f"recovery_factor: expected > 1 or None, got {recovery_factor}")
        if not 0.0 < recovery_smoothing <= 1.0:
            raise ValueError(f"recovery_smoothing: expected in (0, 1], got {recovery_smoothing}")
        self.graph = graph
        self.database = _database(graph, database)
        self.k = k
        # The first frame's and the recovery's full search: FPG's score over every node.
        self.full_search = BruteForceSelector(self.database, k, score="fpg")
        self.recovery_factor = recovery_factor
        self.recovery_min_score = recovery_min_score
        self.recovery_smoothing = recovery_smoothing
        self._marks: np.ndarray | None = None
        self._graph_csr: tuple[object, tuple[np.ndarray, np.ndarray] | None] = (None, None)
        self.reset()

    def reset(self) -> None:
        """Forget the previous nodes: the next frame is a full search."""
        self._previous: np.ndarray | None = None
        self._average: float | None = None
        self.recoveries = 0

    def neighbourhood(self, nodes: np.ndarray) -> np.ndarray:
        """``nodes`` and all their graph neighbours, sorted and unique."""
        return np.sort(self._pool(nodes, _compiled()))

    def _csr(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The graph's CSR arrays ``(indptr, indices)`` when it has them (looked up once per
        graph object)."""
        graph, (seen, csr) = self.graph, self._graph_csr
        if graph is seen:
            return csr
        indptr = getattr(graph, "indptr", None)
        indices = getattr(graph, "indices", None)
        csr = (
            None if indptr is None or indices is None else (np.asarray(indptr), np.asarray(indices))
        )
        self._graph_csr = (graph, csr)
        return csr

    def _pool(self, nodes: np.ndarray, compiled: ModuleType | None) -> np.ndarray:
        """``nodes`` and all their graph neighbours, unique (sorted unless ``compiled``, the
        compiled selection kernels)."""
        nodes = np.asarray(nodes, dtype=np.int64)
        csr = self._csr()
        if compiled is not None and csr is not None:  # a marker array, no sort
            if self._marks is None:
                self._marks = np.zeros(len(csr[0]) - 1, dtype=np.bool_)
            pool: np.ndarray = compiled.neighbourhood(nodes, csr[0], csr[1], self._marks)
            return pool
        graph = self.graph
        if hasattr(graph, "neighbors_of"):
            neighbours = np.asarray(graph.neighbors_of(nodes), dtype=np.int64)
        else:  # plain CSR arrays
            indptr = np.asarray(graph.indptr)  # type: ignore[attr-defined]
            indices = np.asarray(graph.indices)  # type: ignore[attr-defined]
            starts, counts = indptr[nodes], indptr[nodes + 1] - indptr[nodes]
            offsets = np.repeat(starts - np.cumsum(counts) + counts, counts)
            neighbours = indices[offsets + np.arange(counts.sum())].astype(np.int64)
        return np.union1d(nodes, neighbours)

    def select(self, query: SelectionQuery) -> Selection:
        """The K best of the previous nodes' neighbourhood (full search on the first frame)."""
        if self._previous is None:
            selection = self.full_search.select(query)
        else:
            compiled = _compiled()
            pool = self._pool(self._previous, compiled)
            if self.strategy == "auto" and walk_cost(len(pool), compiled is not None) >= len(
                self.database
            ):
                return self._finish(self.full_search.select(query))
            walked = None if compiled is None else self._walk_compiled(compiled, pool, query)
            if walked is not None:
                selection = walked
            else:  # without numba, or a tie across the cut
                pool = np.sort(pool)
                candidates = self.database.poses_for(pool, query.lengths)
                scores = fpg_score(query.pose, query.reliability, candidates, query.prediction)
                best = _best_k(scores, self.k)
                selection = Selection(
                    nodes=pool[best],
                    poses=candidates[best],
                    scores=scores[best].astype(np.float64),
                    num_scored=len(pool),
                    full_search=False,
                )
            if (
                self.recovery_factor is not None
                and self._average is not None
                and selection.scores[0] > self.recovery_min_score
                and selection.scores[0] > self.recovery_factor * self._average
            ):
                full = self.full_search.select(query)
                selection = replace(full, num_scored=len(pool) + full.num_scored, recovered=True)
                self.recoveries += 1
        return self._finish(selection)

    def _walk_compiled(
        self, compiled: ModuleType, pool: np.ndarray, query: SelectionQuery
    ) -> Selection | None:
        """The walk's K best: FPG's ``S`` of every pool node in one compiled pass, retargeted on
        the fly (module docstring); their poses from :meth:`NodeDatabase.poses_for`. None on a
        tie across the cut (the numpy walk then picks the tied nodes kept, as before)."""
        database = self.database
        retarget = query.lengths is not None
        nodes, scores, tied = compiled.fpg_walk_best(  # FPG Eq. 5-7 of every pool node
            pool,
            database.poses,
            database.directions,
            database.roots,
            np.asarray(query.lengths, dtype=np.float64) if retarget else _UNIT_LENGTHS,
            _BONES,
            retarget,
            *_walk_query(query),
            self.k,
        )
        if tied:
            return None
        return Selection(
            nodes=nodes,
            poses=database.poses_for(nodes, query.lengths),
            scores=scores,
            num_scored=len(pool),
            full_search=False,
        )

    def _finish(self, selection: Selection) -> Selection:
        """Remember the frame's nodes and best score; float32 poses."""
        self._previous = selection.nodes
        a = self.recovery_smoothing
        best_score = float(selection.scores[0])
        self._average = (
            best_score if self._average is None else (1 - a) * self._average + a * best_score
        )
        if selection.poses.dtype == np.float32:
            return selection
        return replace(selection, poses=selection.poses.astype(np.float32))


def _database(graph: object, database: NodeDatabase | None) -> NodeDatabase:
    """``database``, or a new one of the graph's node poses."""
    return database or NodeDatabase(np.asarray(graph.poses))  # type: ignore[attr-defined]


def make_selector(
    name: str, graph: object, k: int = 30, database: NodeDatabase | None = None, **kwargs: object
) -> CandidateSelector:
    """Build a selector by name: ``"graph"``, ``"auto"`` (the graph walk or a full search,
    whichever is estimated cheaper each frame) or ``"brute-force"``.

    Extra keyword arguments go to the selector's constructor.
    """
    database = _database(graph, database)
    if name == "graph":
        return GraphSelector(graph, k, database=database, **kwargs)  # type: ignore[arg-type]
    if name == "auto":
        kwargs.setdefault("strategy", "auto")
        return GraphSelector(graph, k, database=database, **kwargs)  # type: ignore[arg-type]
    if name == "brute-force":
        return BruteForceSelector(database, k, **kwargs)  # type: ignore[arg-type]
    raise ValueError(f"selector: expected 'graph', 'auto' or 'brute-force', got {name!r}")
