"""Optimiser plug-ins for the per-frame search problem: an ask/tell protocol and a registry.

An optimiser is a small object with three methods (the :class:`Optimizer` protocol)::

    reset(problem, rng)   # a new frame: read problem.dim, problem.x0, ... ; keep rng
    ask() -> Z | None     # next batch of latent points (n, d), or None when done
    tell(Z, energies)     # the energies (n,) of that batch (lower is better)

It never calls ``problem.evaluate`` itself: :func:`run_optimizer` does, and owns the budget and
the best point. A problem (the :class:`Problem` protocol) only needs ``dim``, ``x0`` and
``evaluate(Z) -> values``; :class:`fpg_gym.reconstruct.SearchProblem` is the per-frame one.

This package is the bottom layer of fpg-gym: numpy only, it imports nothing of the rest.

Built-in optimisers (``make(name, **kwargs)``):

=================  =====================================================================
``local-search``   Shum §VI-E: start at x0, 100 Gaussian samples per iteration around the
                   best point, move on improvement, stop at a local optimum or on budget
``random-search``  samples from the whitened latent prior N(0, I): the floor to beat
``cma-es``         CMA-ES warm-started at x0 (needs ``pip install 'fpg-gym[cma]'``)
``none``           no search: x0 (the previous reconstruction projected, or the best candidate)
=================  =====================================================================

Plug-ins above this layer register themselves (and are found by name without being imported
first: the registry imports the modules of the ``optimizers.plugins`` entry-point group when a
name is missing):

* ``closed-form`` (:mod:`fpg_gym.reconstruct.closed_form`), beyond the papers: one point, the
  exact minimiser of the energy's quadratic terms (Ec, Em, a ridge for Es) in the latent space
  (1 evaluation). It reads the per-frame problem (:class:`fpg_gym.reconstruct.SearchProblem`)
  and refuses a plain :class:`Problem` with an :class:`OptimizerError` saying so.
* Parametrised names ``PREFIX:ARGUMENT`` call a prefix factory with the argument (see
  :func:`register_prefix`): ``learned:PATH`` and ``learned+search:PATH`` draw candidates from a
  learned sampler saved at ``PATH`` (:mod:`policies.learned_optimizers`, needs
  ``fpg-gym[learn]``).

Third-party optimisers register a factory (usually the class) under a name::

    import optimizers

    @optimizers.register("my-search")
    class MySearch(optimizers.BaseOptimizer):
        def ask(self): ...

    opt = optimizers.make("my-search", samples=50)
    optimizers.register("their-search", "their_package.search:TheirSearch")  # imported on use

A package whose module registers at import can declare it in its ``pyproject.toml``
(``[project.entry-points."optimizers.plugins"]``, ``their-search = "their_package.search"``)
so that its names work in programs that never import it.

The registry is a module-level mapping (like Gymnasium's env registry): registering is the only
way it changes.
"""

from __future__ import annotations

from optimizers.base import (
    BaseOptimizer,
    MissingDependency,
    Optimizer,
    OptimizerError,
    OptimizerNotFound,
    Problem,
)
from optimizers.registry import available, make, prefixes, register, register_prefix
from optimizers.run import OptimizerRun, SearchResult, run_optimizer

__all__ = [
    "BaseOptimizer",
    "MissingDependency",
    "Optimizer",
    "OptimizerError",
    "OptimizerNotFound",
    "OptimizerRun",
    "Problem",
    "SearchResult",
    "available",
    "make",
    "prefixes",
    "register",
    "register_prefix",
    "run_optimizer",
]
