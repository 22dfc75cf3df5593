"""The ahead-of-time warm-up of the compiled kernels (fpg_gym.experiments.warm, fpg-gym warm-up)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fpg_gym.core.compiled import COMPILED_MODULES, numba_available
from fpg_gym.experiments.warm import (
    _shares,
    compile_in_background,
    warm_kernels,
    warm_kernels_cached,
)

pytestmark = pytest.mark.skipif(not numba_available(), reason="needs numba (fpg-gym[fast])")


@pytest.mark.parametrize("workers", [1, 2, 3, 20])
def test_every_compiled_module_goes_to_exactly_one_process(workers: int) -> None:
    shares = _shares(workers)
    assert 1 <= len(shares) <= workers
    names = [name for share in shares for name in share]
    assert sorted(names) == sorted(COMPILED_MODULES)
    # The compiled search and latent space run only with the compiled energy kernel.
    together = {
        "fpg_gym.reconstruct.compiled_kernels",
        "fpg_gym.reconstruct.compiled_search",
        "fpg_gym.reconstruct.compiled_frame",
    }
    assert any(together <= set(share) for share in shares)


def test_warm_up_in_this_process_leaves_the_markers_cached() -> None:
    warm_kernels(1, frames=4)
    assert warm_kernels_cached()


@pytest.mark.slow
def test_background_compilation_fills_the_cache_at_the_lowest_priority(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``fpg-gym demo``'s background process on a fresh numba cache: in a process group of its
    own (Ctrl-C in the terminal does not reach it) but this session (where ``nice`` counts), at
    ``nice`` 19, and every marker kernel cached when it ends."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    process = compile_in_background()
    try:
        assert os.getpgid(process.pid) == process.pid
        assert os.getsid(process.pid) == os.getsid(0)
        for _ in range(600):  # it lowers its priority after its imports
            if os.getpriority(os.PRIO_PROCESS, process.pid) == 19:
                break
            time.sleep(0.05)
        assert os.getpriority(os.PRIO_PROCESS, process.pid) == 19
        assert process.wait(timeout=900) == 0
    finally:
        process.kill()
    check = "from fpg_gym.experiments.warm import warm_kernels_cached as c; print(c())"
    done = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True)
    assert done.stdout.strip() == "True", done.stderr


CHECK = """
import importlib
from numba.core.dispatcher import Dispatcher
from fpg_gym.core.compiled import COMPILED_MODULES
from fpg_gym.experiments.warm import _run_methods, warm_kernels_cached
assert warm_kernels_cached()
_run_methods(COMPILED_MODULES, 40)
# The real Kinect v2 path as the demo's real sections and ``fpg-gym reconstruct`` run it (the
# auto preset's maps and fusion), written out here so that the warm-up must cover it.
import warnings
from fpg_gym.experiments.demo import REAL_METHODS, demo_recordings
from fpg_gym.graph import load_graph
from fpg_gym.io.recording import load_recording
from fpg_gym.methods import MethodRunner
from fpg_gym.reconstruct.presets import choose_pipeline, default_graph_name, sensor_of
real = [load_recording(p) for p in demo_recordings()[:2]]
graph = load_graph(default_graph_name(sensor_of(real[0])))
options = {"k": 30, **choose_pipeline("auto", sensor_of(real[0]), graph).options}
warnings.simplefilter("ignore")
with MethodRunner(graph, reconstructor_options=options) as runner:
    for method in (*REAL_METHODS, "fpg:local-search"):
        runner.run(method, real[0], 0)
        runner.run_many(method, real, [0, 1])
missed = [
    f"{m}.{n}"
    for m in COMPILED_MODULES
    for n, d in vars(importlib.import_module(m)).items()
    if isinstance(d, Dispatcher) and d.stats.cache_misses
]
print("compiled after the warm-up:", missed)
assert not missed
several = [
    f"{m}.{n}: {d.signatures}"
    for m in COMPILED_MODULES
    for n, d in vars(importlib.import_module(m)).items()
    if isinstance(d, Dispatcher) and len(d.signatures) > 1
]
print("kernels compiled for several argument types:", several)
assert not several
"""


@pytest.mark.slow
def test_parallel_warm_up_compiles_everything_the_methods_run(tmp_path: Path) -> None:
    """A fresh numba cache: ``fpg-gym warm-up --workers 2`` (each process compiling its share),
    then a new process running every warm-up method, and the real Kinect v2 path of the demo's
    real sections, compiles nothing more, and each kernel it runs for one set of argument types
    only (a second would compile again on a fresh install)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    warm = [sys.executable, "-m", "fpg_gym.cli", "warm-up", "--workers", "2"]
    subprocess.run(warm, env=env, check=True, capture_output=True, text=True)
    done = subprocess.run(
        [sys.executable, "-c", CHECK], env=env, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stdout + done.stderr
