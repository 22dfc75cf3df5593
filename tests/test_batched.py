"""Many streams in one process (fpg_gym.reconstruct.streams): same output per stream as alone,
the stacked energy equals the per-frame energies, and the budget loop steps like run_optimizer."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fpg_gym.methods import reconstruct_many
from fpg_gym.reconstruct import STAGES, EnergyWeights, Reconstructor
from fpg_gym.reconstruct import search as search_module
from fpg_gym.reconstruct.energy import StackedEnergy
from fpg_gym.reconstruct.kernels import available_kernels, stack_tables
from fpg_gym.reconstruct.search import search_together
from fpg_gym.reconstruct.streams import run_streams
from optimizers import OptimizerRun, run_optimizer
from optimizers.local_search import LocalSearch
from tests.test_reconstructor import graph, recording


def _short(rec: SimpleNamespace, frames: int) -> SimpleNamespace:
    return SimpleNamespace(
        positions=rec.positions[:frames],
        states=rec.states[:frames],
        timestamps=rec.timestamps[:frames],
    )


@pytest.mark.parametrize("compiled_search", [True, False])
def test_each_stream_equals_its_single_stream_run(
    compiled_search: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Streams of different lengths (one leaves the batch early) and two with another energy
    # (the prior term, float32 arithmetic: other stack keys, evaluated in their own groups).
    # Without the compiled local search (fpg_gym.reconstruct.search) the batches are stacked.
    if not compiled_search:
        monkeypatch.setattr(search_module, "_compiled", lambda: None)
    recs = [
        _short(recording("punch", seed=1), 24),
        _short(recording("walk", seed=2), 16),
        _short(recording("kick", noise=0.02, seed=3), 24),
        _short(recording("walk", noise=0.02, seed=4), 16),
    ]
    configs: list[dict[str, Any]] = [
        {},
        {},
        {"weights": EnergyWeights.with_prior()},
        {"energy_dtype": "float32"},
    ]
    seeds = [5, 6, 7, 8]
    reconstructors = [Reconstructor(graph(), **c) for c in configs]
    many = run_streams(reconstructors, recs, "local-search", rngs=seeds)
    assert [m.num_frames for m in many] == [24, 16, 24, 16]
    for rec, config, seed, result in zip(recs, configs, seeds, many, strict=True):
        alone = Reconstructor(graph(), **config).reconstruct(rec, "local-search", rng=seed)
        np.testing.assert_allclose(result.poses, alone.poses, atol=1e-5)
        if "numba" in available_kernels():  # the same compiled arithmetic: equal to the bit
            np.testing.assert_array_equal(result.poses, alone.poses)
        np.testing.assert_allclose(
            [r.energy for r in result.records], [r.energy for r in alone.records], rtol=1e-9
        )
        assert [r.evaluations for r in result.records] == [r.evaluations for r in alone.records]
        assert all(r.evaluations > 0 for r in result.records)
        for r in result.records:  # the stream's own search time, and a consistent total
            assert r.ms["search"] > 0
            assert r.ms["total"] == pytest.approx(sum(r.ms[s] for s in STAGES))
    # Another seed gives another output: the equality above is not vacuous.
    other = reconstruct_many(graph(), recs[:1], "local-search", rngs=[99])[0]
    assert np.abs(other.poses - many[0].poses).max() > 1e-4


@pytest.mark.parametrize("kernel", available_kernels())
def test_stacked_energy_equals_each_frame_energy(kernel: str) -> None:
    recs = [recording("punch", seed=s) for s in (1, 2, 3)]
    problems = []
    for rec in recs:
        r = Reconstructor(graph(), energy_kernel=kernel)
        for t in range(3):  # a frame with a motion target
            problem = r.prepare(rec.positions[t], rec.states[t], rec.timestamps[t])
            if t < 2:
                r.finish(problem.x0)
        problems.append(problem)
    z = np.random.default_rng(0).normal(size=(3, 7, problems[0].dim))
    stacked = StackedEnergy.of([p.energy for p in problems]).total(z)
    expected = np.stack([p.energy(z[i]) for i, p in enumerate(problems)])
    np.testing.assert_allclose(stacked, expected, rtol=1e-12)
    if kernel == "numba":  # the same compiled row loop: equal to the last bit
        np.testing.assert_array_equal(stacked, expected)
    assert np.ptp(expected[:, 0]) > 0  # three different frames
    subset = StackedEnergy.of([p.energy for p in problems]).select(np.array([2, 0]))
    np.testing.assert_allclose(subset.total(z[[2, 0]]), expected[[2, 0]], rtol=1e-12)


def test_stacked_energy_refuses_models_that_differ() -> None:
    rec = recording()
    first = Reconstructor(graph()).prepare(rec.positions[0], rec.states[0], 0.0)
    prior = Reconstructor(graph(), weights=EnergyWeights.with_prior())
    second = prior.prepare(rec.positions[0], rec.states[0], 0.0)
    with pytest.raises(ValueError, match=r"models\[1\]: expected the stack key"):
        StackedEnergy.of([first.energy, second.energy])
    with pytest.raises(ValueError, match="at least one"):
        StackedEnergy.of([])
    direct = Reconstructor(graph(), energy_kernel="direct")
    with pytest.raises(ValueError, match="'direct' kernel"):
        StackedEnergy.of([direct.prepare(rec.positions[0], rec.states[0], 0.0).energy])
    with pytest.raises(ValueError, match=r"frames\[1\]: expected wk"):
        stack_tables([first.energy.tables, replace(second.energy.tables, wk=9.0)])
    with pytest.raises(ValueError, match="stacked tables"):
        first.energy.tables.select(np.array([0]))


def test_stepped_run_equals_run_optimizer_with_a_clipped_budget() -> None:
    class Bowl:
        dim = 4
        x0 = np.ones(4)

        def evaluate(self, z: np.ndarray) -> np.ndarray:
            return ((z - 0.3) ** 2).sum(axis=1)

    whole = run_optimizer(Bowl(), "local-search", rng=3, max_evaluations=250)
    run = OptimizerRun(Bowl(), "local-search", rng=3, max_evaluations=250)
    sizes = []
    while (z := run.propose()) is not None:
        sizes.append(len(z))
        run.receive(Bowl().evaluate(z))
    stepped = run.result()
    assert sizes == [100, 100, 50]  # the last batch clipped to the budget
    assert stepped.evaluations == whole.evaluations == 250
    np.testing.assert_array_equal(stepped.x, whole.x)
    assert stepped.energy == whole.energy < Bowl().evaluate(Bowl.x0[None])[0]
    with pytest.raises(RuntimeError, match="nothing was proposed"):
        run.receive(np.zeros(1))


def test_bad_arguments_are_named() -> None:
    recs = [_short(recording(), 3), _short(recording(seed=4), 3)]
    r = Reconstructor(graph())
    with pytest.raises(ValueError, match="distinct objects"):
        run_streams([r, r], recs, rngs=[0, 1])
    with pytest.raises(ValueError, match="rngs: expected 2 seeds"):
        run_streams([r, Reconstructor(graph())], recs, rngs=[0])
    with pytest.raises(ValueError, match=r"recordings\[1\]\.states"):
        bad = SimpleNamespace(positions=recs[1].positions, states=recs[1].states[:2])
        run_streams([r, Reconstructor(graph())], [recs[0], bad], rngs=[0, 1])


def test_a_non_finite_proposal_names_its_stream() -> None:
    class Wild(LocalSearch):
        def ask(self) -> np.ndarray | None:
            z = super().ask()
            if z is not None:
                z[3, 1] = np.nan
            return z

    recs = [_short(recording(), 2), _short(recording(seed=4), 2)]
    reconstructors = [Reconstructor(graph()), Reconstructor(graph())]
    problems = [
        r.prepare(rec.positions[0], rec.states[0], 0.0)
        for r, rec in zip(reconstructors, recs, strict=True)
    ]
    runs = [OptimizerRun(problems[0], "local-search", 0), OptimizerRun(problems[1], Wild(), 1)]
    with pytest.raises(ValueError, match="stream 1: the optimiser proposed non-finite"):
        search_together(problems, runs)
