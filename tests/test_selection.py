"""Candidate selection: brute force (Shum Eq. 9) and graph search (FPG §6.2) vs naive scorers."""

from __future__ import annotations

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.reconstruct.selection import (
    BruteForceSelector,
    CandidateSelector,
    GraphSelector,
    NodeDatabase,
    SelectionQuery,
    _best_k,
    fpg_score,
    make_selector,
    shum_score,
)


class ChainGraph:
    """Stand-in for FilteredPoseGraph: poses plus a CSR ring (each node linked to i±1, i±2)."""

    def __init__(self, node_poses: np.ndarray, reach: int = 2) -> None:
        self.poses = np.asarray(node_poses, dtype=np.float32)
        n = len(self.poses)
        rows = [sorted({(i + s) % n for s in range(-reach, reach + 1)} - {i}) for i in range(n)]
        self.indptr = np.concatenate([[0], np.cumsum([len(r) for r in rows])]).astype(np.int64)
        self.indices = np.concatenate(rows).astype(np.int32)

    def neighbors_of(self, nodes: np.ndarray) -> np.ndarray:
        return np.unique(
            np.concatenate([self.indices[self.indptr[i] : self.indptr[i + 1]] for i in nodes])
        )


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    base = poses.rest_pose()
    out = base[None] + rng.normal(0.0, 0.08, (n, skeleton.NUM_JOINTS, 3)).astype(np.float32)
    out[:, skeleton.ROOT] = 0.0
    return out


def naive_shum(pose: np.ndarray, r: np.ndarray, cands: np.ndarray) -> np.ndarray:
    return np.array(
        [sum(r[j] * np.sum((c[j] - pose[j]) ** 2) for j in range(len(r))) for c in cands]
    )


def naive_fpg(pose: np.ndarray, r: np.ndarray, cands: np.ndarray, pred: np.ndarray | None):
    out = []
    for c in cands:
        ss = np.mean([r[j] * np.linalg.norm(c[j] - pose[j]) for j in range(len(r))])
        sc = 0.0
        if pred is not None:
            sc = np.mean([(1 - r[j]) * np.linalg.norm(pred[j] - c[j]) for j in range(len(r))])
        out.append(ss + sc)
    return np.array(out)


def test_scores_match_naive_per_candidate_loops(rng: np.random.Generator) -> None:
    cands = random_poses(rng, 40).astype(np.float64)
    pose = random_poses(rng, 1)[0].astype(np.float64)
    pred = random_poses(rng, 1)[0].astype(np.float64)
    r = rng.uniform(0, 1, skeleton.NUM_JOINTS)
    assert np.allclose(shum_score(pose, r, cands), naive_shum(pose, r, cands))
    assert np.allclose(fpg_score(pose, r, cands), naive_fpg(pose, r, cands, None))
    assert np.allclose(fpg_score(pose, r, cands, pred), naive_fpg(pose, r, cands, pred))


def test_k_best_are_ordered_by_score_then_node_index() -> None:
    """Ties are ordered by node index, so that equal scores give one deterministic order."""
    scores = np.array([0.2, 0.5, 0.2, 0.9, 0.2, 0.1, 0.2, 0.3, 0.2, 0.05, 0.2, 0.7])
    # By hand: 0.05 (node 9), 0.1 (node 5), then the six ties at 0.2 in node order.
    assert _best_k(scores, 8).tolist() == [9, 5, 0, 2, 4, 6, 8, 10]
    # Then 0.3 (7), 0.5 (1), 0.7 (11), 0.9 (3); k beyond the count keeps them all.
    assert _best_k(scores, 20).tolist() == [9, 5, 0, 2, 4, 6, 8, 10, 7, 1, 11, 3]


def test_brute_force_keeps_the_k_best_by_eq9(rng: np.random.Generator) -> None:
    nodes = random_poses(rng, 200)
    sel = BruteForceSelector(nodes, k=30)
    assert isinstance(sel, CandidateSelector)
    pose = random_poses(rng, 1)[0]
    r = rng.uniform(0, 1, skeleton.NUM_JOINTS)
    out = sel.select(SelectionQuery(pose, r))
    naive = naive_shum(pose.astype(np.float64), r, nodes.astype(np.float64))
    assert np.array_equal(out.nodes, np.argsort(naive, kind="stable")[:30])
    assert np.allclose(out.scores, np.sort(naive)[:30], rtol=1e-5)
    assert np.array_equal(out.poses, nodes[out.nodes])
    assert out.full_search and out.num_scored == 200


def test_graph_selector_full_search_first_then_neighbourhood(rng: np.random.Generator) -> None:
    nodes = random_poses(rng, 120)
    graph = ChainGraph(nodes)
    sel = GraphSelector(graph, k=5, recovery_factor=None)
    r = rng.uniform(0.2, 1, skeleton.NUM_JOINTS)
    pose = nodes[50] + 0.01
    first = sel.select(SelectionQuery(pose, r))
    naive = naive_fpg(pose.astype(np.float64), r, nodes.astype(np.float64), None)
    assert first.full_search and first.num_scored == 120
    assert np.array_equal(first.nodes, np.argsort(naive, kind="stable")[:5])
    # Second frame: only the previous nodes and their ring neighbours are scored, with Ss + Sc.
    pred = nodes[52]
    pose2 = nodes[90]  # far away in the ring: must not be reachable
    second = sel.select(SelectionQuery(pose2, r, prediction=pred))
    pool = np.unique(np.concatenate([first.nodes, graph.neighbors_of(first.nodes)]))
    assert not second.full_search and second.num_scored == len(pool)
    scores = naive_fpg(pose2.astype(np.float64), r, nodes[pool].astype(np.float64), pred)
    assert np.array_equal(second.nodes, pool[np.argsort(scores, kind="stable")[:5]])
    assert np.all(np.isin(second.nodes, pool))
    assert 90 not in second.nodes


def test_graph_selector_plain_csr_fallback_matches(rng: np.random.Generator) -> None:
    nodes = random_poses(rng, 50)
    graph = ChainGraph(nodes, reach=3)

    class CsrOnly:
        poses, indptr, indices = graph.poses, graph.indptr, graph.indices

    a = GraphSelector(graph, k=4)
    b = GraphSelector(CsrOnly(), k=4)
    ids = np.array([3, 17, 49])
    assert np.array_equal(a.neighbourhood(ids), b.neighbourhood(ids))


def test_recovery_falls_back_to_a_full_search(rng: np.random.Generator) -> None:
    nodes = random_poses(rng, 300)
    graph = ChainGraph(nodes, reach=1)
    r = np.ones(skeleton.NUM_JOINTS)
    sel = GraphSelector(graph, k=3, recovery_factor=3.0, recovery_min_score=0.01)
    for _ in range(5):  # settle near node 10
        out = sel.select(SelectionQuery(nodes[10], r, prediction=nodes[10]))
    assert not out.recovered and 10 in out.nodes
    jump = sel.select(SelectionQuery(nodes[200], r, prediction=nodes[200]))
    assert jump.recovered and jump.full_search and jump.nodes[0] == 200
    assert sel.recoveries == 1
    # Without recovery the selector stays stuck in the old neighbourhood.
    stuck = GraphSelector(graph, k=3, recovery_factor=None)
    for _ in range(5):
        stuck.select(SelectionQuery(nodes[10], r, prediction=nodes[10]))
    out = stuck.select(SelectionQuery(nodes[200], r, prediction=nodes[200]))
    assert not out.recovered and 200 not in out.nodes


def test_node_database_retargets_like_poses_retarget(rng: np.random.Generator) -> None:
    nodes = random_poses(rng, 20)
    db = NodeDatabase(nodes)
    lengths = rng.uniform(0.05, 0.4, skeleton.NUM_BONES)
    ids = np.array([4, 0, 19])
    got = db.poses_for(ids, lengths)
    assert np.allclose(got, poses.retarget(nodes[ids], lengths), atol=1e-5)
    assert np.allclose(poses.bone_lengths(got), lengths, atol=1e-5)
    full = db.all_poses(lengths)
    assert np.allclose(full[ids], got, atol=1e-6)
    assert db.all_poses(lengths + 0.001) is full  # within the refresh tolerance: cached
    assert db.all_poses(lengths + 0.01) is not full
    assert db.refreshes == 2
    assert db.poses_for(ids, None) is not None and np.array_equal(
        db.poses_for(ids, None), nodes[ids]
    )


def test_k_larger_than_the_database_and_bad_arguments(rng: np.random.Generator) -> None:
    nodes = random_poses(rng, 4)
    out = BruteForceSelector(nodes, k=30).select(SelectionQuery(nodes[0], np.ones(20)))
    assert len(out.nodes) == 4
    with pytest.raises(ValueError, match="selector"):
        make_selector("nearest", ChainGraph(nodes))
    with pytest.raises(ValueError, match="k"):
        BruteForceSelector(nodes, k=0)
    with pytest.raises(ValueError, match="empty"):
        NodeDatabase(np.zeros((0, 20, 3)))
    assert isinstance(make_selector("brute-force", ChainGraph(nodes)), BruteForceSelector)
