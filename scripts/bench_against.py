"""This checkout against another one (a baseline commit), side by side, in CPU time.

The machine this project is measured on is shared, so its wall-clock times move by tens of
per cent within minutes. This script measures CPU time (``time.process_time``; per stage
``time.thread_time``) and alternates the two checkouts round by round in one run, so that both
see the same load; it reports the median of the rounds and the ratios. Each round runs this file
with ``--measure`` in a fresh process whose ``PYTHONPATH`` is the checkout's root (so the
checkout's own ``fpg_gym`` is imported; both need the same installed packages, e.g. one virtual
environment and a ``git worktree`` of the baseline), with BLAS on one thread. The measurements
use only APIs both checkouts have:

``frame``
    The bench's stage episodes (``fpg-gym bench``: the embedded held-out clips, 3 episodes of up
    to 90 frames, the embedded graph), local search, no ragdoll: CPU ms per frame (mean of the
    ``--repeats``), CPU ms per stage, FPG Eq. 13 error.
``ragdoll``
    The same episodes with the ragdoll (``Reconstructor(ragdoll=Ragdoll)``): CPU ms of each stage,
    the ragdoll's included, and the error; and the ragdoll alone on the no-ragdoll run's outputs
    (floor shifted, one body per episode built from its mean bone lengths): CPU ms per frame
    with the builds, and the error of its output against the ground truth.
``env``
    :func:`fpg_gym.episodes.measure_env_throughput` (random actions, resets included) with and
    without the ragdoll: steps per CPU second.
``real``
    The demo's four real UI-PRMD s08 recordings (Kinect v2) with the pipeline the command line
    picks for them (``--preset auto``: the sensor map and the fusion), local search, no ragdoll:
    CPU ms per frame and per stage (not run unless named: older checkouts lack the preset).
``streams``
    16 simulated recordings reconstructed side by side in one process
    (:func:`fpg_gym.reconstruct.streams.run_streams`, ``batched`` in older checkouts; local
    search, no ragdoll): frames per CPU second.

Usage::

    git worktree add /tmp/base e4823aa
    python scripts/bench_against.py /tmp/base --rounds 3 --json /tmp/against.json
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import subprocess
import sys
import time
import types
import warnings
from pathlib import Path
from typing import Any

import numpy as np

SECTIONS = ("frame", "ragdoll", "env", "streams", "real")
DEFAULT_SECTIONS = ("frame", "ragdoll", "env", "streams")


# --------------------------------------------------------------------------- the measurements


def _stage_cpu_clock() -> None:
    """The reconstructor's stage clock becomes this thread's CPU time (its stage times are then
    CPU milliseconds)."""
    import fpg_gym.reconstruct.reconstructor as module

    module.time = types.SimpleNamespace(  # type: ignore[attr-defined]
        perf_counter=time.thread_time,
        monotonic=time.monotonic,
        time=time.time,
        process_time=time.process_time,
    )


def _reconstruct(
    graph: Any, recordings: list[Any], ragdoll: bool, repeats: int, **options: Any
) -> dict[str, Any]:
    from fpg_gym.core import metrics
    from fpg_gym.physics.ragdoll import Ragdoll
    from fpg_gym.reconstruct import STAGES, Reconstructor

    frames = sum(r.num_frames for r in recordings)
    with Reconstructor(graph, ragdoll=Ragdoll if ragdoll else None, **options) as reconstructor:
        reconstructor.warm_up()
        for i, recording in enumerate(recordings):  # first pass: loads, caches, not timed
            reconstructor.reconstruct(recording, "local-search", rng=i)
        cpu, stages, outputs = [], [], []
        for _ in range(repeats):
            start = time.process_time()
            results = [
                reconstructor.reconstruct(recording, "local-search", rng=i)
                for i, recording in enumerate(recordings)
            ]
            cpu.append(time.process_time() - start)
            outputs = [r.poses for r in results]
            for result in results:
                arrays = result.arrays()
                names = [str(n) for n in arrays["stage_names"]]
                stages.append(arrays["ms_stages"][:, [names.index(s) for s in STAGES]])
    per_stage = np.concatenate(stages).mean(axis=0)
    errors = np.concatenate(
        [metrics.frame_error(r.ground_truth, p) for r, p in zip(recordings, outputs, strict=True)]
    )
    return {
        "cpu_ms_per_frame": 1e3 * float(np.median(cpu)) / frames,
        "stage_cpu_ms": dict(zip(STAGES, map(float, per_stage), strict=True)),
        "error_m": float(errors.mean()),
        "outputs": outputs,
    }


def _ragdoll_alone(targets: list[np.ndarray], recordings: list[Any]) -> dict[str, Any]:
    from fpg_gym.core import metrics, poses
    from fpg_gym.physics.ragdoll import FloorShift, PhysicsWarning, Ragdoll

    cpu = 0.0
    errors, frames = [], 0
    body = Ragdoll()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PhysicsWarning)
            for stream, recording in zip(targets, recordings, strict=True):
                floor = FloorShift()
                world = np.array([floor.down(pose) for pose in stream])
                lengths = poses.bone_lengths(world).mean(axis=0)
                start = time.process_time()
                body.rebuild(lengths)
                out = [body.reset(world[0])]
                out += [body.track(pose) for pose in world[1:]]
                cpu += time.process_time() - start
                frames += len(world)
                errors.append(metrics.frame_error(recording.ground_truth, np.array(out)))
    finally:
        body.close()
    return {
        "cpu_ms_per_frame": 1e3 * cpu / frames,
        "error_m": float(np.concatenate(errors).mean()),
    }


def _real(repeats: int) -> dict[str, Any]:
    """The ``real`` section (module docstring)."""
    from fpg_gym.commands.reconstruct import resolve_graph
    from fpg_gym.experiments.demo import demo_recordings
    from fpg_gym.io.recording import load_recording
    from fpg_gym.reconstruct.presets import choose_pipeline, sensor_of

    recordings = [load_recording(path) for path in demo_recordings()]
    graph = resolve_graph("default", recordings[0], None)
    chosen = choose_pipeline("auto", sensor_of(recordings[0]), graph)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        real = _reconstruct(graph, recordings, False, repeats, **dict(chosen.options))
    real.pop("outputs")
    return real


def measure(sections: tuple[str, ...], repeats: int, env_steps: int) -> dict[str, Any]:
    """What ``--measure`` prints: every section's figures, from the ``fpg_gym`` imported."""
    from threadpoolctl import threadpool_limits

    import fpg_gym
    from fpg_gym.episodes import measure_env_throughput
    from fpg_gym.experiments.bench import BenchSettings, _build, _episodes, _load_data
    from fpg_gym.reconstruct import Reconstructor

    try:
        from fpg_gym.reconstruct.streams import run_streams
    except ImportError:  # a checkout before the one run path (issue 37)
        from fpg_gym.reconstruct.batched import run_streams  # type: ignore[no-redef]
    from fpg_gym.reconstruct.kernels import compile_kernels

    threadpool_limits(limits=1, user_api="blas")
    _stage_cpu_clock()
    compile_kernels()
    report: dict[str, Any] = {"fpg_gym": str(Path(fpg_gym.__file__).parent.parent)}
    settings = BenchSettings.make()
    data = _load_data(settings, False)
    recordings = _episodes(data, settings)
    graph, _ = _build(data.graph_clips, settings.graph_thres1, True)
    if "frame" in sections or "ragdoll" in sections:
        frame = _reconstruct(graph, recordings, False, repeats)
        outputs = frame.pop("outputs")
        report["frame"] = frame
    if "ragdoll" in sections:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pipeline = _reconstruct(graph, recordings, True, repeats)
        pipeline.pop("outputs")
        report["ragdoll"] = {"pipeline": pipeline, "alone": _ragdoll_alone(outputs, recordings)}
    if "env" in sections:
        report["env"] = {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for ragdoll in (True, False):
                measure_env_throughput(steps=20, ragdoll=ragdoll, seed=0)  # loads, not timed
                values = measure_env_throughput(steps=env_steps, ragdoll=ragdoll, seed=0)
                report["env"]["on" if ragdoll else "off"] = {
                    "steps_per_cpu_second": values["steps_per_cpu_second"],
                    "steps_per_second": values["steps_per_second"],
                    "resets": values["resets"],
                }
    if "streams" in sections:
        streams = _episodes(data, settings, 16)
        frames = sum(r.num_frames for r in streams)
        reconstructors = [Reconstructor(graph, ragdoll=False) for _ in streams]
        run_streams(reconstructors, streams, "local-search", list(range(len(streams))))
        cpu = []
        for _ in range(repeats):
            start = time.process_time()
            run_streams(reconstructors, streams, "local-search", list(range(len(streams))))
            cpu.append(time.process_time() - start)
        for r in reconstructors:
            r.close()
        report["streams"] = {"frames": frames, "frames_per_cpu_second": frames / np.median(cpu)}
    if "real" in sections:
        report["real"] = _real(repeats)
    return report


# --------------------------------------------------------------------------- the comparison


def _figures(report: dict[str, Any]) -> dict[str, float]:
    """The flat figures of one measurement, named ``section: what``."""
    out: dict[str, float] = {}
    if "frame" in report:
        out["frame without ragdoll: CPU ms / frame"] = report["frame"]["cpu_ms_per_frame"]
        for stage, ms in report["frame"]["stage_cpu_ms"].items():
            out[f"frame without ragdoll: {stage} CPU ms"] = ms
        out["frame without ragdoll: Eq. 13 error (m)"] = report["frame"]["error_m"]
    if "ragdoll" in report:
        pipeline, alone = report["ragdoll"]["pipeline"], report["ragdoll"]["alone"]
        out["frame with ragdoll: CPU ms / frame"] = pipeline["cpu_ms_per_frame"]
        out["frame with ragdoll: ragdoll stage CPU ms"] = pipeline["stage_cpu_ms"]["ragdoll"]
        out["frame with ragdoll: Eq. 13 error (m)"] = pipeline["error_m"]
        out["ragdoll alone: CPU ms / frame (builds included)"] = alone["cpu_ms_per_frame"]
        out["ragdoll alone: Eq. 13 error (m)"] = alone["error_m"]
    if "env" in report:
        for mode, values in report["env"].items():
            out[f"env, ragdoll {mode}: steps / CPU s"] = values["steps_per_cpu_second"]
    if "streams" in report:
        out["many streams, one process: frames / CPU s"] = report["streams"][
            "frames_per_cpu_second"
        ]
    if "real" in report:
        out["real s08, auto preset: CPU ms / frame"] = report["real"]["cpu_ms_per_frame"]
        for stage, ms in report["real"]["stage_cpu_ms"].items():
            out[f"real s08, auto preset: {stage} CPU ms"] = ms
        out["real s08, auto preset: Eq. 13 error (m)"] = report["real"]["error_m"]
    return out


def _run_child(tree: Path, args: argparse.Namespace) -> dict[str, Any]:
    command = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--measure",
        "--sections",
        ",".join(args.sections),
        "--repeats",
        str(args.repeats),
        "--env-steps",
        str(args.env_steps),
    ]
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"measuring {tree} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("baseline", nargs="?", type=Path, help="the other checkout's root")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (3)")
    parser.add_argument("--repeats", type=int, default=3, help="timed passes per measure (3)")
    parser.add_argument("--env-steps", type=int, default=300, help="env steps timed (300)")
    parser.add_argument(
        "--sections",
        default=",".join(DEFAULT_SECTIONS),
        help=f"some of {','.join(SECTIONS)} ({','.join(DEFAULT_SECTIONS)})",
    )
    parser.add_argument("--json", type=Path, help="write every round's figures here")
    parser.add_argument("--measure", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    args.sections = tuple(s for s in args.sections.split(",") if s)
    unknown = sorted(set(args.sections) - set(SECTIONS))
    if unknown:
        parser.error(f"--sections: unknown {', '.join(unknown)}; expected some of {SECTIONS}")
    if args.measure:
        print(json.dumps(measure(args.sections, args.repeats, args.env_steps)))
        return 0
    if args.baseline is None or not (args.baseline / "fpg_gym").is_dir():
        parser.error(f"baseline: expected a checkout's root folder, got {args.baseline}")
    this = Path(__file__).resolve().parents[1]
    trees = {"baseline": args.baseline.resolve(), "this": this}
    rounds: dict[str, list[dict[str, float]]] = {"baseline": [], "this": []}
    for number in range(args.rounds):
        for name, tree in trees.items():
            started = time.perf_counter()
            rounds[name].append(_figures(_run_child(tree, args)))
            print(f"round {number + 1}, {name}: {time.perf_counter() - started:.0f} s", flush=True)
    names = list(rounds["this"][0])
    print(f"\nbaseline {trees['baseline']}, this {trees['this']}; medians of {args.rounds} rounds")
    print("\n| figure | baseline | this | this / baseline |\n| --- | --- | --- | --- |")
    medians = {}
    for figure in names:
        base = float(np.median([r[figure] for r in rounds["baseline"]]))
        new = float(np.median([r[figure] for r in rounds["this"]]))
        medians[figure] = (base, new)
        ratio = f"{new / base:.2f}" if base else "–"  # e.g. a stage that took no time
        print(f"| {figure} | {base:.4g} | {new:.4g} | {ratio} |")
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "trees": {k: str(v) for k, v in trees.items()},
                    "rounds": rounds,
                    "medians": medians,
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
