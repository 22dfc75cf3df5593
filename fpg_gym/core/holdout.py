"""The hold-out split of mocap takes: whole takes, a fixed seed, never frames.

Accuracy only means something on takes the pose graph was not built from (``../shared/data/
README.md``). ``scripts/holdout_split.py`` and ``fpg-gym bench`` both
split with :func:`holdout_indices`, so they hold out the same takes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

#: Default shuffle seed and held-out share.
HOLDOUT_SEED = 2016
HOLDOUT_SHARE = 0.2


def holdout_indices(
    count: int, share: float = HOLDOUT_SHARE, seed: int = HOLDOUT_SEED
) -> tuple[list[int], list[int]]:
    """``(graph indices sorted, held-out indices in shuffled order)`` of ``count`` takes.

    The takes are shuffled with ``seed`` and the first ``max(1, round(share * count))`` are held
    out.
    """
    order = np.random.default_rng(seed).permutation(count)
    held = max(1, round(share * count))
    return sorted(int(i) for i in order[held:]), [int(i) for i in order[:held]]


def split_takes(
    files: Sequence[Path], share: float = HOLDOUT_SHARE, seed: int = HOLDOUT_SEED
) -> tuple[list[Path], list[Path]]:
    """Split take files (sorted first): ``(graph takes sorted, held-out takes shuffled)``."""
    ordered = sorted(files)
    graph, held = holdout_indices(len(ordered), share, seed)
    return [ordered[i] for i in graph], [ordered[i] for i in held]
