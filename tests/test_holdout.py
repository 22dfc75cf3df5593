"""The hold-out split: whole takes, fixed seed, disjoint and complete."""

from __future__ import annotations

from pathlib import Path

from fpg_gym.core.holdout import holdout_indices, split_takes


def test_split_is_disjoint_complete_and_seeded() -> None:
    files = [Path(f"take_{i:03d}.bvh") for i in range(50)][::-1]
    graph, held = split_takes(files)
    assert len(held) == 10 and len(graph) == 40
    assert sorted(graph + held) == sorted(files) and graph == sorted(graph)
    assert split_takes(files) == (graph, held)
    assert split_takes(files, seed=1) != (graph, held)
    assert holdout_indices(1) == ([], [0])
