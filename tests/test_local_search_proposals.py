"""Local search's pre-drawn proposal table (issue 18): same distribution, same optimum quality."""

from __future__ import annotations

import numpy as np
import pytest

import optimizers
from optimizers.local_search import TABLE_ROWS, LocalSearch


class Quadratic:
    """A shifted, scaled sphere in 20 dimensions."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.dim = 20
        self.x0 = np.zeros(20)
        self.centre = rng.normal(0.0, 0.5, 20)
        self.scale = rng.uniform(0.5, 2.0, 20)

    def evaluate(self, z: np.ndarray) -> np.ndarray:
        return (((z - self.centre) * self.scale) ** 2).sum(axis=1)


def test_table_batches_are_standard_normal_around_the_centre() -> None:
    search = LocalSearch(step=0.5, proposals="table")
    search.reset(Quadratic(np.random.default_rng(0)), np.random.default_rng(1))
    batches = []
    for _ in range(200):
        search.iteration = 1  # keep x0 out of the batch
        batches.append(search.ask())
    samples = np.concatenate(batches) / 0.5
    assert samples.shape == (200 * 100, 20)
    assert np.abs(samples.mean(axis=0)).max() < 0.05
    assert np.abs(samples.std(axis=0) - 1.0).max() < 0.05
    table = search.proposal_table()
    assert table.shape == (TABLE_ROWS, 20) and not table.flags.writeable
    other = LocalSearch(proposals="table")
    other.reset(Quadratic(np.random.default_rng(2)), np.random.default_rng(3))
    assert other.proposal_table() is table  # one table per process and dimension


def test_the_table_is_the_default_and_the_generator_picks_its_rows() -> None:
    assert LocalSearch().proposals == "table"
    runs = [
        optimizers.run_optimizer(Quadratic(np.random.default_rng(0)), LocalSearch(), seed)
        for seed in (1, 1, 2)
    ]
    np.testing.assert_array_equal(runs[0].x, runs[1].x)
    assert not np.array_equal(runs[0].x, runs[2].x)


def test_table_proposals_find_optima_as_good_as_fresh_draws() -> None:
    finals: dict[str, list[float]] = {"normal": [], "table": []}
    for seed in range(30):
        problem = Quadratic(np.random.default_rng(seed))
        for proposals in finals:
            result = optimizers.run_optimizer(
                problem, LocalSearch(proposals=proposals), seed, max_evaluations=2000
            )
            finals[proposals].append(result.energy)
    normal, table = np.median(finals["normal"]), np.median(finals["table"])
    assert table < 3.0 * normal and normal < 3.0 * table
    same_seed = [
        optimizers.run_optimizer(
            Quadratic(np.random.default_rng(0)), LocalSearch(proposals="table"), 5
        ).x
        for _ in range(2)
    ]
    np.testing.assert_array_equal(*same_seed)
    with pytest.raises(ValueError, match="proposals"):
        LocalSearch(proposals="sobol")
