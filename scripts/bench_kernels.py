"""Issue 18's acceptance figures: the new search kernels against the previous implementation.

The energy's reference is its definition (``EnergyModel(kernel="direct")``: the terms of
:mod:`fpg_gym.reconstruct.energy` on decoded poses); the previous selection is kept in the tests
(``tests/reference_selection.py``), and this script imports it from there. Both are timed in one
process, interleaved, in CPU time (``time.process_time``), with BLAS on one thread:

1. **Energy** of 100 latent points of real frames: ``EnergyModel`` (fused kernel) against the
   definition.
2. **Frame without ragdoll** (graph selection + local search, 2,000 evaluations) on held-out
   Bandai Namco takes (``dataset-1``, split of ``scripts/holdout_split.py``, graph ``thres1 =
   0.2`` from the other takes, simulated ``front-many``): the reference (the energy's
   definition, ask/tell loop with normal draws, numpy stages) against today's pipeline with
   normal draws and with its default proposal table; mean error and median energy of each, so
   that equal results can be seen.
3. **Local search alone** (2,000 evaluations) on frame problems of those takes: the ask/tell
   loop of ``optimizers.run_optimizer`` against the compiled search of
   ``fpg_gym.reconstruct.search.run_search``, with normal draws and with the proposal table;
   the results are checked equal.
4. **Exact brute force** (Shum Eq. 9, K = 30) against the previous direct score on databases of
   1k to 100k nodes: the Bandai graph's nodes (``thres1`` 0.2 and 0.04), and for larger sizes
   copies of the 0.04 graph's nodes with 1 cm of noise; the same K nodes are checked for every
   query.
5. **Selection at scale** (``--graph FILE``, a prebuilt graph of ~100k nodes, or
   ``--scale-thres1`` to build one from the training takes of dataset-1 and dataset-2, ~10-20
   min): the ``graph``, ``auto`` and ``brute-force`` selectors (and the full FPG search of first
   frames and recoveries) on the queries of held-out takes (same split over both datasets),
   today's compiled kernels against the numpy path they replace, interleaved query by query;
   median and p95 CPU ms, and the same selections checked.

Usage::

    python scripts/bench_kernels.py                 # ~20 min: 'scale' builds a 99k-node graph
    python scripts/bench_kernels.py --sections energy,frame,search,brute   # ~5 min
    python scripts/bench_kernels.py --clips 2 --frames 90 --sizes 1000,24000
    python scripts/bench_kernels.py --sections brute,scale --graph /tmp/graph_100k.npz
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the previous selection, kept as test reference
sys.path.insert(0, str(REPO))  # this checkout's fpg_gym, whatever the installed one

from reference_selection import reference_best_k  # noqa: E402

import optimizers  # noqa: E402
from fpg_gym.core import metrics  # noqa: E402
from fpg_gym.core.compiled import numpy_only  # noqa: E402
from fpg_gym.core.holdout import HOLDOUT_SEED, HOLDOUT_SHARE, split_takes  # noqa: E402
from fpg_gym.experiments.bench_kernels import (  # noqa: E402
    frame_problem,
    interleaved_cpu_us,
    recorded_queries,
    search_rows,
)
from fpg_gym.graph import FilteredPoseGraph  # noqa: E402
from fpg_gym.io import load_clips  # noqa: E402
from fpg_gym.reconstruct import Reconstructor  # noqa: E402
from fpg_gym.reconstruct import selection as selection_module  # noqa: E402
from fpg_gym.reconstruct.kernels import compile_kernels  # noqa: E402
from fpg_gym.reconstruct.selection import (  # noqa: E402
    NodeDatabase,
    SelectionQuery,
    make_selector,
    shum_best_k,
)
from fpg_gym.simulate import simulate  # noqa: E402

DEFAULT_DATA = REPO.parent / "shared" / "data"


def frame_table(graph: Any, recordings: list[Any], repeats: int) -> list[dict[str, Any]]:
    """CPU ms per frame and output quality of the previous and the new pipeline, interleaved.

    The reference row is the energy's definition on decoded poses (``energy_kernel="direct"``),
    the ask/tell loop with normal draws, and every stage on its numpy path (:func:`numpy_only`:
    the PCA, the filters, the retarget, the selection). The second row keeps the definition and
    the loop but runs today's compiled stages.
    """
    normal = {"proposals": "normal"}
    configs: dict[str, tuple[str, dict[str, Any], bool]] = {
        "energy's definition, numpy stages (reference)": ("direct", normal, True),
        "energy's definition and loop, compiled stages": ("direct", normal, False),
        "today, normal draws": ("auto", normal, False),
        "today's default (proposal table)": ("auto", {"proposals": "table"}, False),
    }
    stats: dict[str, dict[str, Any]] = {
        name: {"cpu": 0.0, "frames": 0, "errors": [], "energies": []} for name in configs
    }
    for kernel, kwargs, numpy_stages in configs.values():  # warm-up
        with numpy_only() if numpy_stages else contextlib.nullcontext():
            Reconstructor(graph, energy_kernel=kernel).reconstruct(
                recordings[0].head(5), optimizers.make("local-search", **kwargs), rng=0
            )
    for repeat in range(repeats):
        for i, recording in enumerate(recordings):
            for name, (kernel, kwargs, numpy_stages) in configs.items():
                with numpy_only() if numpy_stages else contextlib.nullcontext():
                    reconstructor = Reconstructor(graph, energy_kernel=kernel)
                    start = time.process_time()
                    result = reconstructor.reconstruct(
                        recording,
                        optimizers.make("local-search", **kwargs),
                        rng=i + 100 * repeat,
                    )
                    stats[name]["cpu"] += time.process_time() - start
                stats[name]["frames"] += recording.num_frames
                stats[name]["errors"].append(
                    metrics.frame_error(recording.ground_truth, result.poses)
                )
                stats[name]["energies"].append(result.arrays()["energy"])
    reference = None
    rows = []
    for name, s in stats.items():
        ms = 1e3 * s["cpu"] / s["frames"]
        reference = reference or ms
        errors = np.concatenate(s["errors"])
        rows.append(
            {
                "configuration": name,
                "cpu_ms_per_frame": ms,
                "speedup": reference / ms,
                "mean_error_m": float(errors.mean()),
                "err02_pct": 100.0 * metrics.err_ratio(errors),
                "median_energy": float(np.median(np.concatenate(s["energies"]))),
            }
        )
    return rows


def energy_table(graph: Any, recording: Any, frame: int = 60) -> dict[str, float]:
    """CPU µs of the energy of 100 points of a real frame, the definition vs the fused kernel
    (interleaved)."""
    problem = frame_problem(graph, recording, frame)
    e = problem.energy
    previous = type(e)(
        e.latent,
        e.sensor.reshape(20, 3),
        e.reliability,
        problem.node_poses,
        e.lengths,
        None if e.target is None else e.target.reshape(20, 3),
        e.weights,
        kernel="direct",
    )
    z = np.random.default_rng(0).standard_normal((100, problem.dim))
    if not np.allclose(previous(z), e(z), rtol=1e-9, atol=1e-12):
        raise AssertionError("the fused energy differs from its definition")
    timing = interleaved_cpu_us({"old": lambda: previous(z), "new": lambda: e(z)}, repeats=50)
    return {"previous_us": timing["old"], "fused_us": timing["new"]}


def brute_force_table(
    databases: dict[str, np.ndarray], queries: list[SelectionQuery], k: int = 30
) -> list[dict[str, Any]]:
    """CPU ms per query of the exact brute force (compiled kernel; the numpy GEMV path without
    numba) and the previous direct score, interleaved; the same nodes are checked."""
    compiled = selection_module._compiled
    numpy_path = lambda: None  # noqa: E731 - what shum_best_k sees without numba
    rows = []
    for label, poses in databases.items():
        database = NodeDatabase(poses)
        times: dict[str, list[float]] = {"previous": [], "gemv": [], "compiled": []}
        for query in queries[:2]:
            shum_best_k(database, query, k)  # cached tables outside the timing
        for query in queries:
            start = time.process_time()
            expected, _ = reference_best_k(database, query, k, "shum")
            times["previous"].append(time.process_time() - start)
            for name in ("gemv", "compiled"):
                selection_module._compiled = numpy_path if name == "gemv" else compiled
                try:
                    start = time.process_time()
                    nodes, _ = shum_best_k(database, query, k)
                    times[name].append(time.process_time() - start)
                finally:
                    selection_module._compiled = compiled
                if not np.array_equal(nodes, expected):
                    raise AssertionError(f"{label}: the brute force ({name}) selected other nodes")
        ms = {name: 1e3 * float(np.median(t)) for name, t in times.items()}
        rows.append(
            {
                "database": label,
                "nodes": len(poses),
                "previous_ms": ms["previous"],
                "gemv_ms": ms["gemv"],
                "compiled_ms": ms["compiled"],
                "speedup": ms["previous"] / ms["compiled"],
            }
        )
    return rows


def scale_table(
    graph: Any, recordings: list[Any], k: int = 30, chunk: int = 25
) -> list[dict[str, Any]]:
    """CPU ms per query of each selector on a large graph: compiled kernels (today) against the
    numpy path (the previous implementation), interleaved ``chunk`` queries at a time (query by
    query, each path would run on the caches the other just evicted); the selections are
    compared query by query (``differ``: other nodes or order; ``differ_sets``: other nodes)."""
    queries = recorded_queries(graph, recordings)
    # One database per path: the retargeted-pose cache (refreshed when the lengths move by more
    # than 5 mm) then evolves alike for both, chunk after chunk.
    databases = {label: NodeDatabase(np.asarray(graph.poses)) for label in ("numpy", "compiled")}
    compiled = selection_module._compiled
    numpy_path = lambda: None  # noqa: E731 - what the selectors see without numba
    rows = []
    for name, kwargs in (
        ("graph", {}),
        ("auto", {}),
        ("brute-force", {}),
        ("brute-force (FPG score)", {"score": "fpg"}),
    ):
        selector_name = name.split(" ")[0]
        labels = ("numpy", "compiled")
        selectors = {
            label: make_selector(selector_name, graph, k, database=databases[label], **kwargs)
            for label in labels
        }
        times: dict[str, list[float]] = {label: [] for label in labels}
        full = dict.fromkeys(labels, 0)
        nodes: dict[str, list[np.ndarray]] = {label: [] for label in labels}
        stateful = selector_name != "brute-force"
        sample = queries if stateful else queries[:: max(1, len(queries) // 60)]
        for database in databases.values():
            database.clear_cache()
        for begin in range(0, len(sample), chunk):
            for label, selector in selectors.items():
                selection_module._compiled = numpy_path if label == "numpy" else compiled
                try:
                    for query in sample[begin : begin + chunk]:
                        start = time.process_time()
                        selection = selector.select(query)
                        times[label].append(time.process_time() - start)
                        full[label] += selection.full_search
                        nodes[label].append(selection.nodes)
                finally:
                    selection_module._compiled = compiled
        pairs = list(zip(nodes["numpy"], nodes["compiled"], strict=True))
        rows.append(
            {
                "selector": name,
                "nodes": len(graph.poses),
                "queries": len(sample),
                **{
                    f"{label}_{stat}": 1e3 * float(fn(times[label]))
                    for label in labels
                    for stat, fn in (("ms", np.median), ("p95", lambda t: np.percentile(t, 95)))
                },
                "full_numpy": full["numpy"],
                "full_compiled": full["compiled"],
                "differ": sum(not np.array_equal(a, b) for a, b in pairs),
                "differ_sets": sum(set(a.tolist()) != set(b.tolist()) for a, b in pairs),
            }
        )
    return rows


def scale_graph(args: argparse.Namespace) -> tuple[Any, list[Any]]:
    """The large graph (``--graph`` or built at ``--scale-thres1``) and held-out recordings of
    both Bandai Namco datasets (the split of :func:`split_takes` over all their takes)."""
    root = args.data / "bandai_namco"
    files = sorted(root.glob("dataset-*/*.bvh")) + sorted(root.glob("dataset-*/*.bvh.gz"))
    train, held = split_takes(files, HOLDOUT_SHARE, HOLDOUT_SEED)
    if args.graph is not None:
        graph = FilteredPoseGraph.load(args.graph)
    else:
        graph = FilteredPoseGraph.build(
            load_clips(train, progress=False), thres1=args.scale_thres1, progress=False
        )
    recordings = [
        simulate(c.positions[: args.frames], "front-many", seed=i)
        for i, c in enumerate(load_clips(held[: args.clips], progress=False))
    ]
    return graph, recordings


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--clips", type=int, default=3, help="held-out takes reconstructed")
    parser.add_argument("--frames", type=int, default=240, help="frames per take")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of the frame timing")
    parser.add_argument("--sizes", default="24000,72000,100000", help="synthetic database sizes")
    parser.add_argument(
        "--sections",
        default="energy,frame,search,brute,scale",
        help="comma-separated: energy, frame, search, brute, scale",
    )
    parser.add_argument("--graph", type=Path, default=None, help="prebuilt graph for 'scale'")
    parser.add_argument(
        "--scale-thres1",
        type=float,
        default=0.04,
        help="thres1 of the graph 'scale' builds without --graph (0.04: 99k nodes from both "
        "Bandai datasets' training takes; 0.035: 124k)",
    )
    return parser.parse_args(argv)


def print_energy(graph: Any, recordings: list[Any]) -> None:
    energy = energy_table(graph, recordings[0])
    print(
        f"\nenergy of 100 points: definition {energy['previous_us']:.1f} µs, fused "
        f"{energy['fused_us']:.1f} µs ({energy['previous_us'] / energy['fused_us']:.1f}x)"
    )


def print_frame(graph: Any, recordings: list[Any], repeats: int) -> None:
    header = "| configuration | CPU ms / frame | speed-up | mean error (m) | Err0.2 (%) | "
    header += "median E |"
    print("\n" + header)
    print("| --- | --- | --- | --- | --- | --- |")
    for r in frame_table(graph, recordings, repeats):
        print(
            f"| {r['configuration']} | {r['cpu_ms_per_frame']:.3f} | {r['speedup']:.2f}x | "
            f"{r['mean_error_m']:.4f} | {r['err02_pct']:.1f} | {r['median_energy']:.5f} |"
        )


def print_search(graph: Any, recordings: list[Any]) -> None:
    header = "| local search (2,000 evaluations) | problems | ask/tell loop ms | compiled ms "
    print("\n" + header + "| speed-up | results differ |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in search_rows(graph, recordings):
        print(
            f"| proposals {r['proposals']} | {r['problems']} | {r['loop_ms']:.3f} | "
            f"{r['compiled_ms']:.3f} | {r['loop_ms'] / r['compiled_ms']:.2f}x | "
            f"{r['differ']} |"
        )


def print_brute(graph: Any, clips: list[Any], recordings: list[Any], sizes: str) -> None:
    dense = FilteredPoseGraph.build(clips, thres1=0.04, progress=False)
    print(f"\ndense graph {dense}")
    queries = recorded_queries(graph, recordings[:1])
    queries = [q for q in queries if np.any(q.reliability)][::4][:40]
    base = np.asarray(dense.poses)
    rng = np.random.default_rng(0)
    databases = {"graph thres1 0.2": np.asarray(graph.poses), "graph thres1 0.04": base}
    for size in (int(s) for s in sizes.split(",") if s):
        copies = [base] + [
            base + rng.normal(0.0, 0.01, base.shape).astype(np.float32)
            for _ in range(size // len(base))
        ]
        databases[f"0.04 graph + noisy copies ({size})"] = np.concatenate(copies)[:size]
    print("\n| database | nodes | previous ms | numpy GEMV ms | compiled ms | speed-up |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in brute_force_table(databases, queries):
        print(
            f"| {r['database']} | {r['nodes']} | {r['previous_ms']:.3f} | "
            f"{r['gemv_ms']:.3f} | {r['compiled_ms']:.3f} | {r['speedup']:.1f}x |"
        )


def print_scale(args: argparse.Namespace) -> None:
    big, held_out = scale_graph(args)
    print(f"\nlarge graph {big}, mean degree {np.diff(big.indptr).mean():.0f}")
    print(
        "\n| selector | nodes | queries | numpy ms (p95) | compiled ms (p95) | speed-up "
        "| full searches numpy / compiled | selections differ (other nodes) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in scale_table(big, held_out):
        print(
            f"| {r['selector']} | {r['nodes']} | {r['queries']} | {r['numpy_ms']:.3f} "
            f"({r['numpy_p95']:.3f}) | {r['compiled_ms']:.3f} ({r['compiled_p95']:.3f}) | "
            f"{r['numpy_ms'] / r['compiled_ms']:.1f}x | {r['full_numpy']} / "
            f"{r['full_compiled']} | {r['differ']} ({r['differ_sets']}) |"
        )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    sections = set(args.sections.split(","))
    folder = args.data / "bandai_namco" / "dataset-1"
    if not folder.is_dir():
        print(f"bench_kernels: {folder} is absent (see ../shared/data/README.md)", file=sys.stderr)
        return 2
    limits = threadpool_limits(limits=1, user_api="blas")
    print(f"energy kernels: {', '.join(compile_kernels())}; BLAS threads: 1")
    print(f"selection kernels: {'compiled' if selection_module.compiled_available() else 'numpy'}")
    if sections & {"energy", "frame", "search", "brute"}:
        files = sorted(folder.glob("*.bvh"))
        train, held = split_takes(files, HOLDOUT_SHARE, HOLDOUT_SEED)
        clips = load_clips(train, progress=False)
        graph = FilteredPoseGraph.build(clips, thres1=0.2, progress=False)
        print(f"graph {graph}")
        recordings = [
            simulate(c.positions[: args.frames], "front-many", seed=i)
            for i, c in enumerate(load_clips(held[: args.clips], progress=False))
        ]
    if "energy" in sections:
        print_energy(graph, recordings)
    if "frame" in sections:
        print_frame(graph, recordings, args.repeats)
    if "search" in sections:
        print_search(graph, recordings)
    if "brute" in sections:
        print_brute(graph, clips, recordings, args.sizes)
    if "scale" in sections:
        print_scale(args)
    limits.restore_original_limits()
    return 0


if __name__ == "__main__":
    sys.exit(main())
