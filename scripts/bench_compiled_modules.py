"""What each compiled module costs a fresh install, against the CPU time it saves a frame.

* **compile**: ``fpg-gym warm-up``'s work in one new process (``warm_kernels(1)``) with an empty
  ``NUMBA_CACHE_DIR``; numba's compile events give each function's CPU seconds (exclusive of its
  callees, which count in their own rows) and the part spent under LLVM's lock (optimisation and
  machine code), summed by module.
* **savings**: CPU ms per frame of the bench's episodes without and with the ragdoll, of the demo's
  four real UI-PRMD s08 recordings with the auto preset (``real``), and per env step with the
  ragdoll, with every module compiled and with one module on its numpy path
  (:func:`fpg_gym.core.compiled.only_compiled`), the settings interleaved round by round in one
  process (BLAS on one thread), medians of the rounds.

Usage::

    python scripts/bench_compiled_modules.py --rounds 5 --json /tmp/modules.json
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

_COMPILE = """
import json, sys, time
from numba.core import event

log = []


class Listener(event.Listener):
    def __init__(self, kind):
        self.kind = kind

    def on_start(self, e):
        f = getattr((e.data or {}).get("dispatcher"), "py_func", None)
        name = f"{getattr(f, '__module__', '?')}.{getattr(f, '__qualname__', '?')}"
        log.append([self.kind, 1, time.process_time(), name])

    def on_end(self, e):
        log.append([self.kind, 0, time.process_time(), None])


event.register("numba:compile", Listener("compile"))
event.register("numba:llvm_lock", Listener("llvm"))
from fpg_gym.experiments.warm import warm_kernels

warm_kernels(1)
json.dump(log, sys.stdout)
"""


def compile_seconds() -> dict[str, dict[str, float]]:
    """``{function: {"cpu": s, "llvm": s}}`` of ``warm_kernels(1)`` on an empty cache."""
    with tempfile.TemporaryDirectory() as cache:
        out = subprocess.run(
            [sys.executable, "-c", _COMPILE],
            env=dict(os.environ, NUMBA_CACHE_DIR=cache),
            check=True,
            stdout=subprocess.PIPE,
            text=True,
        ).stdout
    seconds: dict[str, dict[str, float]] = {}
    stack: list[list[Any]] = []  # [name, start, seconds in callees]
    llvm_start = 0.0
    for kind, starts, clock, name in json.loads(out):
        if kind == "llvm":
            if starts:
                llvm_start = clock
            elif stack:
                row = seconds.setdefault(stack[-1][0], {"cpu": 0.0, "llvm": 0.0})
                row["llvm"] += clock - llvm_start
        elif starts:
            stack.append([name, clock, 0.0])
        else:
            name, start, inner = stack.pop()
            row = seconds.setdefault(name, {"cpu": 0.0, "llvm": 0.0})
            row["cpu"] += clock - start - inner
            if stack:
                stack[-1][2] += clock - start
    return seconds


def workloads() -> dict[str, Callable[[Sequence[str]], float]]:
    """CPU ms per frame (or env step) of each workload with only ``modules`` compiled."""
    from fpg_gym.commands.reconstruct import resolve_graph
    from fpg_gym.core.compiled import only_compiled
    from fpg_gym.episodes import measure_env_throughput
    from fpg_gym.experiments.bench import BenchSettings, _build, _episodes, _load_data
    from fpg_gym.experiments.demo import demo_recordings
    from fpg_gym.io.recording import load_recording
    from fpg_gym.physics.ragdoll import Ragdoll
    from fpg_gym.reconstruct import Reconstructor
    from fpg_gym.reconstruct.presets import choose_pipeline, sensor_of

    settings = BenchSettings.make()
    data = _load_data(settings, False)
    bench = _episodes(data, settings)
    graph, _ = _build(data.graph_clips, settings.graph_thres1, True)
    real = [load_recording(path) for path in demo_recordings()]
    real_graph = resolve_graph("default", real[0], None)
    auto = dict(choose_pipeline("auto", sensor_of(real[0]), real_graph).options)

    def frames(recordings: list[Any], graph: Any, ragdoll: Any, options: dict[str, Any]) -> Any:
        def run(modules: Sequence[str]) -> float:
            with only_compiled(modules), Reconstructor(graph, ragdoll=ragdoll, **options) as r:
                r.warm_up()
                for i, recording in enumerate(recordings):  # loads, caches: not timed
                    r.reconstruct(recording, "local-search", rng=i)
                start = time.process_time()
                for i, recording in enumerate(recordings):
                    r.reconstruct(recording, "local-search", rng=i)
                return 1e3 * (time.process_time() - start) / sum(x.num_frames for x in recordings)

        return run

    def env(modules: Sequence[str]) -> float:
        with only_compiled(modules):
            measure_env_throughput(steps=20, ragdoll=True, seed=0)
            return (
                1e3
                / measure_env_throughput(steps=300, ragdoll=True, seed=0)["steps_per_cpu_second"]
            )

    return {
        "frame": frames(bench, graph, None, {}),
        "frame with ragdoll": frames(bench, graph, Ragdoll, {}),
        "real s08, auto preset": frames(real, real_graph, None, auto),
        "env step with ragdoll": env,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = parser.parse_args(argv)
    from threadpoolctl import threadpool_limits

    from fpg_gym.core.compiled import COMPILED_MODULES

    threadpool_limits(limits=1, user_api="blas")
    warnings.simplefilter("ignore")
    compiled = compile_seconds()
    settings = {"": COMPILED_MODULES}
    settings.update({m: tuple(n for n in COMPILED_MODULES if n != m) for m in COMPILED_MODULES})
    runs = workloads()
    ms: dict[str, dict[str, list[float]]] = {w: {s: [] for s in settings} for w in runs}
    for _ in range(args.rounds):
        for setting, modules in settings.items():
            for workload, run in runs.items():
                ms[workload][setting].append(run(modules))
    print("| module | functions | compile CPU s | LLVM s | " + " | ".join(runs) + " (µs saved) |")
    print("| --- | --- | --- | --- |" + " --- |" * len(runs))
    for module in COMPILED_MODULES:
        rows = [v for k, v in compiled.items() if k.rsplit(".", 1)[0] == module]
        saved = [
            1e3 * (np.median(ms[w][module]) - np.median(ms[w][""])) for w in runs
        ]  # us per frame that compiling the module saves
        print(
            f"| {module} | {len(rows)} | {sum(r['cpu'] for r in rows):.2f} | "
            f"{sum(r['llvm'] for r in rows):.2f} | " + " | ".join(f"{s:+.0f}" for s in saved) + " |"
        )
    others = [v for k, v in compiled.items() if not k.startswith(COMPILED_MODULES)]
    print(
        f"| numba's own (np.empty, np.dot, ...) | {len(others)} | "
        f"{sum(r['cpu'] for r in others):.2f} | {sum(r['llvm'] for r in others):.2f} |"
    )
    print("all compiled, CPU ms: " + ", ".join(f"{w} {np.median(ms[w]['']):.3f}" for w in runs))
    for name, row in sorted(compiled.items(), key=lambda item: -item[1]["cpu"]):
        print(f"  {row['cpu']:6.2f} s  (LLVM {row['llvm']:5.2f})  {name}")
    if args.json is not None:
        args.json.write_text(json.dumps({"compiled": compiled, "ms": ms}, indent=1), "utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
