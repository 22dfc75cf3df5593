"""``fpg-gym bench``: where the time goes.

Sections (each a list of rows, see :func:`run_bench`):

``stages``
    Milliseconds per frame of each stage of :class:`~fpg_gym.reconstruct.Reconstructor`
    (normalise, reliability, selection, latent = PCA, search, finish, ragdoll), median and
    95th percentile, for graph and brute-force selection with the papers' local search and the
    ragdoll, on simulated episodes of held-out clips; and the CPU time per frame of each, and
    of the graph selection without the ragdoll (after a warm-up: no compilation counted).
``kernels``
    The search's kernels side by side in CPU time (:mod:`fpg_gym.experiments.bench_kernels`):
    the energy of 100 points (fused compiled / fused numpy / the definitions), a frame without
    ragdoll with each, local search alone (the compiled search against the ask/tell loop, results
    compared) and the arithmetic floor of a frame's 2,000 evaluations.
``selection``
    Median CPU time of selection per frame against graph size (graphs built with several
    ``thres1``): the graph walk (FPG §8: scores a neighbourhood), the ``auto`` selector, the
    exact brute force (compiled with numba, else one GEMV on augmented vectors) and the direct
    Eq. 9 score of every node.
``streams``
    Many streams (:func:`fpg_gym.reconstruct.streams.run_streams`): the same simulated
    recordings reconstructed one by one and side by side in this process (local search, no
    ragdoll), frames per CPU-second of each, interleaved, and the largest difference between
    the two outputs.
``build``
    Graph build time (FPG Alg. 1–4) against the number of input poses.
``env``
    Environment steps per second and per CPU second (``fpg_gym/KinectPose-v0`` with random
    actions, resets included), with and without the ragdoll, measured by
    :func:`fpg_gym.episodes.measure_env_throughput`.
``read``
    Mocap read speed (frames per second).

By default everything uses the embedded DeepMimic clips (no files needed); ``mocap=`` paths
(e.g. ``../shared/data/bandai_namco/dataset-1``) use those takes instead: 20 % of the files are
held out for the episodes with the split of ``scripts/holdout_split.py``
(:func:`fpg_gym.core.holdout.holdout_indices`, seed 2016), the others build the graphs.

BLAS runs on one thread (``threadpoolctl``; the per-frame matrices are tiny and more threads only
add contention). Stage timings are wall-clock medians with the CPU time per frame beside them;
the ``kernels`` and ``selection`` figures are CPU time (``time.process_time``), alternatives
interleaved in one run, so that their ratios hold on a busy machine.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from fpg_gym.core import metrics
from fpg_gym.core.defaults import DEFAULT_EPISODE_SCENARIOS, DEFAULT_HOLDOUT_CLIPS
from fpg_gym.core.holdout import holdout_indices
from fpg_gym.episodes import measure_env_throughput
from fpg_gym.experiments.bench_kernels import (
    energy_rows,
    floor_row,
    frame_rows,
    search_rows,
    selection_rows,
)
from fpg_gym.graph import DEFAULT_EMBEDDED_THRES1, DEFAULT_THRES1, FilteredPoseGraph
from fpg_gym.io import load_clips, load_default_clips
from fpg_gym.physics.ragdoll import Ragdoll
from fpg_gym.reconstruct import STAGES, Reconstructor
from fpg_gym.reconstruct.kernels import compile_kernels
from fpg_gym.reconstruct.streams import run_streams
from fpg_gym.simulate import plan_episode, simulate_plan, unique_names

__all__ = ["BenchSettings", "run_bench"]


@dataclass
class BenchSettings:
    """What :func:`run_bench` measures (``quick=True`` gives the reduced set used by tests).

    Attributes
    ----------
    quick : bool
    mocap : list of str
        Mocap files/folders to use instead of the embedded clips.
    episodes : int
        Simulated episodes for the stage timing.
    max_frames : int
        Frames per episode.
    thresholds : tuple of float
        ``thres1`` of the graphs for the selection-vs-size rows (metres).
    env_steps : int
        Env steps timed.
    streams : int
        Recordings of the ``streams`` section.
    sections : tuple of str
        Which sections to run.
    blas_threads : int
        BLAS threads while the bench runs (1).
    """

    quick: bool = False
    mocap: list[str] = field(default_factory=list)
    episodes: int = 3
    max_frames: int = 90
    thresholds: tuple[float, ...] = (0.2, 0.1, 0.06, 0.04)
    env_steps: int = 200
    streams: int = 16
    sections: tuple[str, ...] = (
        "stages",
        "kernels",
        "selection",
        "streams",
        "build",
        "env",
        "read",
    )
    blas_threads: int = 1

    @classmethod
    def make(cls, quick: bool = False, mocap: Sequence[str] = ()) -> BenchSettings:
        """Defaults for the embedded data or for ``mocap`` paths, full or quick."""
        settings = cls(quick=quick, mocap=list(mocap))
        if mocap:
            settings.thresholds = (0.4, 0.3, 0.2, 0.15)
            settings.max_frames = 150
        if quick:
            settings.episodes = 1
            settings.max_frames = 20
            settings.thresholds = settings.thresholds[:2]
            settings.env_steps = 20
            settings.streams = 3
        return settings

    @property
    def graph_thres1(self) -> float:
        """``thres1`` of the graph of the stage timing and of the build rows (metres): FPG's
        0.2 for mocap takes, the embedded graph's 0.1 for the embedded clips."""

        return DEFAULT_THRES1 if self.mocap else DEFAULT_EMBEDDED_THRES1


# --------------------------------------------------------------------------- data


@dataclass
class _Data:
    graph_clips: list[Any]
    episode_clips: list[Any]
    source: str
    read_seconds: float
    read_frames: int


def _load_data(settings: BenchSettings, progress: bool) -> _Data:

    start = time.perf_counter()
    if settings.mocap:
        clips = load_clips(settings.mocap, progress=progress)
        seconds = time.perf_counter() - start
        # The split of scripts/holdout_split.py; a single take is both held out and in the graph.
        graph_indices, held_indices = holdout_indices(len(clips))
        held = [clips[i] for i in held_indices] or clips[-1:]
        graph = [clips[i] for i in graph_indices] or clips
        source = f"{len(clips)} mocap clips from {', '.join(settings.mocap)}"
    else:
        clips = load_default_clips()
        seconds = time.perf_counter() - start
        held = [c for c in clips if c.name in DEFAULT_HOLDOUT_CLIPS]
        graph = [c for c in clips if c.name not in DEFAULT_HOLDOUT_CLIPS]
        source = "embedded DeepMimic clips"
    frames = sum(c.num_frames for c in clips)
    return _Data(graph, held, source, seconds, frames)


def _episodes(data: _Data, settings: BenchSettings, count: int | None = None) -> list[Any]:

    # Episode i: clip i and scenario i (cycling), user seed i, through the episode planner.
    names, scenarios = unique_names(c.name for c in data.episode_clips), DEFAULT_EPISODE_SCENARIOS
    plan = [
        plan_episode(names[i % len(names)], scenarios[i % len(scenarios)], i)
        for i in range(settings.episodes if count is None else count)
    ]
    by_name = dict(zip(names, data.episode_clips, strict=True))
    return simulate_plan(plan, by_name, max_frames=settings.max_frames)


def _build(clips: list[Any], thres1: float, mirror: bool) -> tuple[Any, float]:

    start = time.perf_counter()
    graph = FilteredPoseGraph.build(clips, thres1=thres1, mirror=mirror, progress=False)
    return graph, time.perf_counter() - start


# --------------------------------------------------------------------------- sections


def _quality(outputs: list[np.ndarray], recordings: list[Any]) -> dict[str, float | None]:
    """Error, Err0.2, jitter, lag and bone spread after 1 s of outputs on their recordings."""

    errors, jitters, lags, spreads = [], [], [], []
    for poses, recording in zip(outputs, recordings, strict=True):
        stamps = np.asarray(recording.timestamps, dtype=np.float64)
        jitters.append(float(np.nanmean(metrics.jitter(poses, timestamps=stamps))))
        spread = metrics.settled_bone_spread(poses, timestamps=stamps)
        if np.isfinite(spread).any():
            spreads.append(float(np.nanmax(spread)))
        if recording.ground_truth is not None:
            errors.append(metrics.frame_error(recording.ground_truth, poses))
            lags.append(metrics.lag(poses, recording.ground_truth))
    pooled = np.concatenate(errors) if errors else np.zeros(0)
    return {
        "mean_error_m": float(pooled.mean()) if pooled.size else None,
        "err02_pct": 100.0 * metrics.err_ratio(pooled) if pooled.size else None,
        "jitter_ms2": float(np.nanmean(jitters)) if jitters else None,
        "lag_frames": float(np.nanmean(lags)) if np.isfinite(lags).any() else None,
        "settled_bone_spread_mm": 1000.0 * max(spreads) if spreads else None,
    }


def _stages(
    graph: Any, recordings: list[Any]
) -> tuple[list[dict[str, Any]], dict[str, dict[str, float | None]]]:

    rows = []
    per: dict[str, dict[str, np.ndarray]] = {}
    quality: dict[str, dict[str, float | None]] = {}
    cpu_ms: dict[str, float] = {}
    frames = max(1, sum(r.num_frames for r in recordings))
    for selector in ("graph", "brute-force"):
        ms: list[np.ndarray] = []
        totals: list[np.ndarray] = []
        outputs: list[np.ndarray] = []
        cpu = 0.0
        with Reconstructor(graph, selector=selector, ragdoll=Ragdoll) as reconstructor:
            reconstructor.warm_up()  # kernels loaded, ragdoll client open: not timed
            for i, recording in enumerate(recordings):
                start = time.process_time()
                result = reconstructor.reconstruct(recording, "local-search", rng=i)
                cpu += time.process_time() - start
                arrays = result.arrays()
                names = [str(n) for n in arrays["stage_names"]]
                ms.append(arrays["ms_stages"][:, [names.index(s) for s in STAGES]])
                totals.append(arrays["ms_per_frame"])
                outputs.append(result.poses)
        quality[selector] = _quality(outputs, recordings)
        stages = np.concatenate(ms)
        per[selector] = {s: stages[:, i] for i, s in enumerate(STAGES)}
        per[selector]["total"] = np.concatenate(totals)
        cpu_ms[selector] = 1e3 * cpu / frames
    # The same graph runs without the ragdoll: the frame without it, and the ragdoll's share.
    with Reconstructor(graph, selector="graph", ragdoll=False) as reconstructor:
        reconstructor.warm_up()
        start = time.process_time()
        for i, recording in enumerate(recordings):
            reconstructor.reconstruct(recording, "local-search", rng=i)
        cpu_ms["graph-no-ragdoll"] = 1e3 * (time.process_time() - start) / frames
    for stage in (*STAGES, "total"):
        row: dict[str, Any] = {"stage": stage}
        for selector, values in per.items():
            row[f"{selector}_median_ms"] = float(np.median(values[stage]))
            row[f"{selector}_p95_ms"] = float(np.percentile(values[stage], 95))
        rows.append(row)
    rows.append({"stage": "total CPU (mean)", **{f"{s}_cpu_ms": ms for s, ms in cpu_ms.items()}})
    return rows, quality


def _selection(
    data: _Data, recordings: list[Any], settings: BenchSettings, mirror: bool
) -> list[dict[str, Any]]:

    rows = []
    for thres1 in settings.thresholds:
        graph, seconds = _build(data.graph_clips, thres1, mirror)
        row: dict[str, Any] = {
            "thres1": thres1,
            "nodes": graph.num_nodes,
            "mean_degree": 2 * graph.num_edges / max(1, graph.num_nodes),
            "build_s": seconds,
        }
        row.update(selection_rows(graph, recordings, quick=settings.quick))
        row["brute-force_scored"] = graph.num_nodes
        rows.append(row)
    return rows


def _kernels(graph: Any, recordings: list[Any], settings: BenchSettings) -> dict[str, Any]:
    return {
        "energy": energy_rows(graph, recordings[0], quick=settings.quick),
        "frame": frame_rows(graph, recordings, quick=settings.quick),
        "search": (
            search_rows(graph, recordings[:1], frames=10, repeats=1)
            if settings.quick
            else search_rows(graph, recordings)
        ),
        "floor": floor_row(),
    }


def _streams(graph: Any, recordings: list[Any], repeats: int) -> list[dict[str, Any]]:
    """Frames per CPU-second one by one and side by side (interleaved ``repeats`` rounds,
    medians), the ratio, and the largest output difference (0 with the compiled kernel)."""
    frames = sum(r.num_frames for r in recordings)
    seeds = list(range(len(recordings)))
    cpu: dict[str, list[float]] = {"one by one": [], "side by side": []}
    difference = 0.0
    alone = Reconstructor(graph, ragdoll=False)
    together = [Reconstructor(graph, ragdoll=False) for _ in recordings]
    try:
        for _ in range(repeats):
            start = time.process_time()
            single = [
                alone.reconstruct(r, "local-search", rng=s)
                for r, s in zip(recordings, seeds, strict=True)
            ]
            cpu["one by one"].append(time.process_time() - start)
            start = time.process_time()
            batched = run_streams(together, recordings, "local-search", seeds)
            cpu["side by side"].append(time.process_time() - start)
            difference = max(
                [
                    difference,
                    *(
                        float(np.abs(a.poses - b.poses).max())
                        for a, b in zip(single, batched, strict=True)
                    ),
                ]
            )
    finally:
        for r in (alone, *together):
            r.close()
    base = frames / float(np.median(cpu["one by one"]))
    return [
        {
            "run": name,
            "streams": len(recordings),
            "frames": frames,
            "cpu_s": float(np.median(values)),
            "frames_per_cpu_s": frames / float(np.median(values)),
            "ratio": frames / float(np.median(values)) / base,
            "max_difference_m": difference,
        }
        for name, values in cpu.items()
    ]


def _build_rows(data: _Data, settings: BenchSettings) -> list[dict[str, Any]]:
    clips = data.graph_clips
    thres1 = settings.graph_thres1
    fractions = (0.5, 1.0) if settings.quick else (0.25, 0.5, 1.0)
    rows = []
    for mirror in (False, True):
        for fraction in fractions:
            count = max(1, round(fraction * len(clips)))
            subset = clips[:count]
            graph, seconds = _build(subset, thres1, mirror)
            poses = sum(c.num_frames for c in subset) * (2 if mirror else 1)
            rows.append(
                {
                    "clips": count,
                    "mirror": mirror,
                    "poses": poses,
                    "nodes": graph.num_nodes,
                    "edges": graph.num_edges,
                    "thres1": thres1,
                    "seconds": seconds,
                    "poses_per_second": poses / max(seconds, 1e-9),
                }
            )
    return rows


def _env_rows(settings: BenchSettings) -> list[dict[str, Any]]:
    """Env steps per second, with and without the ragdoll (random actions)."""

    rows = []
    for ragdoll in (True, False):
        measure_env_throughput(steps=5, ragdoll=ragdoll, seed=0)  # loads the kernels: not timed
        values = measure_env_throughput(steps=settings.env_steps, ragdoll=ragdoll, seed=0)
        source = "fpg_gym.episodes.measure_env_throughput, random actions, ragdoll "
        rows.append({"source": source + ("on" if ragdoll else "off"), **values})
    return rows


def _read_rows(data: _Data, settings: BenchSettings) -> list[dict[str, Any]]:
    rows = [
        {
            "source": data.source,
            "frames": data.read_frames,
            "seconds": data.read_seconds,
            "frames_per_second": data.read_frames / max(data.read_seconds, 1e-9),
        }
    ]
    if not settings.mocap:  # a second read: the first includes imports and file caching
        start = time.perf_counter()
        frames = sum(c.num_frames for c in load_default_clips())
        seconds = time.perf_counter() - start
        rows.append(
            {
                "source": "embedded DeepMimic clips (again, warm)",
                "frames": frames,
                "seconds": seconds,
                "frames_per_second": frames / max(seconds, 1e-9),
            }
        )
    return rows


def run_bench(settings: BenchSettings | None = None, *, progress: bool = True) -> dict[str, Any]:
    """Run the bench; returns ``{"date", "settings", "machine", SECTION: rows, "seconds"}``.

    Ctrl-C stops it; the sections finished so far are returned (``"interrupted": True``).
    """

    settings = settings or BenchSettings.make()
    started = time.perf_counter()
    report: dict[str, Any] = {
        "date": datetime.now(timezone.utc).date().isoformat(),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPU(s), Python "
        f"{platform.python_version()}, numpy {np.__version__}",
        "settings": {
            "quick": settings.quick,
            "mocap": settings.mocap,
            "episodes": settings.episodes,
            "max_frames": settings.max_frames,
            "thresholds": list(settings.thresholds),
            "env_steps": settings.env_steps,
            "streams": settings.streams,
        },
        "interrupted": False,
    }
    bar = tqdm(total=len(settings.sections) + 1, desc="bench", unit="part", disable=not progress)
    limits = threadpool_limits(limits=settings.blas_threads, user_api="blas")
    report["blas_threads"] = settings.blas_threads
    report["energy_kernels"] = list(compile_kernels())  # compiled before any timing
    try:
        bar.set_postfix_str("reading")
        data = _load_data(settings, progress)
        mirror = not settings.mocap
        recordings = _episodes(data, settings)
        bar.update()
        report["data"] = data.source
        graph = None
        for section in settings.sections:
            bar.set_postfix_str(section)
            if section in ("stages", "kernels", "streams") and graph is None:
                graph, _ = _build(data.graph_clips, settings.graph_thres1, mirror)
                report["stages_graph"] = repr(graph)
            if section == "stages":
                report["stages"], report["stages_quality"] = _stages(graph, recordings)
            elif section == "kernels":
                report["kernels"] = _kernels(graph, recordings, settings)
            elif section == "selection":
                report["selection"] = _selection(data, recordings, settings, mirror)
            elif section == "streams":
                streams = _episodes(data, settings, settings.streams)
                report["streams"] = _streams(graph, streams, 1 if settings.quick else 3)
            elif section == "build":
                report["build"] = _build_rows(data, settings)
            elif section == "env":
                report["env"] = _env_rows(settings)
            elif section == "read":
                report["read"] = _read_rows(data, settings)
            else:
                raise ValueError(f"sections: unknown section {section!r}")
            bar.update()
    except KeyboardInterrupt:
        report["interrupted"] = True
    finally:
        limits.restore_original_limits()
        bar.close()
    report["seconds"] = time.perf_counter() - started
    return report


# --------------------------------------------------------------------------- printing
