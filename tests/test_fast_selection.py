"""Exact fast selection (issue 18): the GEMV brute force and the auto selector against the
direct scores of tests/reference_selection.py."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
from reference_selection import reference_best_k, reference_walk

from fpg_gym.core import poses, skeleton
from fpg_gym.reconstruct import selection as selection_module
from fpg_gym.reconstruct.node_database import NodeDatabase
from fpg_gym.reconstruct.selection import (
    BruteForceSelector,
    GraphSelector,
    SelectionQuery,
    fpg_best_k,
    make_selector,
    shum_best_k,
)


def random_database(rng: np.random.Generator, n: int, spread: float = 0.15) -> np.ndarray:
    base = poses.rest_pose().astype(np.float64)
    return (base[None] + rng.normal(0.0, spread, (n, skeleton.NUM_JOINTS, 3))).astype(np.float32)


def random_query(rng: np.random.Generator, database: np.ndarray, lengths: bool) -> SelectionQuery:
    pose = database[rng.integers(len(database))] + rng.normal(0.0, 0.05, (skeleton.NUM_JOINTS, 3))
    reliability = rng.uniform(0.0, 1.0, skeleton.NUM_JOINTS)
    reliability[rng.uniform(size=skeleton.NUM_JOINTS) < 0.3] = 0.0
    return SelectionQuery(
        pose=pose.astype(np.float64),
        reliability=reliability,
        prediction=pose + rng.normal(0.0, 0.02, pose.shape),
        lengths=poses.DEFAULT_BONE_LENGTHS * rng.uniform(0.9, 1.1) if lengths else None,
    )


@pytest.mark.parametrize("n", [7, 30, 500, 5000])
@pytest.mark.parametrize("lengths", [False, True])
def test_gemv_brute_force_selects_the_same_nodes_as_direct_scores(
    rng: np.random.Generator, n: int, lengths: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(selection_module, "_compiled", lambda: None)  # the numpy path
    monkeypatch.setattr(selection_module, "GEMV_MIN_NODES", 0)  # the GEMV at every size
    data = random_database(rng, n)
    database = NodeDatabase(data)
    for _ in range(6):
        query = random_query(rng, data, lengths)
        expected, expected_scores = reference_best_k(database, query, 30, "shum")
        nodes, scores = shum_best_k(database, query, 30)
        np.testing.assert_array_equal(nodes, expected)
        np.testing.assert_allclose(scores, expected_scores, rtol=1e-12, atol=1e-15)
        monkeypatch.setattr(selection_module, "GEMV_MIN_NODES", 512)  # direct below 512
        selection = BruteForceSelector(database, 30).select(query)
        monkeypatch.setattr(selection_module, "GEMV_MIN_NODES", 0)
        np.testing.assert_array_equal(selection.nodes, expected)
        np.testing.assert_array_equal(selection.poses, database.all_poses(query.lengths)[expected])


def test_duplicate_nodes_tie_as_the_direct_scores(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Exact duplicates: the same scores; the same nodes but where a tie straddles the cut
    (which of the tied nodes make the k is arbitrary in both)."""
    monkeypatch.setattr(selection_module, "_compiled", lambda: None)  # the numpy path
    monkeypatch.setattr(selection_module, "GEMV_MIN_NODES", 0)
    data = np.repeat(random_database(rng, 40), 3, axis=0)
    database = NodeDatabase(data)
    query = random_query(rng, data, lengths=False)
    nodes, scores = shum_best_k(database, query, 10)
    expected, expected_scores = reference_best_k(database, query, 10, "shum")
    np.testing.assert_array_equal(scores, expected_scores)
    inside = expected_scores < expected_scores[-1]
    assert inside.sum() >= 6
    np.testing.assert_array_equal(nodes[inside], expected[inside])
    assert (data[nodes[~inside]] == data[expected[-1]]).all()  # copies of the same pose
    no_body = SelectionQuery(pose=query.pose, reliability=np.zeros(skeleton.NUM_JOINTS))
    nodes, scores = shum_best_k(database, no_body, 10)
    assert nodes.tolist() == list(range(10)) and not scores.any()


def test_weighted_squared_distances_stay_within_their_error_bound(
    rng: np.random.Generator,
) -> None:
    data = random_database(rng, 2000, spread=0.4)
    database = NodeDatabase(data)
    weights = rng.uniform(0.0, 1.0, (3, skeleton.NUM_JOINTS))
    points = rng.normal(0.0, 0.5, (3, 3 * skeleton.NUM_JOINTS))
    values, error = database.weighted_squared_distances(weights, points, None)
    flat = data.reshape(len(data), skeleton.NUM_JOINTS, 3).astype(np.float64)
    for m in range(3):
        diff = flat - points[m].reshape(skeleton.NUM_JOINTS, 3)
        exact = np.einsum("njc,njc->nj", diff, diff) @ weights[m]
        assert np.all(np.abs(values[:, m] - exact) <= error[m])
        assert error[m] < 1e-3 * np.median(exact)  # and the bound is useful


def test_poses_are_c_contiguous_and_retargeted(rng: np.random.Generator) -> None:
    data = random_database(rng, 50)
    database = NodeDatabase(data)
    lengths = poses.DEFAULT_BONE_LENGTHS * 1.1
    subset = database.poses_for(np.array([3, 1, 4]), lengths)
    assert subset.flags.c_contiguous and subset.dtype == np.float32
    np.testing.assert_allclose(poses.bone_lengths(subset), np.tile(lengths, (3, 1)), rtol=1e-5)
    np.testing.assert_allclose(subset[:, skeleton.ROOT], data[[3, 1, 4], skeleton.ROOT])
    assert database.all_poses(lengths).flags.c_contiguous


@dataclass
class ChainGraph:
    """A graph-like object: nodes on a chain, each linked to ``width`` nodes on either side."""

    poses: np.ndarray
    width: int

    def neighbors_of(self, nodes: np.ndarray) -> np.ndarray:
        ids = np.asarray(nodes)[:, None] + np.arange(-self.width, self.width + 1)
        return np.unique(np.clip(ids, 0, len(self.poses) - 1))


def test_auto_selector_walks_a_sparse_graph_and_searches_a_dense_one(
    rng: np.random.Generator,
) -> None:
    data = random_database(rng, 3000)
    queries = [random_query(rng, data, lengths=False) for _ in range(4)]
    sparse = GraphSelector(ChainGraph(data, 2), 10, strategy="auto", recovery_factor=None)
    dense = make_selector("auto", ChainGraph(data, 400), 10, recovery_factor=None)
    walk = GraphSelector(ChainGraph(data, 2), 10, recovery_factor=None)
    full = BruteForceSelector(NodeDatabase(data), 10, score="fpg")
    for i, query in enumerate(queries):
        a, b, c = sparse.select(query), dense.select(query), walk.select(query)
        assert a.full_search == (i == 0)  # the first frame is a full search
        np.testing.assert_array_equal(a.nodes, c.nodes)  # sparse: the graph walk
        assert b.full_search  # dense: the neighbourhood costs more than all nodes
        np.testing.assert_array_equal(b.nodes, full.select(query).nodes)
    with pytest.raises(ValueError, match="strategy"):
        GraphSelector(ChainGraph(data, 2), 10, strategy="fastest")


# --------------------------------------------------------------------------- compiled kernels

needs_numba = pytest.mark.skipif(
    not selection_module.compiled_available(), reason="needs numba (fpg-gym[fast])"
)


class RandomGraph:
    """A graph-like object with CSR arrays: each node linked to ``degree`` random others."""

    def __init__(self, rng: np.random.Generator, node_poses: np.ndarray, degree: int) -> None:
        self.poses = node_poses
        n = len(node_poses)
        pairs = rng.integers(0, n, (n * degree // 2, 2))
        pairs = pairs[pairs[:, 0] != pairs[:, 1]]
        both = np.unique(np.concatenate([pairs, pairs[:, ::-1]]), axis=0)
        self.indptr = np.searchsorted(both[:, 0], np.arange(n + 1)).astype(np.int64)
        self.indices = both[:, 1].astype(np.int32)


def tie_query(rng: np.random.Generator, data: np.ndarray, kind: str) -> SelectionQuery:
    """Queries of the edge cases: no reliability, no prediction, float32, full reliability."""
    query = random_query(rng, data, lengths=kind == "lengths")
    if kind == "zero":
        return replace(query, reliability=np.zeros(skeleton.NUM_JOINTS))
    if kind == "no prediction":
        return replace(query, prediction=None)
    if kind == "float32":
        return replace(
            query,
            pose=query.pose.astype(np.float32),
            prediction=query.prediction.astype(np.float32),
        )
    if kind == "reliable":
        return replace(query, reliability=np.ones(skeleton.NUM_JOINTS))
    return query


def assert_same_selection(
    nodes: np.ndarray,
    scores: np.ndarray,
    expected: np.ndarray,
    expected_scores: np.ndarray,
    tol: float,
) -> None:
    """The same K best as the reference in the same order, scores within ``tol``, except that
    nodes whose reference scores agree within ``2 tol`` (ties, and rounding-level near-ties
    whose reference order depends on the node's position in a BLAS call) may be ordered
    differently, and at the cut tied nodes may be others of the same score."""
    assert len(nodes) == len(expected)
    np.testing.assert_allclose(scores, expected_scores, rtol=0, atol=tol)
    assert np.all(np.diff(scores) >= 0)
    # groups of reference scores closer than 2 tol
    group = np.concatenate([[0], np.cumsum(np.diff(expected_scores) > 2 * tol)])
    last = group[-1]
    for g in np.unique(group):
        members = group == g
        if g == last:  # the cut: others of the same score may make the K
            continue
        assert set(nodes[members].tolist()) == set(expected[members].tolist()), (g, nodes, expected)


@needs_numba
@pytest.mark.parametrize("n", [1, 29, 30, 31, 400, 3000])
@pytest.mark.parametrize(
    "kind", ["plain", "lengths", "zero", "no prediction", "float32", "reliable"]
)
def test_compiled_full_searches_equal_the_reference(
    rng: np.random.Generator, n: int, kind: str
) -> None:
    """Shum Eq. 9 and FPG's S over all nodes: the reference's nodes in its order, scores to
    rounding; the exact ties of duplicated nodes ordered by node id."""
    data = random_database(rng, max(1, n // 3))
    data = np.concatenate([data, data, data])[:n]
    database = NodeDatabase(data)
    for _ in range(4):
        query = tie_query(rng, data, kind)
        for score, best_k in (("shum", shum_best_k), ("fpg", fpg_best_k)):
            expected, expected_scores = reference_best_k(database, query, 30, score)
            nodes, scores = best_k(database, query, 30)
            tol = 1e-12 * max(1.0, float(expected_scores.max(initial=0.0)))
            if kind == "float32":  # the reference sums in float32
                tol = 1e-5 * max(1.0, float(expected_scores.max(initial=0.0)))
            if score == "shum" and kind == "zero":  # all tie at 0: the first k, documented
                expected = np.arange(min(30, len(data)))
            assert_same_selection(nodes, scores, expected, expected_scores, tol)
            for value in np.unique(scores):  # exact ties: by node id
                tied = nodes[scores == value]
                assert np.all(np.diff(tied) > 0)
                if len(tied) > 1 and kind != "float32" and value > 0:
                    assert np.all(data[tied] == data[tied[0]])


@needs_numba
@pytest.mark.parametrize("lengths", [False, True])
@pytest.mark.parametrize("degree", [3, 40, 400])
def test_compiled_graph_walk_equals_the_reference_walk(
    rng: np.random.Generator, lengths: bool, degree: int
) -> None:
    """The compiled walk (marker-array union, retargeting and FPG's S in one pass) gives the
    previous walk's nodes in its order frame after frame, scores within the float32
    retargeting bound, poses from poses_for."""
    data = random_database(rng, 2000)
    data = np.concatenate([data, data[:200]])  # exact duplicates: ties in the walk
    graph = RandomGraph(rng, data, degree)
    database = NodeDatabase(data)
    selector = GraphSelector(graph, 30, database=database, recovery_factor=None)
    previous = None
    for frame in range(6):
        query = random_query(rng, data, lengths)
        if frame == 3:
            query = replace(query, prediction=None)
        selection = selector.select(query)
        if previous is not None:
            neighbours = [graph.indices[graph.indptr[p] : graph.indptr[p + 1]] for p in previous]
            pool = np.unique(np.concatenate([previous, *neighbours]))
            np.testing.assert_array_equal(selector.neighbourhood(previous), pool)
            nodes, _, scores = reference_walk(database, pool, query, 30)
            assert selection.num_scored == len(pool) and not selection.full_search
            tol = 1e-12
            if lengths:
                tol = float(np.sqrt(3.0) * retarget_error_bound(database, query.lengths))
            assert_same_selection(selection.nodes, selection.scores, nodes, scores, tol)
            if not lengths:  # no retargeting: the same poses, the same scores to rounding
                assert_same_selection(selection.nodes, selection.scores, nodes, scores, 1e-12)
            np.testing.assert_array_equal(
                selection.poses, database.poses_for(selection.nodes, query.lengths)
            )
        previous = selection.nodes


def retarget_error_bound(database: NodeDatabase, lengths: np.ndarray) -> float:
    """Bound on ``|poses_for(nodes, lengths) - exact|`` for every coordinate of every node.

    ``exact`` is the root plus the sum of the (float32) directions times the float32 lengths
    along the path, in exact arithmetic. ``poses_for`` rounds each product and a sum of at most
    20 terms in float32, in any order (``gamma_21`` of the terms' magnitudes, Higham); doubled
    for safety, plus as much for a float64 evaluation (the compiled walk's).
    """
    terms = skeleton.NUM_BONES + 2
    magnitude = float(np.abs(database.roots).max()) + 1.001 * float(
        np.abs(np.asarray(lengths, dtype=np.float32)).sum()
    )
    u32 = float(np.finfo(np.float32).eps) / 2
    u64 = float(np.finfo(np.float64).eps) / 2
    gamma = terms * u32 / (1.0 - terms * u32) + terms * u64 / (1.0 - terms * u64)
    return 2.0 * gamma * magnitude


@needs_numba
def test_retarget_error_bound_covers_float32_retargeting(rng: np.random.Generator) -> None:
    """poses_for's float32 poses stay within the bound of the walk's float64 retargeting."""
    data = random_database(rng, 3000, spread=0.4)
    database = NodeDatabase(data)
    lengths = poses.DEFAULT_BONE_LENGTHS * 1.07
    bound = retarget_error_bound(database, lengths)
    retargeted = database.poses_for(np.arange(len(data)), lengths).astype(np.float64)
    vectors = database.directions.astype(np.float64) * np.asarray(lengths, np.float32)[:, None]
    tree = np.zeros_like(retargeted)
    tree[:, skeleton.ROOT] = database.roots
    for b, (parent, child) in enumerate(skeleton.BONES):
        tree[:, child] = tree[:, parent] + vectors[:, b]
    error = np.abs(tree - retargeted).max()
    assert 0 < error <= bound < 1e-4


@needs_numba
def test_numpy_fallback_gives_the_same_selections(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without numba (the kernels forced off) every selector runs its numpy path; both agree."""
    data = random_database(rng, 1500)
    graph = RandomGraph(rng, data, 20)
    queries = [random_query(rng, data, lengths=i % 2 == 1) for i in range(6)]
    results = {}
    for label in ("compiled", "numpy"):
        if label == "numpy":
            monkeypatch.setattr(selection_module, "_compiled", lambda: None)
        assert selection_module.compiled_available() == (label == "compiled")
        database = NodeDatabase(data)
        selectors = [
            make_selector(name, graph, 30, database=database)
            for name in ("graph", "brute-force")  # (auto's cost model differs by path)
        ] + [BruteForceSelector(database, 30, score="fpg")]
        results[label] = [[s.select(q) for q in queries] for s in selectors]
    for compiled_run, numpy_run in zip(results["compiled"], results["numpy"], strict=True):
        for a, b in zip(compiled_run, numpy_run, strict=True):
            np.testing.assert_array_equal(a.nodes, b.nodes)  # no near-ties in these data
            np.testing.assert_allclose(a.poses, b.poses, rtol=0, atol=1e-6)
            np.testing.assert_allclose(a.scores, b.scores, rtol=1e-6)
            assert a.num_scored == b.num_scored and a.full_search == b.full_search


@needs_numba
def test_best_k_kernel_orders_by_score_then_node() -> None:
    from fpg_gym.reconstruct import compiled_selection

    nodes = np.array([7, 3, 9, 1, 4, 8], dtype=np.int64)
    scores = np.array([5.0, 1.0, 3.0, 2.0, 3.0, np.nan])
    out, kept, tied = compiled_selection._best(nodes, scores, 3)
    assert tied and out.size == 0  # 9 and 4 tie across the cut: the caller runs numpy
    out, kept, tied = compiled_selection._best(nodes, scores, 2)
    assert out.tolist() == [3, 1] and kept.tolist() == [1.0, 2.0] and not tied
    out, kept, tied = compiled_selection._best(nodes, scores, 4)
    assert out.tolist() == [3, 1, 4, 9] and not tied  # the tie inside: by node id
    many = np.zeros(100_000)  # a large tie: no quadratic sort
    out, _, tied = compiled_selection._best(np.arange(100_000), many, 30)
    assert tied and out.size == 0
    out, kept, tied = compiled_selection._best(nodes, scores, 10)  # k >= n: all, NaN last
    assert out.tolist() == [3, 1, 4, 9, 7, 8] and np.isnan(kept[-1]) and not tied
    out, _, _ = compiled_selection._best(nodes[:0], scores[:0], 3)
    assert out.size == 0


@needs_numba
def test_compiled_auto_selector_follows_its_cost_model(rng: np.random.Generator) -> None:
    """``auto`` walks while the compiled walk's estimated cost is below a full search."""
    data = random_database(rng, 3000)
    queries = [random_query(rng, data, lengths=True) for _ in range(4)]
    for degree in (4, 600):
        graph = RandomGraph(rng, data, degree)
        auto = make_selector("auto", graph, 10, recovery_factor=None)
        walk = make_selector("graph", graph, 10, recovery_factor=None)
        for i, query in enumerate(queries):
            previous = None if i == 0 else auto._previous  # type: ignore[attr-defined]
            a, w = auto.select(query), walk.select(query)
            if previous is None:
                assert a.full_search
                continue
            pool = len(auto.neighbourhood(previous))  # type: ignore[attr-defined]
            full = selection_module.walk_cost(pool, compiled=True) >= len(data)
            assert a.full_search == full and full == (degree == 600)
            if not full:
                np.testing.assert_array_equal(a.nodes, w.nodes)


@needs_numba
@pytest.mark.parametrize("kind", ["plain", "lengths", "zero", "root only", "no prediction"])
def test_compiled_full_searches_give_the_very_reference_selection(
    rng: np.random.Generator, kind: str
) -> None:
    """Distinct nodes: exactly the reference's nodes in its order. Exact ties across the K-th
    place (no reliable joint; only the root, at the origin in every normalised pose) run the
    numpy path, so the tied nodes kept are the reference's too."""
    data = random_database(rng, 2000)
    data[:, skeleton.ROOT] = 0.0
    database = NodeDatabase(data)
    for _ in range(4):
        query = tie_query(rng, data, "lengths" if kind == "lengths" else "plain")
        if kind in ("zero", "root only"):
            reliability = np.zeros(skeleton.NUM_JOINTS)
            reliability[skeleton.ROOT] = 0.0 if kind == "zero" else 0.7
            query = replace(query, reliability=reliability, prediction=None)
        if kind == "no prediction":
            query = replace(query, prediction=None)
        for score, best_k in (("shum", shum_best_k), ("fpg", fpg_best_k)):
            expected, expected_scores = reference_best_k(database, query, 30, score)
            nodes, scores = best_k(database, query, 30)
            if score == "shum" and kind == "zero":  # all tie at 0: the first k, documented
                expected = np.arange(30)
            np.testing.assert_array_equal(nodes, expected)
            np.testing.assert_allclose(scores, expected_scores, rtol=1e-12, atol=1e-15)
