"""The previous full-search selection (before issue 18), kept as the tests' reference.

Scores every node directly with :func:`~fpg_gym.reconstruct.selection.shum_score` or
:func:`~fpg_gym.reconstruct.selection.fpg_score` and keeps the K best, sorted by (score, node).
"""

from __future__ import annotations

import numpy as np

from fpg_gym.reconstruct.selection import (
    NodeDatabase,
    SelectionQuery,
    _best_k,
    fpg_score,
    shum_score,
)


def reference_best_k(
    database: NodeDatabase, query: SelectionQuery, k: int, score: str
) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and scores of the ``k`` best nodes by the direct score over all nodes."""
    candidates = database.all_poses(query.lengths)
    if score == "shum":
        scores = shum_score(query.pose, query.reliability, candidates)
    else:
        scores = fpg_score(query.pose, query.reliability, candidates, query.prediction)
    best = _best_k(scores, k)
    return best, scores[best].astype(np.float64)


def reference_walk(
    database: NodeDatabase, pool: np.ndarray, query: SelectionQuery, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The previous graph walk's K best of a sorted neighbourhood ``pool``: every pool node
    retargeted with ``poses_for`` and scored with FPG's S; nodes, poses, scores."""
    candidates = database.poses_for(pool, query.lengths)
    scores = fpg_score(query.pose, query.reliability, candidates, query.prediction)
    best = _best_k(scores, k)
    return pool[best], candidates[best], scores[best].astype(np.float64)
