"""Many streams: frames per CPU-second and per wall-second, one by one vs side by side.

Simulates ``--streams`` recordings (the embedded clips in the ``*-many`` scenarios, seed = stream
number, the first ``--frames`` frames each) and reconstructs them, in one run:

1. one by one: ``Reconstructor.reconstruct`` per stream (the first ``--alone`` streams);
2. side by side in this process: :func:`fpg_gym.reconstruct.streams.run_streams`;
3. side by side in ``--processes`` spawned processes (the streams split between them with about
   equal frames).

CPU time is ``time.process_time`` of the process(es) doing the work; wall time is measured
around each. Also checks that each stream run side by side equals its run alone. BLAS threads
are limited to one (``OPENBLAS_NUM_THREADS=1`` unless set).

Usage::

    python scripts/bench_many_streams.py --streams 32 --frames 30
    python scripts/bench_many_streams.py --graph bandai_graph.npz --streams 32
    python scripts/bench_many_streams.py --proposals normal --energy-dtype float64
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from types import SimpleNamespace
from typing import Any

import numpy as np

from fpg_gym.graph import load_graph
from fpg_gym.io import load_default_clips
from fpg_gym.reconstruct import ENERGY_DTYPES, Reconstructor, ReconstructorConfig
from fpg_gym.reconstruct.kernels import compile_kernels
from fpg_gym.reconstruct.streams import run_streams
from fpg_gym.simulate import simulate
from optimizers.local_search import LocalSearch

CLIPS = ("walk", "punch", "kick", "dance_b")
SCENARIOS = ("front-many", "left45-many", "right45-many")


def streams(count: int, frames: int) -> list[SimpleNamespace]:
    clips = load_default_clips(list(CLIPS))
    out = []
    for i in range(count):
        rec = simulate(clips[i % len(clips)], SCENARIOS[i % len(SCENARIOS)], seed=i)
        n = min(frames, rec.num_frames) if frames else rec.num_frames
        out.append(
            SimpleNamespace(
                positions=rec.positions[:n], states=rec.states[:n], timestamps=rec.timestamps[:n]
            )
        )
    return out


def balanced_parts(frames: list[int], processes: int) -> list[list[int]]:
    """Streams split between processes with about equal frames: longest first, each to the
    process with the fewest frames so far (a split by stream number gave one of two processes
    680 frames and the other 960 with the embedded clips' lengths)."""
    parts: list[list[int]] = [[] for _ in range(processes)]
    load = [0] * processes
    for i in sorted(range(len(frames)), key=lambda i: (-frames[i], i)):
        p = load.index(min(load))
        parts[p].append(i)
        load[p] += frames[i]
    return [sorted(part) for part in parts]


def _side_by_side(
    graph_name: str,
    recordings: list[Any],
    seeds: list[int],
    dtype: str = "float64",
    proposals: str = "table",
) -> tuple[float, float, list[np.ndarray]]:
    """Reconstruct side by side; this process's CPU and wall seconds of the reconstruction
    (graph loading and set-up excluded) and the poses."""
    graph = load_graph(graph_name, exclude=list(CLIPS) if graph_name == "default" else [])
    reconstructors = [Reconstructor(graph, energy_dtype=dtype) for _ in recordings]
    compile_kernels()  # numba's disk cache loads once per process, before the clock
    cpu, wall = time.process_time(), time.perf_counter()
    results = run_streams(reconstructors, recordings, LocalSearch(proposals=proposals), seeds)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    return cpu, wall, [r.poses for r in results]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--graph", default="default")
    parser.add_argument("--streams", type=int, default=32)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--alone", type=int, default=4, help="streams also run one by one")
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument(
        "--energy-dtype",
        choices=ENERGY_DTYPES,
        default=ReconstructorConfig().energy_dtype,
        help="energy precision (default %(default)s)",
    )
    parser.add_argument(
        "--proposals",
        choices=("normal", "table"),
        default="table",
        help="local search's N(0, I) proposals (LocalSearch(proposals=...); its default: table)",
    )
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repeats (median)")
    args = parser.parse_args()

    exclude = list(CLIPS) if args.graph == "default" else []
    graph = load_graph(args.graph, exclude=exclude)
    recordings = streams(args.streams, args.frames)
    seeds = list(range(args.streams))
    total = sum(len(r.positions) for r in recordings)
    print(
        f"graph {graph!r}; {args.streams} streams, {total} frames; energy {args.energy_dtype}; "
        f"proposals {args.proposals}"
    )
    rows = []

    alone = recordings[: args.alone]
    frames_alone = sum(len(r.positions) for r in alone)
    reconstructor = Reconstructor(graph, energy_dtype=args.energy_dtype)
    compile_kernels()
    parts = balanced_parts([len(r.positions) for r in recordings], args.processes)
    context = multiprocessing.get_context("spawn")
    measured: dict[str, list[tuple[float, float]]] = {"alone": [], "one": [], "many": []}
    worst = 0.0
    with ProcessPoolExecutor(args.processes, mp_context=context) as pool:
        for _ in range(args.repeat):  # interleaved, so that a busy moment hits every run
            c0, w0 = time.process_time(), time.perf_counter()
            poses_alone = [
                reconstructor.reconstruct(r, LocalSearch(proposals=args.proposals), rng=s).poses
                for r, s in zip(alone, seeds, strict=False)
            ]
            measured["alone"].append((time.process_time() - c0, time.perf_counter() - w0))
            cpu, wall, poses = _side_by_side(
                args.graph, recordings, seeds, args.energy_dtype, args.proposals
            )
            measured["one"].append((cpu, wall))
            worst = max(
                [
                    worst,
                    *(float(np.abs(a - b).max()) for a, b in zip(poses_alone, poses, strict=False)),
                ]
            )
            futures = [
                pool.submit(
                    _side_by_side,
                    args.graph,
                    [recordings[i] for i in p],
                    [seeds[i] for i in p],
                    args.energy_dtype,
                    args.proposals,
                )
                for p in parts
            ]
            done = [f.result() for f in futures]
            # CPU: both processes; wall: the slower process (set-up excluded, as above).
            measured["many"].append((sum(d[0] for d in done), max(d[1] for d in done)))

    def median(name: str) -> tuple[float, float]:
        values = np.array(measured[name])
        return float(np.median(values[:, 0])), float(np.median(values[:, 1]))

    rows.append(("one by one", len(alone), frames_alone, *median("alone")))
    rows.append(("side by side, 1 process", args.streams, total, *median("one")))
    rows.append((f"side by side, {args.processes} processes", args.streams, total, *median("many")))
    print(f"medians of {args.repeat} interleaved repeats")
    print("| run | streams | frames | CPU s | frames / CPU-s | wall s | frames / s |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, count, frames, cpu, wall in rows:
        print(
            f"| {name} | {count} | {frames} | {cpu:.2f} | {frames / cpu:.0f} | {wall:.2f} "
            f"| {frames / wall:.0f} |"
        )
    base = rows[0][2] / rows[0][3]
    for name, _, frames, cpu, _ in rows[1:]:
        print(f"{name}: {frames / cpu / base:.2f}x the frames per CPU-second of one by one")
    print(f"largest difference side by side vs alone (first {len(alone)} streams): {worst:.3g} m")


if __name__ == "__main__":
    main()
