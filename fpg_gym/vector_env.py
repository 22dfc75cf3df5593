"""``KinectPoseVectorEnv``: N :class:`~fpg_gym.env.KinectPoseEnv` in one process, searched together.

The env's vector mode (``gym.make_vec("fpg_gym/KinectPose-v0", num_envs=N)``). It is a
:class:`gymnasium.vector.SyncVectorEnv` (the same batched spaces, seeding, autoreset modes and
merged ``infos``) whose sub-envs share one pose graph, with one addition:
:meth:`KinectPoseVectorEnv.search` runs an optimiser on every sub-env's waiting frame problem
side by side, the energies of all streams evaluated with one stacked kernel call per search
iteration (:func:`fpg_gym.reconstruct.search.search_together`), and returns the batch of
actions that step exactly the points found. Driving N episodes is then::

    import gymnasium as gym
    import fpg_gym  # noqa: F401  (registers the env and its vector mode)

    venv = gym.make_vec("fpg_gym/KinectPose-v0", num_envs=4, ragdoll=False)
    obs, infos = venv.reset(seed=0)                  # sub-env i: seed 0 + i
    actions = venv.search("local-search")            # one optimiser per sub-env, batched
    obs, rewards, terminated, truncated, infos = venv.step(actions)

Each sub-env's episode equals the same env driven alone by
:func:`fpg_gym.episodes.run_episode` with its seed and optimiser (to the last bit with the
compiled energy kernel, to rounding with numpy's; tested).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, SyncVectorEnv

from fpg_gym.core.validation import check_integer
from fpg_gym.env import ExactAction, KinectPoseEnv
from fpg_gym.reconstruct import SearchProblem
from fpg_gym.reconstruct.search import (
    OptimizerSpec,
    budgeted_run,
    make_generators,
    make_optimizers,
    search_together,
)
from optimizers import Optimizer, OptimizerRun

__all__ = ["KinectPoseVectorEnv"]


class KinectPoseVectorEnv(SyncVectorEnv[Any, Any]):
    """N Kinect pose reconstruction envs in one process, their frame searches batched.

    A :class:`gymnasium.vector.SyncVectorEnv` of :class:`~fpg_gym.env.KinectPoseEnv`: ``reset``,
    ``step``, ``render``, ``call``, ``get_attr``, ``close`` and the autoreset modes behave as
    there (default ``AutoresetMode.NEXT_STEP``: the step after a sub-env's episode ended resets it
    and ignores its action; ``metadata["autoreset_mode"]`` says which). ``reset(seed=s)`` seeds
    sub-env i with ``s + i`` (or ``s[i]`` for a list); ``infos`` are merged per key with a
    ``"_key"`` mask, as Gymnasium's vector envs do.

    :meth:`search` is the addition: one optimiser per sub-env, run side by side on the sub-envs'
    waiting :class:`~fpg_gym.reconstruct.SearchProblem`, with their energies evaluated together;
    ``venv.step(venv.search(...))`` reconstructs every waiting frame from the point its search
    found.

    Parameters
    ----------
    num_envs : int, optional
        Sub-envs to create from ``env_kwargs`` (default 1); with ``env_fns``, None or their count.
    env_fns : sequence of callables, optional
        Instead of ``env_kwargs``: functions that create the sub-envs (possibly wrapped, e.g. by
        ``gym.make``; their ``unwrapped`` must be a :class:`~fpg_gym.env.KinectPoseEnv`, all
        with the same spaces), for sub-envs that differ (other recordings, other arguments).
    copy : bool
        Return copies of the batched observations (as ``SyncVectorEnv``).
    autoreset_mode : AutoresetMode or str
        ``"NextStep"`` (default), ``"SameStep"`` or ``"Disabled"``.
    **env_kwargs
        :class:`~fpg_gym.env.KinectPoseEnv` arguments, the same for every sub-env. The graph is
        loaded once (by the first sub-env) and shared.

    Attributes
    ----------
    envs : list of gymnasium.Env
        The sub-envs.

    Raises
    ------
    ValueError
        If ``num_envs`` is not a positive integer or disagrees with ``env_fns``, or
        ``env_fns`` comes with ``env_kwargs``, or is empty.
    TypeError
        If a sub-env is not a :class:`~fpg_gym.env.KinectPoseEnv` (wrapped or not).

    Examples
    --------
    >>> venv = KinectPoseVectorEnv(2, ragdoll=False)                       # doctest: +SKIP
    >>> obs, infos = venv.reset(seed=[3, 7])                               # doctest: +SKIP
    >>> obs, rewards, terminated, truncated, infos = venv.step(venv.search("local-search"))
    ...                                                                    # doctest: +SKIP
    """

    metadata: dict[str, Any] = {  # noqa: RUF012  (replaced per instance by SyncVectorEnv)
        **KinectPoseEnv.metadata,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int | None = None,
        *,
        env_fns: Sequence[Callable[[], gym.Env[Any, Any]]] | None = None,
        copy: bool = True,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        **env_kwargs: Any,
    ) -> None:
        if env_fns is None:
            count = check_integer(1 if num_envs is None else num_envs, "num_envs", low=1)
            first = KinectPoseEnv(**env_kwargs)
            shared = {**env_kwargs, "graph": first.graph}  # one graph for all sub-envs
            fns: list[Callable[[], gym.Env[Any, Any]]] = [lambda: first]
            fns += [partial(KinectPoseEnv, **shared)] * (count - 1)
        else:
            if env_kwargs:
                raise ValueError(
                    f"env_kwargs: give either env_fns or KinectPoseEnv arguments, not both "
                    f"(got {sorted(env_kwargs)})"
                )
            fns = list(env_fns)
            if not fns:
                raise ValueError("env_fns: expected at least one function")
            if num_envs is not None and num_envs != len(fns):
                raise ValueError(
                    f"num_envs: expected None or {len(fns)} (len(env_fns)), got {num_envs}"
                )
        super().__init__(fns, copy=copy, autoreset_mode=autoreset_mode)
        bases = [env.unwrapped for env in self.envs]
        for i, base in enumerate(bases):
            if not isinstance(base, KinectPoseEnv):
                self.close()
                raise TypeError(
                    f"env_fns[{i}]: expected a KinectPoseEnv (wrapped or not), got "
                    f"{type(base).__name__}"
                )
        self._bases: list[KinectPoseEnv] = [b for b in bases if isinstance(b, KinectPoseEnv)]
        # The search generators, one per sub-env (seeded at reset, as run_episode seeds its own
        # with the reset seed) and the optimisers of the last search (reused while the same
        # optimiser is asked for, as run_episode reuses one per episode).
        self._search_rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._search_optimizers: tuple[OptimizerSpec, list[Optimizer]] | None = None
        self._finished = np.zeros(self.num_envs, dtype=bool)

    def __repr__(self) -> str:
        if self.spec is None:
            return f"KinectPoseVectorEnv(num_envs={self.num_envs})"
        return f"KinectPoseVectorEnv({self.spec.id}, num_envs={self.num_envs})"

    # ------------------------------------------------------------------ state

    @property
    def bases(self) -> tuple[KinectPoseEnv, ...]:
        """The sub-envs without their wrappers (``env.unwrapped`` of each)."""
        return tuple(self._bases)

    @property
    def problems(self) -> tuple[SearchProblem | None, ...]:
        """Each sub-env's waiting frame problem (None where no frame waits)."""
        return tuple(base.problem for base in self._bases)

    @property
    def searching(self) -> npt.NDArray[np.bool_]:
        """Which sub-envs :meth:`search` searches: those with a frame waiting whose episode has
        not ended (an ended one is reset by the next ``step``, or by ``reset`` with a mask)."""
        waiting = [base.problem is not None for base in self._bases]
        return np.asarray(waiting, dtype=bool) & ~self._finished

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self,
        *,
        seed: int | Sequence[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the sub-envs (all, or ``options["reset_mask"]``'s) and their search generators.

        ``seed``: None (no new seeds), an int ``s`` (sub-env i gets ``s + i``) or one seed per
        sub-env. A sub-env reset with seed ``s_i`` also restarts its :meth:`search` generator as
        ``numpy.random.default_rng(s_i)`` (the generator :func:`~fpg_gym.episodes.run_episode`
        gives the optimiser); without a seed the generator goes on (a fresh unseeded one the first
        time). Returns the batched observation and the merged infos.

        Raises
        ------
        ValueError
            If ``seed`` is a list of the wrong length (or ``reset_mask`` is malformed, as
            ``SyncVectorEnv`` checks).
        """
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int | np.integer):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(
                    f"seed: expected None, an int or {self.num_envs} seeds (one per sub-env), "
                    f"got {len(seeds)}"
                )
        mask = None if options is None else options.get("reset_mask")
        obs, infos = super().reset(seed=seeds, options=options)
        for i, own in enumerate(seeds):
            if mask is not None and not mask[i]:
                continue
            self._finished[i] = False
            if own is not None:
                self._search_rngs[i] = np.random.default_rng(own)
            elif self._search_rngs[i] is None:
                self._search_rngs[i] = np.random.default_rng()
        return obs, infos

    def step(
        self, actions: Any
    ) -> tuple[
        Any,
        npt.NDArray[np.float64],
        npt.NDArray[np.bool_],
        npt.NDArray[np.bool_],
        dict[str, Any],
    ]:
        """Step every sub-env with its row of ``actions`` ``(num_envs, latent_dim)``.

        As ``SyncVectorEnv.step``; rows that are :class:`~fpg_gym.env.ExactAction` (what
        :meth:`search` returns) are stepped unclipped.

        Raises
        ------
        ValueError
            If ``actions`` does not have one row per sub-env (or a row is malformed, as
            :meth:`KinectPoseEnv.step <fpg_gym.env.KinectPoseEnv.step>` checks).
        """
        if isinstance(self.single_action_space, spaces.Box):
            expected = (self.num_envs, *self.single_action_space.shape)
            if np.shape(actions) != expected:
                raise ValueError(
                    f"actions: expected shape {expected} (one row per sub-env), got "
                    f"{np.shape(actions)}"
                )
        obs, rewards, terminated, truncated, infos = super().step(actions)
        if self.autoreset_mode != AutoresetMode.SAME_STEP:  # SAME_STEP has reset them already
            self._finished = terminated | truncated
        return obs, rewards, terminated, truncated, infos

    # ------------------------------------------------------------------ batched search

    def search(
        self,
        optimizer: OptimizerSpec = "local-search",
        rngs: Sequence[np.random.Generator | int] | None = None,
        *,
        max_evaluations: int | None = None,
    ) -> ExactAction:
        """Search every waiting frame with its own optimiser, energies evaluated together.

        One :class:`optimizers.OptimizerRun` per sub-env in :attr:`searching`, on its
        ``problem``, within its budget (the env's ``max_evaluations`` and the reconstructor's
        ``time_budget_s``), all run by :func:`~fpg_gym.reconstruct.search.search_together`. Each
        search equals :meth:`Reconstructor.search <fpg_gym.reconstruct.Reconstructor.search>` on
        that sub-env with the same optimiser and generator.

        Parameters
        ----------
        optimizer : str, Optimizer or callable
            A registered name, an optimiser object (copied per sub-env) or a factory. The
            objects are kept and reused while the same name or object is passed (as
            :func:`~fpg_gym.episodes.run_episode` reuses one per episode).
        rngs : sequence of numpy.random.Generator or int, optional
            One generator (or seed) per sub-env. Default: the vector env's own, seeded at
            :meth:`reset` with each sub-env's seed, so that ``venv.step(venv.search(opt))`` frame
            after frame gives sub-env i the episode ``run_episode(env, opt, seed=seed_i)`` gives
            it alone. Seeds given here start new generators at every call.
        max_evaluations : int, optional
            Energy evaluations per sub-env for this search (default: each env's
            ``max_evaluations``).

        Returns
        -------
        ExactAction, shape (num_envs, latent_dim), float64
            Row i selects exactly the best point of sub-env i's search (stepped unclipped); rows
            of sub-envs not searched are zeros (their episode has ended: the next ``step``
            resets them and ignores the row).

        Raises
        ------
        RuntimeError
            If a sub-env has no frame waiting although its episode has not ended (before
            :meth:`reset`).
        ValueError
            If ``rngs`` does not hold one item per sub-env, ``max_evaluations`` is negative or
            ``optimizer`` is not an optimiser (and if an optimiser proposes non-finite points).
        """
        if max_evaluations is not None:
            check_integer(max_evaluations, "max_evaluations", low=0)
        searching = self.searching
        idle = np.flatnonzero(~searching & ~self._finished)
        if len(idle):
            raise RuntimeError(
                f"search: sub-env {int(idle[0])} has no frame waiting (call reset first)"
            )
        generators: Sequence[np.random.Generator | None] = (
            self._search_rngs if rngs is None else make_generators(rngs, self.num_envs)
        )
        optimizers = self._optimizers(optimizer)
        active = [int(i) for i in np.flatnonzero(searching)]
        problems: list[SearchProblem] = []
        runs: list[OptimizerRun] = []
        for i in active:
            base, generator = self._bases[i], generators[i]
            problem = base.problem
            assert problem is not None and generator is not None  # set by reset
            problems.append(problem)
            runs.append(
                budgeted_run(
                    problem, optimizers[i], generator, base.reconstructor.config, max_evaluations
                )
            )
        search_together(problems, runs)
        actions = np.zeros(self.action_space.shape or (self.num_envs, 0), dtype=np.float64)
        for i, problem, run in zip(active, problems, runs, strict=True):
            actions[i] = self._bases[i].action_for(run.result().x, problem)
        return ExactAction(actions)

    def _optimizers(self, optimizer: OptimizerSpec) -> list[Optimizer]:
        """One optimiser per sub-env: the last search's while ``optimizer`` is the same."""
        cached = self._search_optimizers
        if cached is not None and (
            cached[0] is optimizer or (isinstance(optimizer, str) and cached[0] == optimizer)
        ):
            return cached[1]
        made = make_optimizers(optimizer, self.num_envs)
        self._search_optimizers = (optimizer, made)
        return made
