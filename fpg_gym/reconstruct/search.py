"""One frame's search: the compiled local search where it applies, else the ask/tell loop.

:func:`run_search` is :func:`optimizers.run_optimizer` for a frame's
:class:`~fpg_gym.reconstruct.SearchProblem`, and :func:`complete_compiled` ends one
:class:`optimizers.OptimizerRun` of many-stream search the same way. When the optimiser is
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

from types import ModuleType
from typing import Any

import numpy as np

from fpg_gym.core.compiled import compiled_module
from fpg_gym.reconstruct.energy import EnergyModel
from fpg_gym.reconstruct.kernels import compiled_arguments
from fpg_gym.reconstruct.problem import SearchProblem
from optimizers import Optimizer, OptimizerRun, SearchResult
from optimizers.local_search import LocalSearch

__all__ = ["compiled_search_available", "complete_compiled", "run_search"]


def _compiled() -> ModuleType | None:
    """The compiled search kernel's module, or None without numba."""
    return compiled_module("fpg_gym.reconstruct.compiled_search")


def compiled_search_available() -> bool:
    """Whether local search can run compiled (numba installed)."""
    return _compiled() is not None


def _applies(problem: Any, run: OptimizerRun) -> bool:
    """Whether ``run`` on ``problem`` is a compiled local search's (see the module docstring)."""
    energy = getattr(problem, "energy", None)
    return (
        type(run.optimizer) is LocalSearch
        and isinstance(problem, SearchProblem)
        and isinstance(energy, EnergyModel)
        and energy.kernel == "numba"
        and run.time_budget_s is None
        and problem.dim > 0
        and run.asks == 0
        and _compiled() is not None
    )


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
    if not _applies(problem, run):
        return False
    compiled = _compiled()
    assert compiled is not None
    optimizer = run.optimizer
    assert isinstance(optimizer, LocalSearch)
    budget = -1 if run.max_evaluations is None else run.max_evaluations
    max_asks = -1 if run.max_asks is None else run.max_asks
    table = np.zeros((0, problem.dim))
    if optimizer.proposals == "table" and budget != 0 and max_asks != 0:
        table = optimizer.proposal_table()  # the process's shared table
    x, energy, evaluations, asks, status = compiled.local_search(
        run.rng,
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
    problem.evaluations += int(evaluations)
    if status == compiled.STATUS_NON_FINITE:
        raise ValueError("Z: non-finite latent coordinates")
    run.complete(SearchResult(x=x, energy=float(energy), evaluations=evaluations, asks=asks))
    return True


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
