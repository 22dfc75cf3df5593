"""A frame's search: the compiled local search where it applies, else the ask/tell loop; and
many streams' frames searched side by side.

:func:`run_search` is :func:`optimizers.run_optimizer` for a frame's
:class:`~fpg_gym.reconstruct.SearchProblem`, and :func:`complete_compiled` ends one
:class:`optimizers.OptimizerRun` of many-stream search the same way.
:func:`search_together` runs the searches of many streams' frames side by side: at every
search iteration the points their optimisers asked are stacked and their energies computed with
one call of the fused kernel on the frames' stacked tables
(:class:`~fpg_gym.reconstruct.energy.StackedEnergy`); each stream's result equals its search
alone (to the last bit with the compiled kernel, to floating-point rounding with numpy's).

When the optimiser is
:class:`~optimizers.local_search.LocalSearch` itself (not a subclass), the frame's energy runs
the compiled kernel and the budget has no time limit, the whole search runs as one compiled
kernel (:func:`fpg_gym.reconstruct.compiled_search.local_search`, ``fpg-gym[fast]``): the same
draws, budget and best point as the ask/tell loop, to the last bit, about 1.6x faster with
normal draws and 1.7-1.8x with the proposal table (``python scripts/bench_kernels.py --sections
search``). Any other optimiser, a time budget or no numba runs the ask/tell loop.

The compiled run leaves the :class:`~optimizers.local_search.LocalSearch` object as ``reset``
left it (its ``center`` and ``current_step`` are not advanced; its proposal table is drawn and
kept as the loop would): what a search returns is :class:`optimizers.SearchResult`.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

import numpy as np

from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.seeding import as_generator
from fpg_gym.reconstruct.config import ReconstructorConfig
from fpg_gym.reconstruct.energy import EnergyModel, StackedEnergy
from fpg_gym.reconstruct.kernels import compiled_arguments
from fpg_gym.reconstruct.problem import SearchProblem
from optimizers import Optimizer, OptimizerRun, SearchResult, make
from optimizers.local_search import LocalSearch

__all__ = [
    "OptimizerSpec",
    "budgeted_run",
    "compiled_search_available",
    "complete_compiled",
    "make_generators",
    "make_optimizers",
    "run_search",
    "search_together",
]


def _compiled() -> ModuleType | None:
    """The compiled search kernel's module, or None without numba."""
    return compiled_module("fpg_gym.reconstruct.compiled_search")


def compiled_search_available() -> bool:
    """Whether local search can run compiled (numba installed)."""
    return _compiled() is not None


def _compiled_for(problem: Any, run: OptimizerRun) -> ModuleType | None:
    """The compiled search's module when ``run`` on ``problem`` is a compiled local search's
    (see the module docstring), else None."""
    energy = getattr(problem, "energy", None)
    applies = (
        type(run.optimizer) is LocalSearch
        and isinstance(problem, SearchProblem)
        and isinstance(energy, EnergyModel)
        and energy.kernel == "numba"
        and run.time_budget_s is None
        and problem.dim > 0
        and run.asks == 0
    )
    return _compiled() if applies else None


def complete_compiled(problem: Any, run: OptimizerRun) -> bool:
    """Run ``run`` to its end on ``problem`` with the compiled local search, if it applies.

    Parameters
    ----------
    problem : SearchProblem
    run : optimizers.OptimizerRun
        A run that has not proposed yet.

    Returns
    -------
    bool
        Whether it applied (``run`` is then done, ``problem.evaluations`` counts its rows);
        when False nothing was changed and the caller runs the ask/tell loop.

    Raises
    ------
    ValueError
        If a proposed point is not finite (as ``problem.evaluate`` would raise).
    """
    compiled = _compiled_for(problem, run)
    if compiled is None:
        return False
    optimizer = run.optimizer
    assert isinstance(optimizer, LocalSearch)
    budget = -1 if run.max_evaluations is None else run.max_evaluations
    max_asks = -1 if run.max_asks is None else run.max_asks
    draws: np.random.Generator | np.ndarray = run.rng  # the normal draws: drawn in numba
    state, batches = None, 0
    if optimizer.proposals == "table":
        # Each batch's d + 1 uniforms drawn here, as many batches as the budget allows (an
        # array costs numba less to take than the generator); the draws of the batches the
        # search does not run are given back below.
        batches = optimizer.iterations if max_asks < 0 else min(optimizer.iterations, max_asks)
        if budget >= 0:
            batches = min(batches, -(-budget // optimizer.samples))
        state = run.rng.bit_generator.state
        draws = run.rng.random((batches, problem.dim + 1))
    if optimizer.proposals == "table" and batches > 0:
        table = optimizer.proposal_table()  # the process's shared table
    else:
        table = np.zeros((0, problem.dim))
    x, energy, evaluations, asks, status = compiled.local_search(
        draws,
        table,
        np.ascontiguousarray(problem.x0, dtype=np.float64),
        *compiled_arguments(problem.energy.tables),
        optimizer.samples,
        optimizer.iterations,
        float(optimizer.step),
        0.0 if optimizer.shrink is None else float(optimizer.shrink),
        float(optimizer.min_step),
        budget,
        max_asks,
    )
    if state is not None:  # the generator where the ask/tell loop leaves it
        # every batch but the last is whole; a non-finite batch was drawn, not counted
        drawn = -(-int(evaluations) // optimizer.samples) + (status == compiled.STATUS_NON_FINITE)
        if drawn < batches:
            run.rng.bit_generator.state = state
            run.rng.random((drawn, problem.dim + 1))
    problem.evaluations += int(evaluations)
    if status == compiled.STATUS_NON_FINITE:
        raise ValueError("Z: non-finite latent coordinates")
    run.complete(SearchResult(x=x, energy=float(energy), evaluations=evaluations, asks=asks))
    return True


def budgeted_run(
    problem: SearchProblem,
    optimizer: Optimizer,
    rng: np.random.Generator | int | None,
    config: ReconstructorConfig,
    max_evaluations: int | None = None,
) -> OptimizerRun:
    """An :class:`optimizers.OptimizerRun` of ``optimizer`` on ``problem`` within a
    reconstructor's budget: ``config.max_evaluations`` (or ``max_evaluations`` when given) and
    ``config.time_budget_s``."""
    return OptimizerRun(
        problem,
        optimizer,
        rng,
        max_evaluations=config.max_evaluations if max_evaluations is None else max_evaluations,
        time_budget_s=config.time_budget_s,
    )


def run_search(
    problem: SearchProblem,
    optimizer: Optimizer | str,
    rng: np.random.Generator | int | None = None,
    *,
    max_evaluations: int | None = None,
    time_budget_s: float | None = None,
) -> SearchResult:
    """:func:`optimizers.run_optimizer` on a frame's problem, compiled where it applies.

    Parameters
    ----------
    problem : SearchProblem
    optimizer, rng, max_evaluations, time_budget_s
        As :func:`optimizers.run_optimizer`.

    Returns
    -------
    optimizers.SearchResult
        Equal to :func:`optimizers.run_optimizer`'s, and the generator left in the same state.
    """
    run = OptimizerRun(
        problem, optimizer, rng, max_evaluations=max_evaluations, time_budget_s=time_budget_s
    )
    if not complete_compiled(problem, run):
        while (z := run.propose()) is not None:
            run.receive(problem.evaluate(z))
    return run.result()


OptimizerSpec = str | Optimizer | Callable[[], Optimizer]

#: Most streams whose energies are evaluated by one stacked call.
STACK_SIZE = 8


def make_optimizers(optimizer: OptimizerSpec, count: int) -> list[Optimizer]:
    """One optimiser object per stream: a name is made, a factory called, an object copied.

    Parameters
    ----------
    optimizer : str, Optimizer or callable
        A registered name, an optimiser object (deep-copied per stream) or a factory.
    count : int
        Streams.

    Returns
    -------
    list of Optimizer
        ``count`` distinct objects.

    Raises
    ------
    ValueError
        If ``optimizer`` is none of these.
    """
    if isinstance(optimizer, str):
        return [make(optimizer) for _ in range(count)]
    if isinstance(optimizer, Optimizer):
        return [copy.deepcopy(optimizer) for _ in range(count)]
    if callable(optimizer):
        return [make(optimizer()) for _ in range(count)]
    raise ValueError(f"optimizer: expected a name, an optimiser or a factory, got {optimizer!r}")


def make_generators(rngs: Any, count: int) -> list[np.random.Generator]:
    """One generator per stream from a sequence of seeds or generators (None: unseeded).

    Parameters
    ----------
    rngs : sequence of int or numpy.random.Generator, or None
        One per stream; a generator is used as is, a seed starts a new one.
    count : int
        Streams.

    Returns
    -------
    list of numpy.random.Generator

    Raises
    ------
    ValueError
        If ``rngs`` is a single seed or generator, or does not hold ``count`` items.
    """
    if rngs is None:
        return [np.random.default_rng() for _ in range(count)]
    if isinstance(rngs, (int, np.integer, np.random.Generator)):
        raise ValueError(
            "rngs: expected one seed or generator per stream (a sequence), got a single one"
        )
    items = list(rngs)
    if len(items) != count:
        raise ValueError(f"rngs: expected {count} seeds or generators, got {len(items)}")
    return [as_generator(r) for r in items]


def search_together(problems: Sequence[Any], runs: Sequence[OptimizerRun]) -> np.ndarray:
    """Run the searches ``runs[i]`` on ``problems[i]`` side by side until all are over.

    A local search that runs compiled (:func:`fpg_gym.reconstruct.search.complete_compiled`)
    runs first, alone: it does not leave the kernel between batches. Then each round, every
    search still running proposes a batch; the batches of problems whose
    energies stack (:class:`SearchProblem` with equal :meth:`EnergyModel.stack_key` and batch
    size) are evaluated with one :class:`StackedEnergy` call, the others one by one with
    ``problem.evaluate``. Each :class:`SearchProblem` counts its rows in ``evaluations``.

    Returns
    -------
    ndarray, shape (len(problems),)
        Seconds of each search: its optimiser's calls and its share (by rows) of the stacked
        evaluations.

    Raises
    ------
    ValueError
        When an optimiser proposes non-finite points (naming the stream).
    """
    if len(problems) != len(runs):
        raise ValueError(f"runs: expected {len(problems)} (one per problem), got {len(runs)}")
    seconds = np.zeros(len(problems))
    clock = time.perf_counter
    live = []
    for i, (problem, run) in enumerate(zip(problems, runs, strict=True)):
        start = clock()
        try:
            compiled = complete_compiled(problem, run)  # a compiled local search runs alone
        except ValueError as error:
            raise ValueError(
                f"stream {i}: the optimiser proposed non-finite latent points"
            ) from error
        if not compiled:
            live.append(i)
        seconds[i] += clock() - start
    stacks: dict[tuple[Any, ...], tuple[StackedEnergy, dict[int, int]]] = {}
    members: dict[tuple[Any, ...], list[int]] = {}
    for i in live:
        problem = problems[i]
        energy = getattr(problem, "energy", None)
        if (
            isinstance(problem, SearchProblem)
            and isinstance(energy, EnergyModel)
            and energy.kernel != "direct"
        ):
            members.setdefault(energy.stack_key(), []).append(i)
    key_of: dict[int, tuple[Any, ...]] = {}
    for key, indices in members.items():
        # Stacks of a few streams each: their temporaries stay in cache (measured: 8 streams
        # per stack cost 0.7x the time per stream of one stack of 32).
        for first in range(0, len(indices), STACK_SIZE):
            chunk = indices[first : first + STACK_SIZE]
            if len(chunk) < 2:  # alone: its own problem.evaluate, as run_search
                continue
            stack = StackedEnergy.of([problems[i].energy for i in chunk])
            stacks[(*key, first)] = (stack, {stream: row for row, stream in enumerate(chunk)})
            key_of.update((i, (*key, first)) for i in chunk)

    while live:
        groups: dict[tuple[Any, ...], list[tuple[int, np.ndarray]]] = {}
        still: list[int] = []
        for i in live:
            start = clock()
            z = runs[i].propose()
            if z is not None and i not in key_of:
                if not np.isfinite(z).all():
                    raise ValueError(f"stream {i}: the optimiser proposed non-finite latent points")
                runs[i].receive(problems[i].evaluate(z))
            seconds[i] += clock() - start
            if z is None:
                continue
            still.append(i)
            if i in key_of:
                groups.setdefault((*key_of[i], len(z)), []).append((i, z))
        for group_key, batch in groups.items():
            start = clock()
            stack, rows = stacks[group_key[:-1]]
            streams = [i for i, _ in batch]
            if len(streams) != len(stack):
                stack = stack.select(np.array([rows[i] for i in streams]))
            values = stack.total(np.stack([z for _, z in batch]))
            if not np.isfinite(values).all():  # n values to check rather than n x d
                for i, z in batch:
                    if not np.isfinite(z).all():
                        raise ValueError(
                            f"stream {i}: the optimiser proposed non-finite latent points"
                        )
            share = (clock() - start) / len(batch)
            for j, (i, z) in enumerate(batch):
                start = clock()
                problems[i].evaluations += len(z)
                runs[i].receive(values[j])
                seconds[i] += share + clock() - start
        live = still
    return seconds
