"""Many streams in one process: their per-frame searches evaluated together.

:func:`reconstruct_many` reconstructs N recordings frame by frame in lockstep: each stream has
its own :class:`~fpg_gym.reconstruct.Reconstructor` (its own history, bone lengths, selector
state) and its own optimiser and generator, so every stream's output equals what
``Reconstructor.reconstruct`` gives it alone with the same seed (to the last bit with the
compiled kernel, to floating-point rounding with numpy's; the tests check it). What is shared
is the search's arithmetic: at every search iteration the points the N optimisers asked are
stacked and their energies computed with one call of the fused kernel on the frames' stacked
tables (:class:`~fpg_gym.reconstruct.energy.StackedEnergy`). The budget rules are those of
:func:`optimizers.run_optimizer` (:class:`optimizers.OptimizerRun`, one per stream).

Per-frame timings
-----------------
The ``search`` stage time of a frame's record (:attr:`FrameRecord.ms`) is the stream's own
share: the time spent in its optimiser's calls plus its share (by rows) of each stacked
evaluation it took part in; ``total`` is corrected with it.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from tqdm import tqdm

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.seeding import as_generator
from fpg_gym.reconstruct.config import ReconstructorConfig
from fpg_gym.reconstruct.energy import EnergyModel, StackedEnergy
from fpg_gym.reconstruct.output_correction import output_correction_of
from fpg_gym.reconstruct.problem import SearchProblem
from fpg_gym.reconstruct.reconstructor import Reconstructor
from fpg_gym.reconstruct.records import FrameRecord, ReconstructionResult
from fpg_gym.reconstruct.search import complete_compiled
from optimizers import Optimizer, OptimizerRun, make

__all__ = [
    "OptimizerSpec",
    "make_generators",
    "make_optimizers",
    "reconstruct_many",
    "run_streams",
    "search_together",
]

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


def _stream_arrays(recording: Any, index: int, frame_dt: float) -> tuple[np.ndarray, ...]:
    """``positions`` (T,20,3), ``states`` (T,20), ``timestamps`` (T,) of one recording."""
    name = f"recordings[{index}]"
    positions = pose_utils.as_poses(recording.positions, f"{name}.positions", ndim=3)
    states = np.asarray(recording.states)
    if states.shape != positions.shape[:2]:
        raise ValueError(f"{name}.states: expected shape {positions.shape[:2]}, got {states.shape}")
    stamps = getattr(recording, "timestamps", None)
    timestamps = (
        np.arange(len(positions)) * frame_dt
        if stamps is None
        else np.asarray(stamps, dtype=np.float64).reshape(-1)
    )
    if timestamps.shape != (len(positions),):
        raise ValueError(
            f"{name}.timestamps: expected shape ({len(positions)},), got {timestamps.shape}"
        )
    return positions, states, timestamps


def _own_search_time(record: FrameRecord, search_ms: float) -> FrameRecord:
    """The record with the stream's own search time (not the batch's): its ``ms``, a dict new
    with the frame (``Reconstructor.finish``), set in place."""
    ms = record.ms
    ms["total"] += search_ms - ms["search"]
    ms["search"] = search_ms
    return record


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


def run_streams(
    reconstructors: Sequence[Reconstructor],
    recordings: Sequence[Any],
    optimizer: OptimizerSpec = "local-search",
    rngs: Sequence[np.random.Generator | int] | None = None,
    *,
    progress: bool = False,
) -> list[ReconstructionResult]:
    """Reconstruct ``recordings[i]`` with ``reconstructors[i]``, all streams in lockstep.

    Parameters
    ----------
    reconstructors : sequence of Reconstructor
        One per recording, distinct objects (each keeps its stream's state; each is reset).
    recordings : sequence of Recording-like
        ``positions`` (T,20,3), ``states`` (T,20), optional ``timestamps`` (T,); lengths may
        differ (a finished stream leaves the batch).
    optimizer : str, Optimizer or callable
        A registered name (made once per stream), an optimiser object (copied per stream) or a
        factory called once per stream.
    rngs : sequence of numpy.random.Generator or int, optional
        One seed or generator per stream; None: unseeded.
    progress : bool
        A tqdm bar over all frames, on stderr.

    Returns
    -------
    list of ReconstructionResult
        In the order of ``recordings``; stream i equals
        ``reconstructors[i].reconstruct(recordings[i], optimizer, rngs[i])``.
    """
    count = len(recordings)
    if len(reconstructors) != count:
        raise ValueError(
            f"reconstructors: expected {count} (one per recording), got {len(reconstructors)}"
        )
    if len({id(r) for r in reconstructors}) != count:
        raise ValueError("reconstructors: expected distinct objects (one per stream)")
    arrays = [
        _stream_arrays(rec, i, r.config.frame_dt)
        for i, (rec, r) in enumerate(zip(recordings, reconstructors, strict=True))
    ]
    optimizers = make_optimizers(optimizer, count)
    generators = make_generators(rngs, count)
    lengths = [len(a[0]) for a in arrays]
    outputs = [np.zeros((n, skeleton.NUM_JOINTS, 3), dtype=np.float32) for n in lengths]
    records: list[list[FrameRecord]] = [[] for _ in range(count)]
    for r in reconstructors:
        r.reset()
    bar = tqdm(total=sum(lengths), unit="frame", desc="reconstruct", disable=not progress)
    try:
        for t in range(max(lengths, default=0)):
            active = [i for i in range(count) if t < lengths[i]]
            problems = []
            for i in active:
                positions, states, timestamps = arrays[i]
                problems.append(reconstructors[i].prepare(positions[t], states[t], timestamps[t]))
            runs = [
                OptimizerRun(
                    problem,
                    optimizers[i],
                    generators[i],
                    max_evaluations=reconstructors[i].config.max_evaluations,
                    time_budget_s=reconstructors[i].config.time_budget_s,
                )
                for i, problem in zip(active, problems, strict=True)
            ]
            searched = search_together(problems, runs)
            for i, run, own in zip(active, runs, searched, strict=True):
                outputs[i][t], record = reconstructors[i].finish(
                    run.result().x, correction=output_correction_of(optimizers[i])
                )
                records[i].append(_own_search_time(record, 1e3 * own))
            bar.update(len(active))
    except BaseException:
        for r in reconstructors:  # drop the half-done frame: the objects stay usable
            r.reset()
        raise
    finally:
        bar.close()
    return [
        ReconstructionResult(outputs[i], records[i], False, bones=reconstructors[i].bones.report())
        for i in range(count)
    ]


def reconstruct_many(
    graph: Any,
    recordings: Sequence[Any],
    optimizer: OptimizerSpec = "local-search",
    rngs: Sequence[np.random.Generator | int] | None = None,
    *,
    config: ReconstructorConfig | None = None,
    progress: bool = False,
    **overrides: Any,
) -> list[ReconstructionResult]:
    """Reconstruct many recordings against one graph in one process, searches batched.

    One :class:`Reconstructor` per recording (``config`` and ``overrides`` as for
    :class:`Reconstructor`), then :func:`run_streams`.

    Examples
    --------
    >>> seeds = range(len(recordings))                                   # doctest: +SKIP
    >>> results = reconstruct_many(graph, recordings, rngs=seeds)        # doctest: +SKIP
    >>> [r.num_frames for r in results]                                  # doctest: +SKIP
    """
    reconstructors = [Reconstructor(graph, config, **overrides) for _ in recordings]
    try:
        return run_streams(reconstructors, recordings, optimizer, rngs, progress=progress)
    finally:
        for r in reconstructors:
            r.close()
