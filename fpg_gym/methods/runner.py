"""Runs methods (:mod:`fpg_gym.methods.names`) on recordings against one pose graph: the
filters frame by frame, ``shum``/``fpg`` through the one run path
(:func:`fpg_gym.reconstruct.streams.reconstruct_streams`, one stream or many side by side);
every run gives a :class:`~fpg_gym.reconstruct.ReconstructionResult`."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from fpg_gym.core.poses import RecordingLike
from fpg_gym.core.seeding import as_generator
from fpg_gym.definitions import sensor_to_output_map
from fpg_gym.filters import make_filter
from fpg_gym.methods.names import Method, parse_method
from fpg_gym.methods.ragdoll import RagdollStage, ragdoll_factory, reference_bone_lengths
from fpg_gym.reconstruct import EnergyWeights, ReconstructionResult, Reconstructor
from fpg_gym.reconstruct.config import ReconstructorConfig
from fpg_gym.reconstruct.search import OptimizerSpec
from fpg_gym.reconstruct.streams import (
    Stream,
    reconstruct_stream,
    reconstruct_streams,
    run_streams,
)
from optimizers import make

__all__ = ["MethodRunner", "reconstruct_many"]


def _reconstruction_info(result: ReconstructionResult) -> dict[str, Any]:
    """The facts of a reconstruction the comparisons report: recoveries, the bone lengths'
    settling and, with the ragdoll, its divergences."""
    info: dict[str, Any] = {
        "recoveries": sum(int(r.recovered) for r in result.records),
        "bone_settling": dict(result.bones),
    }
    if any(r.ragdoll for r in result.records):
        info["ragdoll_divergences"] = sum(
            int(r.ragdoll.get("new_divergences", 0)) for r in result.records if r.ragdoll
        )
    return info


class MethodRunner:
    """Runs methods on recordings against one pose graph.

    Keeps the :class:`~fpg_gym.reconstruct.Reconstructor` objects of each (selector, ragdoll,
    prior), one per stream run side by side, and one ragdoll for the filters, so a worker that
    runs many episodes builds each once.

    Parameters
    ----------
    graph : FilteredPoseGraph, optional
        Needed by ``shum`` and ``fpg`` (filters run without one).
    budget : int, optional
        Energy evaluations per frame (the reconstructor's ``max_evaluations``; 2,000).
    reconstructor_options : dict, optional
        Further :class:`~fpg_gym.reconstruct.ReconstructorConfig` fields (e.g. ``k``).
    """

    def __init__(
        self,
        graph: Any = None,
        *,
        budget: int | None = 2000,
        reconstructor_options: dict[str, Any] | None = None,
    ) -> None:
        self.graph = graph
        self.budget = budget
        self.options = dict(reconstructor_options or {})
        # The reconstructors of each kind, one per stream of a batch (pool[0] for one stream).
        self._pools: dict[tuple[str, bool, bool], list[Reconstructor]] = {}
        self._ragdoll_stage: RagdollStage | None = None

    def _reconstructors(self, spec: Method, count: int) -> list[Reconstructor]:
        """``count`` reconstructors of the method's selector, ragdoll and prior."""
        assert spec.selector is not None
        key = (spec.selector, spec.ragdoll, spec.prior)
        if key not in self._pools:
            if self.graph is None:
                raise ValueError("a pose graph is needed for the shum and fpg methods")
            options = dict(self.options)
            if spec.prior:
                options["weights"] = EnergyWeights.with_prior()
            first = Reconstructor(
                self.graph,
                ragdoll=ragdoll_factory(spec.ragdoll),
                selector=spec.selector,
                max_evaluations=self.budget,
                **options,
            )
            self._pools[key] = [first]
        pool = self._pools[key]
        while len(pool) < count:
            pool.append(
                Reconstructor(self.graph, pool[0].config, ragdoll=ragdoll_factory(spec.ragdoll))
            )
        return pool[:count]

    def run(
        self,
        method: Method | str,
        recording: RecordingLike,
        seed: int | np.random.Generator = 0,
        *,
        stop_on_interrupt: bool = False,
        progress: bool = False,
        checkpoint: Callable[[ReconstructionResult], None] | None = None,
        checkpoint_s: float = 30.0,
    ) -> ReconstructionResult:
        """Run ``method`` on ``recording`` (``positions``, ``states``, ``timestamps``).

        ``seed`` drives the optimiser (reconstruction methods); filters are deterministic.
        ``stop_on_interrupt``, ``progress``, ``checkpoint`` and ``checkpoint_s`` are those of
        :func:`~fpg_gym.reconstruct.streams.reconstruct_streams` (reconstruction methods).
        """
        spec = parse_method(method) if isinstance(method, str) else method
        if spec.is_filter:
            return self._run_filter(spec, recording)
        (stream,) = self._streams(spec, [recording], [seed])
        result = reconstruct_stream(
            stream,
            progress=progress,
            stop_on_interrupt=stop_on_interrupt,
            checkpoint=checkpoint,
            checkpoint_s=checkpoint_s,
        )
        result.info.update(_reconstruction_info(result))
        return result

    def run_many(
        self,
        method: Method | str,
        recordings: Sequence[RecordingLike],
        seeds: Sequence[int | np.random.Generator],
    ) -> list[ReconstructionResult]:
        """Run ``method`` on many recordings; ``shum``/``fpg`` reconstruct them side by side
        with their searches batched (:func:`fpg_gym.reconstruct.streams.reconstruct_streams`).

        Each result equals ``run(method, recordings[i], seeds[i])`` (timings aside: a batched
        frame's search time is its share of the batch's, see :mod:`fpg_gym.reconstruct.streams`).
        """
        spec = parse_method(method) if isinstance(method, str) else method
        if len(seeds) != len(recordings):
            raise ValueError(
                f"seeds: expected {len(recordings)} (one per recording), got {len(seeds)}"
            )
        if spec.is_filter:
            return [self._run_filter(spec, recording) for recording in recordings]
        results = reconstruct_streams(self._streams(spec, recordings, seeds))
        for result in results:
            result.info.update(_reconstruction_info(result))
        return results

    def _streams(
        self,
        spec: Method,
        recordings: Sequence[RecordingLike],
        seeds: Sequence[int | np.random.Generator],
    ) -> list[Stream]:
        """One stream per recording for ``shum``/``fpg``: its reconstructor, the method's
        optimiser and the seed's generator."""
        assert spec.optimizer is not None
        return [
            Stream(reconstructor, recording, make(spec.optimizer), as_generator(seed), index=i)
            for i, (reconstructor, recording, seed) in enumerate(
                zip(self._reconstructors(spec, len(recordings)), recordings, seeds, strict=True)
            )
        ]

    def _run_filter(self, spec: Method, recording: RecordingLike) -> ReconstructionResult:
        """A reference filter frame by frame (then the ragdoll, ``+ragdoll``)."""
        assert spec.filter_name is not None
        flt = make_filter(spec.filter_name)
        positions = np.asarray(recording.positions)
        if spec.mapped:
            mapping = sensor_to_output_map(self.options)
            if mapping is None:
                raise ValueError(
                    f"method {spec.name}: no definition map to apply; give a sensor map "
                    "(--sensor-map) or a calibration map (--calibration-map)"
                )
            positions = mapping.apply(positions).astype(np.float32)
        states = np.asarray(recording.states)
        stamps = getattr(recording, "timestamps", None)
        times = np.arange(len(positions)) / 30.0 if stamps is None else np.asarray(stamps)
        out = np.empty(positions.shape, dtype=np.float32)
        ms = np.empty(len(positions))
        flt.reset()
        for t in range(len(positions)):
            t0 = time.perf_counter()
            out[t] = flt.update(positions[t], states[t], float(times[t]))
            ms[t] = 1000.0 * (time.perf_counter() - t0)
        stage_ms = {"filter": ms}
        info: dict[str, Any] = {"filter_params": flt.params}
        if spec.ragdoll:
            if self._ragdoll_stage is None:
                self._ragdoll_stage = RagdollStage()
            lengths = reference_bone_lengths(positions, states)
            out, ragdoll_ms, ragdoll_info = self._ragdoll_stage.run(out, lengths)
            stage_ms["ragdoll"] = ragdoll_ms
            info.update(ragdoll_info)
        return ReconstructionResult(out, info=info, stage_times=stage_ms)

    def close(self) -> None:
        """Release every ragdoll."""
        for pool in self._pools.values():
            for reconstructor in pool:
                reconstructor.close()
        self._pools.clear()
        if self._ragdoll_stage is not None:
            self._ragdoll_stage.close()
            self._ragdoll_stage = None

    def __enter__(self) -> MethodRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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
    :class:`~fpg_gym.reconstruct.Reconstructor`), then
    :func:`~fpg_gym.reconstruct.streams.run_streams`.

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
