"""The ask/tell protocol, the registry, the built-in optimisers and run_optimizer's budget."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import optimizers
from fpg_gym.core import poses, skeleton
from fpg_gym.reconstruct.energy import EnergyModel
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.problem import FrameContext, SearchProblem
from fpg_gym.reconstruct.reliability import ReliabilityTerms
from fpg_gym.reconstruct.selection import Selection


def make_problem(seed: int = 0) -> SearchProblem:
    rng = np.random.default_rng(seed)
    base = poses.rest_pose().astype(np.float64)
    k = 30
    neighbours = base[None] + rng.normal(0.0, 0.05, (k, skeleton.NUM_JOINTS, 3))
    sensor = neighbours[0] + rng.normal(0.0, 0.03, (skeleton.NUM_JOINTS, 3))
    r = rng.uniform(0.3, 1.0, skeleton.NUM_JOINTS)
    lengths = poses.bone_lengths(neighbours).mean(axis=0)
    previous = neighbours[1]
    latent = LatentSpace.fit(neighbours)
    ones = np.ones(skeleton.NUM_JOINTS)
    terms = ReliabilityTerms(r, ones, ones, ones, r, lengths, "given")
    selection = Selection(np.arange(k), neighbours.astype(np.float32), np.zeros(k), k, True)
    return SearchProblem(
        energy=EnergyModel(latent, sensor, r, neighbours, lengths, previous),
        kinect_pose=sensor,
        reliability=terms,
        selection=selection,
        prediction=previous,
        previous=previous,
        x0=latent.encode(previous),
        context=FrameContext(0, 0.0, 1 / 30, False),
    )


def test_registry_lists_the_builtins_and_makes_them() -> None:
    names = optimizers.available()
    for name in ("local-search", "random-search", "cma-es", "none"):
        assert name in names
        opt = optimizers.make(name)
        assert isinstance(opt, optimizers.Optimizer)
    assert optimizers.make("local-search", samples=10).samples == 10  # type: ignore[attr-defined]
    with pytest.raises(optimizers.OptimizerNotFound, match=r"available: .*local-search"):
        optimizers.make("gradient-descent")
    with pytest.raises(TypeError):
        optimizers.make("local-search", no_such_argument=1)


def test_a_third_party_toy_optimizer_runs_through_the_protocol() -> None:
    calls: list[str] = []

    class Toy(optimizers.BaseOptimizer):
        """Asks the start point and its negation, twice."""

        def reset(self, problem, rng):
            super().reset(problem, rng)
            self.rounds = 0
            calls.append("reset")

        def ask(self):
            if self.rounds == 2:
                return None
            self.rounds += 1
            calls.append("ask")
            return np.stack([self.problem.x0, -self.problem.x0])

        def tell(self, z, energies):
            calls.append(f"tell{len(energies)}")

    name = "toy-for-test"
    optimizers.register(name, Toy, overwrite=True)
    assert name in optimizers.available()
    with pytest.raises(ValueError, match="already registered"):
        optimizers.register(name, Toy)
    problem = make_problem()
    found = optimizers.run_optimizer(problem, name, rng=0)
    assert calls == ["reset", "ask", "tell2", "ask", "tell2"]
    assert problem.evaluations == 4 == found.evaluations and found.asks == 3
    energies = problem.evaluate_terms(np.stack([problem.x0, -problem.x0]), count=False)["E"]
    assert np.allclose(found.x, [problem.x0, -problem.x0][int(np.argmin(energies))])
    assert found.energy == pytest.approx(energies.min())


class Sphere:
    """The smallest problem: exactly the documented members (dim, x0, evaluate)."""

    dim = 4
    x0 = np.full(4, 2.0)

    def evaluate(self, z: np.ndarray) -> np.ndarray:
        return np.sum((z - 0.5) ** 2, axis=1)


def test_run_optimizer_owns_the_best_point_on_a_toy_problem() -> None:
    """A problem with only dim, x0 and evaluate gets the best point found, not x0 back."""
    assert isinstance(Sphere(), optimizers.Problem)
    start = float(Sphere().evaluate(Sphere.x0[None])[0])  # 4 * 1.5**2 = 9
    assert start == 9.0
    for name in ("local-search", "random-search"):
        found = optimizers.run_optimizer(Sphere(), name, rng=0, max_evaluations=2000)
        assert found.energy < 0.1 * start, (name, found.energy)
        assert found.energy == pytest.approx(float(Sphere().evaluate(found.x[None])[0]))
        assert not np.allclose(found.x, Sphere.x0)
    none = optimizers.run_optimizer(Sphere(), "none", rng=0)
    assert np.array_equal(none.x, Sphere.x0) and none.energy == np.inf and none.evaluations == 0


def test_a_fifteen_line_custom_optimizer() -> None:
    """The cmaes-style example of the docs: a coordinate search in a few lines."""

    class CoordinateSearch(optimizers.BaseOptimizer):
        def reset(self, problem, rng):
            super().reset(problem, rng)
            self.center, self.step, self.best = np.array(problem.x0, float), 1.0, np.inf

        def ask(self):
            if self.step < 1e-3:
                return None
            return self.center + self.step * np.vstack([np.eye(self.dim), -np.eye(self.dim)])

        def tell(self, z, energies):
            i = int(np.argmin(energies))
            if energies[i] < self.best:
                self.best, self.center = float(energies[i]), z[i]
            else:
                self.step /= 2

    found = optimizers.run_optimizer(Sphere(), CoordinateSearch(), rng=0)
    assert np.allclose(found.x, 0.5, atol=1e-3) and found.energy < 1e-5


def test_local_search_improves_on_x0_within_the_paper_budget() -> None:
    problem = make_problem()
    e0 = problem.evaluate_terms(problem.x0, count=False)["E"][0]
    found = optimizers.run_optimizer(
        problem, optimizers.make("local-search"), rng=1, max_evaluations=2000
    )
    assert problem.evaluations == found.evaluations <= 2000
    assert problem.evaluations % 100 == 0
    assert found.energy < e0
    assert problem.evaluate_terms(found.x, count=False)["E"][0] == pytest.approx(found.energy)


class _Scripted:
    """A two-dimensional problem for driving an optimiser by hand (energies given by the test)."""

    dim = 2
    x0 = np.array([1.0, -2.0])

    def evaluate(self, z: np.ndarray) -> np.ndarray:  # pragma: no cover - never called
        raise AssertionError("the test tells the energies itself")


def test_local_search_scores_x0_moves_on_strict_improvement_and_halves_its_step() -> None:
    """Shum §VI-E with the step rule of ``local-search`` (halving, ``shrink=0.5``), by hand.

    Each batch is ``center + step * N(0, I)`` (a twin generator gives the same normals); the
    first batch has x0 itself in row 0. A batch whose best only ties the current best is no
    improvement: the step halves, 0.25 -> 0.125 -> ... -> 0.015625 -> 0.0078125 < min_step =
    0.01, and the search stops.
    """
    search = optimizers.make(
        "local-search", samples=4, iterations=20, step=0.25, min_step=0.01, proposals="normal"
    )
    search.reset(_Scripted(), np.random.default_rng(7))
    twin = np.random.default_rng(7)
    x0 = _Scripted.x0
    # (energies told, step of the batch, center of the batch); energies index 0 is the batch's
    # row 0. Batch 1: x0 (row 0) is the best, energy 0 -> center x0, best 0.
    # Batch 2: a tie at 0 is no improvement -> step 0.125. Batch 3: row 1 improves to -1 ->
    # center moves there, step stays. Batch 4: a tie at -1 -> 0.0625; then three batches with
    # nothing better -> 0.03125, 0.015625, 0.0078125 (< 0.01: stop).
    script = [
        ([0.0, 5.0, 5.0, 5.0], 0.25),
        ([0.0, 1.0, 1.0, 1.0], 0.25),
        ([1.0, -1.0, 1.0, 1.0], 0.125),
        ([-1.0, 0.0, 0.0, 0.0], 0.125),
        ([0.0, 0.0, 0.0, 0.0], 0.0625),
        ([0.0, 0.0, 0.0, 0.0], 0.03125),
        ([0.0, 0.0, 0.0, 0.0], 0.015625),
    ]
    center = x0
    for batch, (energies, step) in enumerate(script):
        z = search.ask()
        assert z is not None, f"batch {batch} should be asked"
        expected = center + step * twin.standard_normal((4, 2))
        if batch == 0:
            expected[0] = x0  # the start is scored
        np.testing.assert_allclose(z, expected, rtol=0, atol=1e-12, err_msg=f"batch {batch}")
        search.tell(z, np.array(energies))
        if batch == 2:
            center = z[1]
    assert search.ask() is None  # the step fell below min_step


def test_local_search_literal_rule_stops_at_the_first_batch_without_improvement() -> None:
    search = optimizers.make("local-search", samples=3, shrink=None)
    search.reset(_Scripted(), np.random.default_rng(0))
    z = search.ask()
    assert z is not None
    search.tell(z, np.array([2.0, 1.0, 3.0]))
    z = search.ask()
    assert z is not None
    search.tell(z, np.array([1.0, 1.0, 1.0]))  # ties the best: a local optimum
    assert search.ask() is None


def test_run_optimizer_returns_x0_when_x0_is_the_minimum() -> None:
    """x0 is scored: on a bowl centred at x0, no sample can beat it, so x0 and E = 0 come back."""

    class Bowl:
        dim = 3
        x0 = np.array([0.5, -0.25, 2.0])

        def evaluate(self, z: np.ndarray) -> np.ndarray:
            return ((z - self.x0) ** 2).sum(axis=1)  # 0 at x0 only

    found = optimizers.run_optimizer(Bowl(), "local-search", rng=0, max_evaluations=300)
    np.testing.assert_array_equal(found.x, Bowl.x0)
    assert found.energy == 0.0
    assert found.evaluations == 300  # three batches of 100: the step halves twice, no stop yet


def test_local_search_beats_random_search_and_none_keeps_x0() -> None:
    energies = {}
    for name in ("local-search", "random-search", "none"):
        problem = make_problem(seed=3)
        z = optimizers.run_optimizer(problem, name, rng=2).x
        energies[name] = problem.evaluate_terms(z, count=False)["E"][0]
        if name == "none":
            assert problem.evaluations == 0 and np.array_equal(z, problem.x0)
        if name == "random-search":
            assert problem.evaluations == 2000
    assert energies["local-search"] < energies["random-search"]
    assert energies["local-search"] < energies["none"]


def test_cma_es_warm_starts_at_x0_and_respects_the_budget() -> None:
    pytest.importorskip("cmaes")
    problem = make_problem(seed=4)
    e0 = problem.evaluate_terms(problem.x0, count=False)["E"][0]
    found = optimizers.run_optimizer(problem, "cma-es", rng=5, max_evaluations=600)
    assert problem.evaluations == 600 == found.evaluations
    assert found.energy < e0


def test_same_seed_same_result_different_seed_different_path() -> None:
    runs = []
    for seed in (7, 7, 8):
        problem = make_problem()
        runs.append(optimizers.run_optimizer(problem, "local-search", rng=seed).x)
    assert np.array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


def test_budget_clips_a_batch_and_stops() -> None:
    """A batch larger than what is left is clipped: its first rows are scored, the rest get
    inf (told to the optimiser), and the search ends."""
    told: list[np.ndarray] = []

    class Wide(optimizers.BaseOptimizer):
        def ask(self):
            return np.zeros((100, self.dim)) + len(told)

        def tell(self, z, energies):
            told.append(energies)

    problem = make_problem()
    found = optimizers.run_optimizer(problem, Wide(), rng=0, max_evaluations=150)
    assert found.evaluations == problem.evaluations == 150 and found.asks == 2
    assert np.all(np.isfinite(told[0])) and np.all(np.isfinite(told[1][:50]))
    assert np.all(np.isinf(told[1][50:]))
    # Uncounted diagnostics still work; a wrong shape is an error naming Z.
    assert problem.evaluate_terms(np.zeros((2, problem.dim)), count=False)["Ec"].shape == (2,)
    with pytest.raises(ValueError, match="Z"):
        problem.evaluate(np.zeros((3, problem.dim + 1)))
    with pytest.raises(ValueError, match="max_evaluations"):
        optimizers.run_optimizer(problem, Wide(), max_evaluations=-1)


def test_time_budget_stops_the_search() -> None:
    problem = make_problem()
    found = optimizers.run_optimizer(problem, "random-search", rng=0, time_budget_s=1e-9)
    assert found.evaluations == problem.evaluations == 100  # one batch, then the clock ran out


def test_unlimited_budget_with_a_stopping_optimizer() -> None:
    problem = make_problem()
    found = optimizers.run_optimizer(problem, optimizers.make("random-search", iterations=3), rng=0)
    assert found.evaluations == 300 and found.asks == 4


def test_registry_takes_module_attr_strings_without_importing() -> None:
    optimizers.register("lazy-for-test", "optimizers.none:NoSearch", overwrite=True)
    assert type(optimizers.make("lazy-for-test")).__name__ == "NoSearch"
    optimizers.register("missing-for-test", "no_such_module_xyz:Thing", overwrite=True)
    with pytest.raises(ModuleNotFoundError):
        optimizers.make("missing-for-test")
    with pytest.raises(ValueError, match="module:attr"):
        optimizers.register("bad-for-test", "no-colon")


def test_plug_ins_register_themselves_and_the_registry_names_none_of_them() -> None:
    """The optimiser layer names no module above it: ``closed-form`` and the ``learned``
    prefixes come from the modules that define them (declared as ``optimizers.plugins`` entry
    points, so a fresh program finds them by name alone)."""
    source = Path(optimizers.registry.__file__).read_text()
    assert "fpg_gym" not in source and "policies" not in source
    code = (
        "import sys, optimizers\n"
        "assert 'fpg_gym' not in sys.modules and 'policies' not in sys.modules\n"
        "print(type(optimizers.make('closed-form')).__module__)\n"
        "print(' '.join(optimizers.prefixes()))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split("\n")
    assert out[0] == "fpg_gym.reconstruct.closed_form"
    assert out[1].split() == ["learned", "learned+search"]


def test_closed_form_refuses_a_plain_problem_naming_the_problem_it_needs() -> None:
    """``available()`` lists ``closed-form``; on a problem with only dim, x0 and evaluate it
    stops with an error that names the per-frame problem, not an AttributeError."""
    assert "closed-form" in optimizers.available()
    with pytest.raises(optimizers.OptimizerError, match=r"SearchProblem.*without kinect_pose"):
        optimizers.run_optimizer(Sphere(), "closed-form", rng=0)
    optimizers.run_optimizer(make_problem(), "closed-form", rng=0)  # the per-frame problem: fine


def _quadratic_energy(problem: SearchProblem, points: np.ndarray, style: float) -> np.ndarray:
    """w_c Ec + w_m Em + the ridge and the faint whitened prior of the closed form."""
    terms = problem.evaluate_terms(points, count=False)
    w = problem.weights
    u = points * problem.latent.std
    ridge = (w.style / 20) * style * (u**2).sum(axis=1)
    faint = 1e-5 * (points**2).sum(axis=1)
    return w.control * terms["Ec"] + w.motion * terms["Em"] + ridge + faint


def test_closed_form_minimises_the_quadratic_energy_with_one_evaluation() -> None:
    """The closed-form point has zero gradient of the quadratic energy (checked by central
    differences) and costs exactly one evaluation."""
    from fpg_gym.graph import FilteredPoseGraph
    from fpg_gym.io import load_default_clips
    from fpg_gym.reconstruct import Reconstructor
    from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE
    from fpg_gym.simulate import simulate

    clips = load_default_clips(["walk", "run", "kick", "punch"])
    graph = FilteredPoseGraph.build(clips[1:], thres1=0.05, progress=False)
    recording = simulate(clips[0], "front-many", seed=3)
    # The point does not depend on the energy's dtype; central differences need float64 terms.
    rec = Reconstructor(graph, energy_dtype="float64")
    for t in range(3):
        problem = rec.prepare(recording.positions[t], recording.states[t], recording.timestamps[t])
        z = optimizers.run_optimizer(problem, "closed-form", np.random.default_rng(0)).x
        assert problem.evaluations == 1
        h = 1e-4
        steps = np.vstack([np.eye(problem.dim), -np.eye(problem.dim)]) * h
        values = _quadratic_energy(problem, z[None] + steps, DEFAULT_STYLE)
        gradient = (values[: problem.dim] - values[problem.dim :]) / (2 * h)
        centre = _quadratic_energy(problem, z[None], DEFAULT_STYLE)[0]
        assert np.abs(gradient).max() < 1e-6 * max(centre, 1.0), (t, np.abs(gradient).max())
        # A step away in any direction raises it.
        assert np.all(values >= centre - 1e-12)
        rec.finish(z)


def test_an_optimiser_may_recommend_another_point_than_the_lowest() -> None:
    """``recommend`` (Nevergrad's distinction between the best evaluated point and the
    recommendation): the run returns the recommended point with its own energy; without a
    recommendation, the lowest-energy point."""

    class Recommends(optimizers.BaseOptimizer):
        def reset(self, problem, rng):
            super().reset(problem, rng)
            self.asked, self.energies = False, None

        def ask(self):
            if self.asked:
                return None
            self.asked = True
            return np.stack([np.full(self.dim, 0.5), np.full(self.dim, 1.0)])

        def tell(self, z, energies):
            self.points, self.energies = z, energies

        def recommend(self):
            return None if self.energies is None else (self.points[1], float(self.energies[1]))

    found = optimizers.run_optimizer(Sphere(), Recommends(), rng=0)
    assert np.allclose(found.x, 1.0) and found.energy == pytest.approx(4 * 0.5**2)
    assert found.evaluations == 2
    plain = optimizers.run_optimizer(Sphere(), "random-search", rng=0, max_evaluations=50)
    assert plain.energy == pytest.approx(float(Sphere().evaluate(plain.x[None])[0]))
