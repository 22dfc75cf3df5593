"""The search's kernels side by side, in CPU time (``fpg-gym bench``, sections ``kernels`` and
``selection``).

Every figure is the median of ``time.process_time`` over repeated calls, measured in one run with
the alternatives interleaved, so that ratios are comparable on a busy machine:

* **energy** of 100 latent points of a real frame: the fused kernels
  (:mod:`fpg_gym.reconstruct.kernels`: compiled when numba is installed, numpy) against the
  terms' definitions on decoded poses (``"direct"``);
* **frame** without ragdoll (graph selection + local search, 2,000 evaluations) with each
  energy kernel, and local search's pre-drawn proposal table;
* **floor**: the floating-point operations of a frame's 2,000 evaluations divided by this
  machine's measured small-matrix product rate;
* **selection** per frame against graph size: the graph walk, the ``auto`` selector, the exact
  brute force (:func:`~fpg_gym.reconstruct.selection.shum_best_k`: compiled with numba, else
  one GEMV on augmented vectors) and the direct Eq. 9 score of every node.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

import optimizers
from fpg_gym.core import skeleton
from fpg_gym.core.seeding import as_generator
from fpg_gym.reconstruct import Reconstructor
from fpg_gym.reconstruct.kernels import available_kernels, fused_energy
from fpg_gym.reconstruct.problem import SearchProblem
from fpg_gym.reconstruct.search import run_search
from fpg_gym.reconstruct.selection import (
    NodeDatabase,
    SelectionQuery,
    make_selector,
    shum_best_k,
    shum_score,
)
from fpg_gym.reconstruct.streams import Choice, Stream, reconstruct_streams, step_streams
from optimizers.local_search import LocalSearch

__all__ = [
    "cpu_median_us",
    "energy_rows",
    "floor_row",
    "frame_problem",
    "frame_rows",
    "search_rows",
    "selection_rows",
]


def cpu_median_us(fn: Callable[[], object], repeats: int = 25, inner: int = 20) -> float:
    """Median CPU microseconds of one call of ``fn`` (``repeats`` timings of ``inner`` calls)."""
    return interleaved_cpu_us({"fn": fn}, repeats, inner)["fn"]


def interleaved_cpu_us(
    calls: dict[str, Callable[[], object]], repeats: int = 25, inner: int = 20
) -> dict[str, float]:
    """Median CPU microseconds per call of each function, timed in interleaved rounds (so that
    the machine's load affects all alike); each is called once first (compilation, caches)."""
    for fn in calls.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeats):
        for name, fn in calls.items():
            start = time.process_time()
            for _ in range(inner):
                fn()
            times[name].append((time.process_time() - start) / inner)
    return {name: 1e6 * float(np.median(values)) for name, values in times.items()}


def frame_problem(graph: Any, recording: Any, frame: int) -> SearchProblem:
    """The search problem of ``frame`` of ``recording`` (at least 1, at most the last), the
    frames before it reconstructed (graph selection, local search, seed 0)."""
    stream = Stream(
        Reconstructor(graph), recording, optimizers.make("local-search"), as_generator(0)
    )
    frame = max(1, min(frame, recording.num_frames - 1))
    while stream.next < frame:
        step_streams([stream])
    return stream.prepare()


def energy_rows(graph: Any, recording: Any, quick: bool = False) -> list[dict[str, Any]]:
    """CPU microseconds of the energy of 100 points (in the reconstructor's energy dtype) for
    each kernel and the definition."""
    problem = frame_problem(graph, recording, 20 if quick else 60)
    energy = problem.energy
    z = np.random.default_rng(0).standard_normal((100, problem.dim)).astype(energy.dtype)
    direct = type(energy)(
        energy.latent,
        energy.sensor.reshape(skeleton.NUM_JOINTS, 3),
        energy.reliability,
        problem.node_poses,
        energy.lengths,
        None if energy.target is None else energy.target.reshape(skeleton.NUM_JOINTS, 3),
        energy.weights,
        kernel="direct",
    )
    calls: dict[str, Callable[[], object]] = {
        f"fused ({kernel})": functools.partial(fused_energy, z, energy.tables, kernel)
        for kernel in available_kernels()
    }
    calls["direct (definitions on decoded poses)"] = lambda: direct(z)
    timings = interleaved_cpu_us(calls, repeats=5 if quick else 25)
    reference = timings["direct (definitions on decoded poses)"]
    return [
        {"kernel": name, "us_per_100_points": us, "speedup_vs_direct": reference / us}
        for name, us in timings.items()
    ]


#: The reference row of :func:`frame_rows`.
DIRECT_FRAME = "direct (definitions), normal draws"


def frame_rows(graph: Any, recordings: list[Any], quick: bool = False) -> list[dict[str, Any]]:
    """CPU milliseconds per frame (graph + local search, 2,000 evaluations, no ragdoll) for each
    energy kernel and proposal source, interleaved recording by recording."""
    normal = {"proposals": "normal"}
    configs: dict[str, tuple[str, dict[str, Any]]] = {
        f"{kernel} kernel, normal draws": (kernel, normal) for kernel in available_kernels()
    }
    configs[f"{available_kernels()[0]} kernel + proposal table (default)"] = (
        available_kernels()[0],
        {"proposals": "table"},
    )
    configs[DIRECT_FRAME] = ("direct", normal)
    if quick:
        recordings = recordings[:1]
    cpu = {name: 0.0 for name in configs}
    frames = {name: 0 for name in configs}
    search: dict[str, list[np.ndarray]] = {name: [] for name in configs}
    for kernel, kwargs in configs.values():  # warm-up (compilation, imports)
        Reconstructor(graph, energy_kernel=kernel).reconstruct(
            recordings[0].head(3), optimizers.make("local-search", **kwargs), rng=0
        )
    for i, recording in enumerate(recordings):
        for name, (kernel, kwargs) in configs.items():
            reconstructor = Reconstructor(graph, energy_kernel=kernel)
            start = time.process_time()
            result = reconstructor.reconstruct(
                recording, optimizers.make("local-search", **kwargs), rng=i
            )
            cpu[name] += time.process_time() - start
            frames[name] += recording.num_frames
            arrays = result.arrays()
            names = [str(n) for n in arrays["stage_names"]]
            search[name].append(arrays["ms_stages"][:, names.index("search")])
    reference = 1e3 * cpu[DIRECT_FRAME] / max(frames[DIRECT_FRAME], 1)
    rows = []
    for name in configs:
        ms = 1e3 * cpu[name] / max(frames[name], 1)
        rows.append(
            {
                "configuration": name,
                "cpu_ms_per_frame": ms,
                "search_wall_median_ms": float(np.median(np.concatenate(search[name]))),
                "speedup_vs_direct": reference / ms,
            }
        )
    return rows


def floor_row(dim: int = 20, k: int = 30, evaluations: int = 2000) -> dict[str, Any]:
    """The arithmetic floor of a frame's search on this machine.

    Floating-point operations of ``evaluations`` fused energies (the ``(n, d) x (d, d + 1 + K +
    57)`` product and the per-row reductions) divided by the measured rate of that product at
    ``n = 100``.
    """
    columns = dim + 1 + k + 3 * skeleton.NUM_BONES
    rng = np.random.default_rng(0)
    z, matrix = rng.standard_normal((100, dim)), rng.standard_normal((dim, columns))
    seconds = 1e-6 * cpu_median_us(lambda: z @ matrix, repeats=25, inner=200)
    gemm_flops = 2.0 * 100 * dim * columns
    rate = gemm_flops / seconds
    per_point = 2.0 * dim * columns + 2 * dim + 2 * k + 9 * skeleton.NUM_BONES
    flops = per_point * evaluations
    return {
        "evaluations": evaluations,
        "mflop": flops / 1e6,
        "gemm_gflops": rate / 1e9,
        "floor_ms": 1e3 * flops / rate,
    }


def _search_keeping(
    kept: list[SearchProblem],
    step: int,
    problems: Sequence[SearchProblem],
    streams: Sequence[Stream],
) -> list[Choice]:
    """A stream's chooser: local search seeded with the frame's number, every ``step``-th
    frame's problem kept in ``kept``."""
    (problem,), (stream,) = problems, streams
    if stream.next % step == 0:
        kept.append(problem)
    return [Choice(stream.reconstructor.search("local-search", stream.next).x)]


def search_rows(
    graph: Any, recordings: list[Any], frames: int = 30, repeats: int = 3
) -> list[dict[str, Any]]:
    """CPU ms of local search alone (2,000 evaluations) on recorded frame problems: the
    ask/tell loop (``optimizers.run_optimizer``) against the compiled search
    (``fpg_gym.reconstruct.search.run_search``), interleaved problem by problem, for both
    proposal sources; ``differ`` counts the problems whose results (point, energy, asks) are not
    equal. ``frames`` problems per recording, each searched ``repeats`` times."""
    problems: list[SearchProblem] = []
    for recording in recordings:
        keep = functools.partial(_search_keeping, problems, max(1, recording.num_frames // frames))
        reconstruct_streams([Stream(Reconstructor(graph), recording)], keep)
    rows = []
    for proposals in ("normal", "table"):
        cpu = {"loop": 0.0, "compiled": 0.0}
        differ = 0
        for i, problem in enumerate(problems * repeats):
            found = {}
            for name, run in (("loop", optimizers.run_optimizer), ("compiled", run_search)):
                optimizer = LocalSearch(proposals=proposals)
                generator = np.random.default_rng(i)
                if proposals == "table":  # drawn once per stream, not per frame: not timed
                    optimizer.reset(problem, generator)
                    optimizer.proposal_table()
                start = time.process_time()
                found[name] = run(problem, optimizer, generator, max_evaluations=2000)
                cpu[name] += time.process_time() - start
            a, b = found["loop"], found["compiled"]
            differ += not (np.array_equal(a.x, b.x) and (a.energy, a.asks) == (b.energy, b.asks))
        count = repeats * len(problems)
        rows.append(
            {
                "proposals": proposals,
                "problems": count,
                "loop_ms": 1e3 * cpu["loop"] / count,
                "compiled_ms": 1e3 * cpu["compiled"] / count,
                "differ": differ,
            }
        )
    return rows


def recorded_queries(graph: Any, recordings: list[Any]) -> list[SelectionQuery]:
    """The selection queries of a graph-selection reconstruction (no search) of ``recordings``
    (pose, reliability, continuity prediction, settled bone lengths), in stream order."""
    queries: list[SelectionQuery] = []
    reconstructor = Reconstructor(graph, selector="graph")
    select = reconstructor.selector.select

    def spy(query: SelectionQuery) -> Any:
        queries.append(query)
        return select(query)

    setattr(reconstructor.selector, "select", spy)  # noqa: B010 - record real queries
    for i, recording in enumerate(recordings):
        reconstructor.reconstruct(recording, "none", rng=i)
    return queries


def selection_rows(
    graph: Any, recordings: list[Any], k: int = 30, quick: bool = False
) -> dict[str, Any]:
    """CPU milliseconds per frame of each selector on the queries of ``recordings``.

    The queries are those of a graph-selection reconstruction (no search); the stateful
    selectors (``graph``, ``auto``) replay them in order, the full searches score each alone.
    """
    queries = recorded_queries(graph, recordings)
    queries = [q for q in queries if np.any(q.reliability)] or queries
    database = NodeDatabase(np.asarray(graph.poses))
    row: dict[str, Any] = {"nodes": len(database), "queries": len(queries)}
    for name in ("graph", "auto"):
        selector = make_selector(name, graph, k, database=database)
        times, scored, full = [], [], 0
        for query in queries:
            start = time.process_time()
            selection = selector.select(query)
            times.append(time.process_time() - start)
            scored.append(selection.num_scored)
            full += selection.full_search
        row[f"{name}_ms"] = 1e3 * float(np.median(times))
        row[f"{name}_p95_ms"] = 1e3 * float(np.percentile(times, 95))
        row[f"{name}_scored"] = float(np.median(scored))
        row[f"{name}_full_searches"] = full
    sample = queries[:: max(1, len(queries) // (8 if quick else 40))]
    for query in sample[:2]:
        shum_best_k(database, query, k)  # build the cached tables outside the timing

    def direct(query: SelectionQuery) -> Any:  # Eq. 9 of every node, the K best sorted
        scores = shum_score(query.pose, query.reliability, database.all_poses(query.lengths))
        best = np.argpartition(scores, k - 1)[:k] if k < len(scores) else np.arange(len(scores))
        return best[np.argsort(scores[best], kind="stable")]

    for name, fn in (
        ("brute_gemv", lambda q: shum_best_k(database, q, k)),
        ("brute_direct", direct),
    ):
        times = []
        for query in sample:
            start = time.process_time()
            fn(query)
            times.append(time.process_time() - start)
        row[f"{name}_ms"] = 1e3 * float(np.median(times))
    row["gemv_speedup"] = row["brute_direct_ms"] / row["brute_gemv_ms"]
    return row
