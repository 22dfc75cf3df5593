"""Exact fast selection (issue 18): the GEMV brute force and the auto selector against the
direct scores of tests/reference_selection.py."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from reference_selection import reference_best_k

from fpg_gym import poses, skeleton
from fpg_gym.reconstruct import selection as selection_module
from fpg_gym.reconstruct.node_database import NodeDatabase
from fpg_gym.reconstruct.selection import (
    BruteForceSelector,
    GraphSelector,
    SelectionQuery,
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
    monkeypatch.setattr(selection_module, "GEMV_MIN_NODES", 0)  # the GEMV at every size
    data = random_database(rng, n)
    database = NodeDatabase(data)
    for _ in range(6):
        query = random_query(rng, data, lengths)
        expected, expected_scores = reference_best_k(database, query, 30, "shum")
        nodes, scores = shum_best_k(database, query, 30)
        np.testing.assert_array_equal(nodes, expected)
        np.testing.assert_allclose(scores, expected_scores, rtol=1e-12, atol=1e-15)
        monkeypatch.undo()  # the selector as configured (direct below GEMV_MIN_NODES)
        selection = BruteForceSelector(database, 30).select(query)
        monkeypatch.setattr(selection_module, "GEMV_MIN_NODES", 0)
        np.testing.assert_array_equal(selection.nodes, expected)
        np.testing.assert_array_equal(selection.poses, database.all_poses(query.lengths)[expected])


def test_duplicate_nodes_tie_as_the_direct_scores(
    rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Exact duplicates: the same scores; the same nodes but where a tie straddles the cut
    (which of the tied nodes make the k is arbitrary in both)."""
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
