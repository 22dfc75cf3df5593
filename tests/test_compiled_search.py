"""The compiled local search (fpg_gym.reconstruct.search): the same best point, energy, counts
and generator state as the ask/tell loop of run_optimizer, to the last bit, on real frames."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from fpg_gym.reconstruct import Reconstructor
from fpg_gym.reconstruct import search as search_module
from fpg_gym.reconstruct.search import compiled_search_available, complete_compiled, run_search
from fpg_gym.reconstruct.streams import run_streams
from optimizers import OptimizerRun, SearchResult, run_optimizer
from optimizers.local_search import LocalSearch
from tests.test_reconstructor import recording

pytestmark = pytest.mark.skipif(
    not compiled_search_available(), reason="the compiled search needs numba (fpg-gym[fast])"
)


def _problems(graph: Any, frames: tuple[int, ...], **config: Any) -> list[Any]:
    """Search problems of ``frames`` of an occluded, noisy punch (local search before each)."""
    rec = recording("punch", seed=3)
    problems = []
    for frame in frames:
        reconstructor = Reconstructor(graph, **config)
        reconstructor.reconstruct(
            type(rec)(**{k: v[:frame] for k, v in vars(rec).items()}), "local-search", rng=0
        )
        problems.append(
            reconstructor.prepare(rec.positions[frame], rec.states[frame], rec.timestamps[frame])
        )
    return problems


def _same(a: SearchResult, b: SearchResult) -> None:
    np.testing.assert_array_equal(a.x, b.x)
    assert (a.energy, a.evaluations, a.asks) == (b.energy, b.evaluations, b.asks)


@pytest.mark.parametrize(
    ("params", "budget"),
    [
        ({}, 2000),
        ({"proposals": "table"}, 2000),
        ({"proposals": "normal"}, 2000),  # drawn in numba from the optimiser's generator
        ({}, 250),  # a clipped batch: its other rows count as +inf
        ({"proposals": "table", "samples": 64}, 1000),
        ({"shrink": None}, 2000),  # Shum's literal stop
        ({"iterations": 7}, None),  # no evaluation budget: the optimiser's own end
        ({}, 0),
    ],
)
def test_compiled_search_equals_the_ask_tell_loop(
    graph: Any, params: dict[str, Any], budget: int | None
) -> None:
    for seed, problem in enumerate(_problems(graph, (1, 30))):
        loop_rng, compiled_rng = np.random.default_rng(seed), np.random.default_rng(seed)
        before = problem.evaluations
        loop = run_optimizer(problem, LocalSearch(**params), loop_rng, max_evaluations=budget)
        counted = problem.evaluations - before
        compiled = run_search(problem, LocalSearch(**params), compiled_rng, max_evaluations=budget)
        _same(compiled, loop)
        assert problem.evaluations - before - counted == counted == loop.evaluations
        assert loop_rng.random() == compiled_rng.random()  # the generator ends in one state
        if budget:
            assert loop.evaluations > 0 and loop.energy < np.inf


def test_float32_energy_and_the_table_kept_across_frames(graph: Any) -> None:
    problems = _problems(graph, (2, 12, 40), energy_dtype="float32")
    loop_search, compiled_search = LocalSearch(proposals="table"), LocalSearch(proposals="table")
    loop_rng, compiled_rng = np.random.default_rng(1), np.random.default_rng(1)
    for problem in problems:  # one optimiser over a stream: its table is drawn once
        loop = run_optimizer(problem, loop_search, loop_rng, max_evaluations=2000)
        compiled = run_search(problem, compiled_search, compiled_rng, max_evaluations=2000)
        _same(compiled, loop)
    np.testing.assert_array_equal(compiled_search.proposal_table(), loop_search.proposal_table())
    assert loop_rng.random() == compiled_rng.random()


def test_only_local_search_itself_without_a_time_budget_runs_compiled(graph: Any) -> None:
    class Counting(LocalSearch):
        asked = 0

        def ask(self) -> np.ndarray | None:
            Counting.asked += 1
            return super().ask()

    problem = _problems(graph, (5,))[0]
    run = OptimizerRun(problem, Counting(), 0, max_evaluations=500)
    assert not complete_compiled(problem, run)  # a subclass may change ask/tell
    assert run.asks == 0 and not run.done
    timed = OptimizerRun(problem, LocalSearch(), 0, max_evaluations=500, time_budget_s=1.0)
    assert not complete_compiled(problem, timed)  # the time budget is checked between batches
    run = OptimizerRun(problem, LocalSearch(), 0, max_evaluations=500)
    assert complete_compiled(problem, run) and run.done and run.propose() is None
    with pytest.raises(RuntimeError, match="already proposed"):
        run.complete(run.result())
    direct = _problems(graph, (5,), energy_kernel="numpy")[0]
    assert not complete_compiled(direct, OptimizerRun(direct, LocalSearch(), 0))


def test_streams_equal_with_and_without_the_compiled_search(
    graph: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    recs = [recording("punch", seed=1), recording("walk", seed=2)]
    recs = [type(r)(**{k: v[:20] for k, v in vars(r).items()}) for r in recs]
    compiled = [
        Reconstructor(graph).reconstruct(r, "local-search", rng=i) for i, r in enumerate(recs)
    ]
    together = run_streams([Reconstructor(graph) for _ in recs], recs, "local-search", [0, 1])
    monkeypatch.setattr(search_module, "_compiled", lambda: None)
    loop = [Reconstructor(graph).reconstruct(r, "local-search", rng=i) for i, r in enumerate(recs)]
    for a, b, c in zip(compiled, together, loop, strict=True):
        np.testing.assert_array_equal(a.poses, c.poses)
        np.testing.assert_array_equal(b.poses, c.poses)
        assert [r.evaluations for r in a.records] == [r.evaluations for r in c.records]
        assert [r.energy for r in b.records] == [r.energy for r in c.records]


_INTERPRETED_SEARCH = """
import json, sys
import numpy as np
from fpg_gym.reconstruct import compiled_search as cs
from optimizers.local_search import shared_proposal_table
rng = np.random.default_rng(0)
d, k = 4, 3
tables = (rng.standard_normal((d, d + 1 + k + 57)) * 0.3, 0.2, rng.random(k),
          rng.standard_normal(57), rng.random(19), 0.05)
out = []
for proposals in ("table", "normal", "table drawn before", "normal drawn before"):
    generator = np.random.default_rng(1)
    table = shared_proposal_table(400, d) if "table" in proposals else np.zeros((0, d))
    draws = generator
    if proposals.endswith("before"):  # the three batches' draws as an array
        draws = generator.random((3, d + 1)) if "table" in proposals else (
            generator.standard_normal((3, 10 * d)))
    x, energy, evaluations, asks, status = cs.local_search(
        draws, table, np.zeros(d), *tables, 10, 3, 1.0, 0.5, 1e-3,
        25, 100000)
    out.append([[float(v) for v in x], float(energy), int(evaluations), int(asks), int(status),
                generator.random()])
json.dump(out, sys.stdout)
"""


def test_the_compiled_search_equals_its_source_interpreted() -> None:
    """The kernel compiled and run by the interpreter (``NUMBA_DISABLE_JIT=1``): the same
    points, energies, counts and generator state."""
    runs = []
    for disable in ("0", "1"):
        environment = {**os.environ, "NUMBA_DISABLE_JIT": disable}
        done = subprocess.run(
            [sys.executable, "-c", _INTERPRETED_SEARCH],
            env=environment,
            capture_output=True,
            text=True,
            check=True,
        )
        runs.append(json.loads(done.stdout))
    assert runs[0] == runs[1]
    assert all(run[2] == 25 for run in runs[0])  # the budget clips the third batch
