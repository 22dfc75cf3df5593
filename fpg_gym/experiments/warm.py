"""Compile the numba kernels before the first frame, sharing the work between processes.

With ``fpg-gym[fast]`` the kernels compile on first use and are cached on disk (numba's
``cache=True``, in ``__pycache__`` beside their modules): a fresh installation compiles about
thirty CPU seconds of kernels, once. :func:`warm_kernels` does it ahead of time by running the
demo's methods on a short simulated stream and the real sections' on a packaged Kinect v2
recording (the auto preset: maps and fusion), alone and side by side with another, so that every
kernel compiles with the argument types the real runs use; with ``workers > 1`` this process and
``workers - 1`` new ones run them with only their share of the compiled modules switched on
(:func:`fpg_gym.core.compiled.only_compiled`), so the modules compile in parallel and none
twice. ``fpg-gym warm-up`` runs it. :func:`compile_in_background` runs it in a detached process
at the lowest CPU priority: ``fpg-gym demo`` starts one when the cache is cold and meanwhile runs
the kernels' numpy versions, which take less time on the demo's few thousand frames than
compiling them would.
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import time
import warnings
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from fpg_gym.core.compiled import COMPILED_MODULES, kernels_cached, numba_available, only_compiled
from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
from fpg_gym.graph import default_graph, load_graph
from fpg_gym.io import load_default_clips
from fpg_gym.io.recording import Recording, load_recording
from fpg_gym.methods import MethodRunner
from fpg_gym.physics.ragdoll import PhysicsWarning
from fpg_gym.reconstruct.presets import choose_pipeline, default_graph_name, sensor_of
from fpg_gym.simulate import simulate_clips

__all__ = [
    "REAL_WARM_UP_METHODS",
    "WARM_UP_METHODS",
    "compile_in_background",
    "warm_kernels",
    "warm_kernels_cached",
]

#: Methods whose code paths the warm-up runs (every compiled kernel of the demo).
WARM_UP_METHODS: tuple[str, ...] = (
    "holt",
    "kalman",
    "fpg:none",
    "fpg:local-search+ragdoll",
    "shum:local-search",
    "fpg:random-search",
    "fpg:closed-form",
    "fpg:local-search+prior",
)
#: Methods run on a packaged real Kinect v2 recording with the auto preset (the sensor and
#: definition maps, the fusion's trust: the demo's real sections and ``fpg-gym reconstruct``).
REAL_WARM_UP_METHODS: tuple[str, ...] = ("holt+map", "fpg:closed-form", "fpg:local-search")
#: The packaged real recording (one of :func:`fpg_gym.experiments.demo.demo_recordings`).
_REAL_RECORDING = Path(__file__).resolve().parents[1] / "data" / "demo" / "m01_s08_e05.npz"

#: The compiled modules in units that compile together (the compiled local search and the
#: compiled latent space run only with the compiled energy kernel), with the CPU seconds each
#: unit took to compile on the shared 2-core machine (to share the units out between processes):
#: numba's compile events of ``_run_methods(unit, 40)`` in a new process with an empty
#: ``NUMBA_CACHE_DIR``; a callee in another unit's module counts in both. The other process
#: also pays its start and the numpy code of the modules it does not compile (about 3 CPU s).
_UNITS: tuple[tuple[tuple[str, ...], float], ...] = (
    (
        (
            "fpg_gym.reconstruct.compiled_kernels",
            "fpg_gym.reconstruct.compiled_search",
            "fpg_gym.reconstruct.compiled_frame",
        ),
        11.3,
    ),
    (("fpg_gym.reconstruct.compiled_selection",), 3.7),
    (("fpg_gym.reconstruct.compiled_reliability",), 7.0),
    (("fpg_gym.reconstruct.compiled_fusion",), 2.0),
    (("fpg_gym.physics.compiled_ragdoll",), 2.8),
    (("fpg_gym.core.compiled_poses",), 3.0),
    (("fpg_gym.filters.compiled_filters",), 1.0),
)

#: Kernels that the first frame of any reconstruction runs: cached means warm.
_MARKERS: tuple[tuple[str, str], ...] = (
    ("fpg_gym.reconstruct.compiled_search", "local_search"),
    ("fpg_gym.reconstruct.compiled_kernels", "fused_kernel"),
    ("fpg_gym.reconstruct.compiled_selection", "fpg_walk_best"),
    ("fpg_gym.reconstruct.compiled_frame", "whitened_axes"),
    ("fpg_gym.physics.compiled_ragdoll", "bone_frames"),
    ("fpg_gym.filters.compiled_filters", "kalman_step"),
)


def warm_kernels_cached() -> bool:
    """Whether the kernels a reconstruction's first frame runs are in numba's disk cache (True
    without numba: there is nothing to compile)."""
    return not numba_available() or kernels_cached(_MARKERS)


def _shares(workers: int) -> list[tuple[str, ...]]:
    """The compiled modules shared out between ``workers`` processes (the longest units first,
    each to the least loaded process; a module in no unit counts 1 s)."""
    listed = {name for unit, _ in _UNITS for name in unit}
    units = [*_UNITS, *(((name,), 1.0) for name in COMPILED_MODULES if name not in listed)]
    loads = [0.0] * workers
    shares: list[list[str]] = [[] for _ in range(workers)]
    for unit, seconds in sorted(units, key=lambda item: -item[1]):
        least = loads.index(min(loads))
        shares[least].extend(unit)
        loads[least] += seconds
    return [tuple(share) for share in shares if share]


#: Frames of the two streams run side by side (the stacked kernels run from the first frame).
_SIDE_BY_SIDE_FRAMES = 4


def _simulated(frames: int) -> list[Recording]:
    """The first ``frames`` frames of a simulated held-out clip, then two streams of its first
    few (seeds 0 and 1): made once, in the first process, and sent to the others (which then
    load no simulator: its filters' import alone costs more than a CPU second)."""
    clip = load_default_clips([DEFAULT_HOLDOUT_CLIPS[0]])
    (recording,) = simulate_clips(clip, ["front-many"], [0], max_frames=frames)
    pair = simulate_clips(
        clip, ["front-many"], [0, 1], max_frames=min(frames, _SIDE_BY_SIDE_FRAMES)
    )
    return [recording, *pair]


def _run_methods(
    modules: Sequence[str], frames: int, simulated: list[Recording] | None = None
) -> None:
    """Every warm-up method on the first ``frames`` frames of a simulated held-out clip, the real
    ones on those of a packaged Kinect v2 recording with the auto preset, and each on two short
    streams side by side (a compare's batches: the stacked kernels), with only ``modules``
    compiled (``simulated``: :func:`_simulated`'s streams, made here when None)."""
    graph = default_graph(exclude=DEFAULT_HOLDOUT_CLIPS)  # the demo's graph, from the cache
    recording, *pair = _simulated(frames) if simulated is None else simulated
    real = load_recording(_REAL_RECORDING)
    real_graph = load_graph(default_graph_name(sensor_of(real)))
    chosen = choose_pipeline("auto", sensor_of(real), real_graph)
    real_pair = [real.head(min(frames, _SIDE_BY_SIDE_FRAMES))] * 2
    with only_compiled(modules), warnings.catch_warnings():
        warnings.simplefilter("ignore", PhysicsWarning)
        with MethodRunner(graph) as runner:
            for method in WARM_UP_METHODS:
                runner.run(method, recording, 0)
                runner.run_many(method, pair, [0, 1])
        with MethodRunner(real_graph, reconstructor_options=dict(chosen.options)) as runner:
            for method in REAL_WARM_UP_METHODS:
                runner.run(method, real.head(frames), 0)
                runner.run_many(method, real_pair, [0, 1])


def warm_kernels(workers: int = 1, *, frames: int = 40) -> float:
    """Compile (or load from the disk cache) every kernel the demo's methods run.

    Parameters
    ----------
    workers : int
        Processes sharing the compilation (1: in this process).
    frames : int
        Frames of the streams the methods run (more than a second, so that the bones settle
        and the ragdoll is rebuilt as in a real run: kernels that run only then compile too).

    Returns
    -------
    float
        Seconds taken (0 without numba).
    """
    if not numba_available():
        return 0.0
    started = time.perf_counter()
    default_graph(exclude=DEFAULT_HOLDOUT_CLIPS)  # built and cached once, before any worker
    shares = _shares(max(1, int(workers)))
    if len(shares) == 1:
        _run_methods(shares[0], frames)
    else:  # the largest share here (imported already), the others in new processes meanwhile
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(len(shares) - 1, mp_context=context) as pool:
            for _ in shares[1:]:  # the processes start (their imports) while this one simulates
                pool.submit(warm_kernels_cached)
            simulated = _simulated(frames)
            others = [pool.submit(_run_methods, share, frames, simulated) for share in shares[1:]]
            _run_methods(shares[0], frames, simulated)
            for done in others:
                done.result()
    return time.perf_counter() - started


def compile_in_background() -> subprocess.Popen[bytes]:
    """Start :func:`warm_kernels` in one new process at the lowest CPU priority
    (``nice`` 19 where the system has it), in a process group of its own, so that it goes on
    compiling into numba's disk cache after this process ends or is interrupted (Ctrl-C signals
    the terminal's foreground group only); its output is discarded (``fpg-gym warm-up``
    compiles in the foreground and shows it). It stays in this session: Linux's autogroup
    scheduler shares the CPU between sessions before it weighs ``nice``, so a session of its own
    would take a full share from the demo.

    Returns
    -------
    subprocess.Popen
        The process (``pid``; nothing needs to wait for it).
    """
    group: dict[str, Any] = {}
    if os.name == "posix":
        group = {"process_group": 0} if sys.version_info >= (3, 11) else {"preexec_fn": os.setpgrp}
    return subprocess.Popen(
        [sys.executable, "-m", __name__],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        **group,
    )


if __name__ == "__main__":  # compile_in_background's process
    if hasattr(os, "nice"):
        os.nice(19)
    warm_kernels(1)
