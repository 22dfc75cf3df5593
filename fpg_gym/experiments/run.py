"""Run a comparison of reconstruction methods on many episodes: ``fpg-gym compare``, the demo.

An *episode* is one Kinect stream with ground truth: a mocap clip simulated in one scenario with
one seed (:func:`plan_episodes`), or a recording file. Every (episode, method) pair is a task;
tasks run in parallel worker processes (each loads the pose graph once) and each finished task
appends one row to ``results.csv`` (flushed at once) and writes its per-frame arrays to
``frames/<episode>/<method>.npz``. Ctrl-C keeps every finished row; the report is then written
from them, and a rerun with the same ``--out`` skips the finished rows.

Output folder::

    manifest.txt      every file compare wrote here (``--fresh`` deletes these and nothing else)
    config.json       the run's settings (a rerun must match them to resume)
    results.csv       one row per episode and method (see :data:`CSV_FIELDS`)
    episodes/*.npz    the simulated recordings (``fpg_gym.io.recording.load_recording``)
    frames/E/M.npz    per-frame error, ms, stage ms, evaluations, energy and output poses
    summary.json      per-method aggregates, the paired tests, the settings
    report.md         the tables (FPG §8 style) and the plots
    *.png             error histogram, cumulative curve, error over time, frame times

Safety: compare writes only into a folder it created (or an empty one) and lists every file it
writes in ``manifest.txt`` before writing it (never over a file it did not list); ``fresh=True``
deletes the listed files and nothing else, and is refused on a folder without a manifest. A run
holds the folder's lock (:class:`~fpg_gym.experiments.store.Manifest`) until it ends: a second
run on the same folder is refused. Resuming trusts nothing stale: a torn last row of
``results.csv`` (a kill during a write) is dropped with a warning, a task whose per-frame file is
missing or damaged runs again, the graph is keyed by its content (another graph is refused), a
``learned:MODEL`` method by its model's files (a changed model's rows are recomputed), and
episodes by content (:attr:`EpisodeSpec.key`, a hash of the input file or clip and of the
episode's settings), so a different clip under the same file name is recomputed, two inputs with
the same file name stay two episodes, and the same input given twice is one. The report covers
this run's methods and episodes; rows an earlier run left in the folder are kept and counted
apart.

Hold-out rule: the graph must not contain the evaluated takes. ``--graph default`` builds the
embedded graph without the evaluated embedded clips; for a graph file, build it from other takes
(``scripts/holdout_split.py``); the report warns when an evaluated clip's name is a graph clip.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from fpg_gym.core import metrics
from fpg_gym.core.errors import TaskError
from fpg_gym.core.outputs import write_text
from fpg_gym.experiments.config import CompareConfig, EpisodeSpec
from fpg_gym.experiments.distributed import require_ray, run_on_ray
from fpg_gym.experiments.report import format_table, write_report
from fpg_gym.experiments.resume import resume_folder
from fpg_gym.experiments.store import (
    Manifest,
    ResultsWriter,
    claim_folder,
    frames_path,
    read_rows,
    save_frames,
)
from fpg_gym.graph import load_graph
from fpg_gym.io.recording import load_recording
from fpg_gym.methods import Method, MethodRunner, parse_method
from fpg_gym.reconstruct import ReconstructionResult
from fpg_gym.reconstruct.presets import choose_pipeline, default_graph_name, sensor_of
from fpg_gym.runtime.ray_session import check_address
from optimizers import make


@dataclass(frozen=True)
class _Task:
    episode: EpisodeSpec
    method: str
    recording_path: str


def _nanmean(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else float("nan")


def _jitter(poses: np.ndarray, timestamps: np.ndarray) -> float:
    if len(poses) < 3:
        return float("nan")
    stamps = np.asarray(timestamps, dtype=np.float64)
    if np.all(np.diff(stamps) > 0):
        return _nanmean(metrics.jitter(poses, timestamps=stamps))
    return _nanmean(metrics.jitter(poses))


def _settled_spread_mm(poses: np.ndarray, timestamps: np.ndarray) -> float:
    """Largest bone-length range (mm) after the first second (:func:`metrics.
    settled_bone_spread`); NaN for a stream shorter than that."""
    stamps = np.asarray(timestamps, dtype=np.float64)
    spread = metrics.settled_bone_spread(poses, timestamps=stamps)
    finite = spread[np.isfinite(spread)]
    return float(1000.0 * finite.max()) if finite.size else float("nan")


def _frame_interval(timestamps: np.ndarray) -> float:
    """Median frame interval in seconds (1/30 without usable timestamps)."""
    steps = np.diff(np.asarray(timestamps, dtype=np.float64))
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else 1.0 / 30.0


def _side_by_side(tasks: Sequence[_Task]) -> bool:
    """Whether a batch runs its episodes side by side (a reconstruction method, more than one
    episode) rather than one by one."""
    return len(tasks) > 1 and not parse_method(tasks[0].method).is_filter


def _execute(
    runner: MethodRunner, task: _Task, recording: Any
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Run one method on one episode; return the CSV row and the per-frame arrays."""
    method = parse_method(task.method)
    start = time.perf_counter()
    result = runner.run(method, recording, seed=task.episode.sim_seed)
    return _row(runner, method, task, recording, result, time.perf_counter() - start)


def _execute_batch(
    runner: MethodRunner, tasks: Sequence[_Task], recordings: Sequence[Any]
) -> list[tuple[dict[str, Any], dict[str, np.ndarray]]]:
    """Run one method on many episodes side by side (:meth:`MethodRunner.run_many`); the CSV
    row and per-frame arrays of each. ``seconds`` of a row is its share of the batch."""
    method = parse_method(tasks[0].method)
    start = time.perf_counter()
    results = runner.run_many(method, recordings, [t.episode.sim_seed for t in tasks])
    seconds = (time.perf_counter() - start) / len(tasks)
    return [
        _row(runner, method, task, recording, result, seconds)
        for task, recording, result in zip(tasks, recordings, results, strict=True)
    ]


def _row(
    runner: MethodRunner,
    method: Method,
    task: _Task,
    recording: Any,
    result: ReconstructionResult,
    seconds: float,
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The CSV row and the per-frame arrays of one method's result on one episode."""
    episode = task.episode
    count = result.num_frames
    poses = result.poses
    truth = recording.ground_truth
    row: dict[str, Any] = {
        "episode": episode.id,
        "clip": episode.clip,
        "scenario": episode.scenario,
        "seed": episode.seed,
        "method": method.name,
        "base": method.base,
        "selector": method.selector or "",
        "optimizer": method.optimizer or "",
        "ragdoll": int(method.ragdoll),
        "budget": runner.budget if not method.is_filter else "",
        "frames": count,
        "input_frames": recording.num_frames,
        "interrupted": int(result.interrupted),
        "seconds": round(seconds, 4),
        "recoveries": result.info.get("recoveries", ""),
        "ragdoll_divergences": result.info.get("ragdoll_divergences", ""),
    }
    arrays: dict[str, np.ndarray] = {
        "poses": poses.astype(np.float32),
        "ms": result.ms.astype(np.float64),
        "stage_names": np.array(list(result.stage_ms)),
        "stage_ms": (
            np.stack([result.stage_ms[s] for s in result.stage_ms], axis=1)
            if result.stage_ms
            else np.zeros((count, 0))
        ),
    }
    if count:
        times = metrics.time_summary(result.ms)
        row.update(ms_median=times["median"], ms_p95=times["p95"], ms_mean=times["mean"])
        spread = metrics.bone_length_variation(poses)
        row["bone_length_spread_mm"] = 1000.0 * _nanmean(spread)
        row["jitter_ms2"] = _jitter(poses, recording.timestamps[:count])
        row["settled_bone_spread_mm"] = _settled_spread_mm(poses, recording.timestamps[:count])
    bones = result.info.get("bone_settling")
    if isinstance(bones, dict):
        row["bone_changes_after_settling"] = bones.get("changes_after_settling", "")
    if result.evaluations is not None and count:
        row["evaluations_mean"] = float(result.evaluations.mean())
        arrays["evaluations"] = result.evaluations
    if result.energy is not None and count:
        row["energy_mean"] = _nanmean(result.energy)
        arrays["energy"] = result.energy
    if truth is not None and count:
        errors = metrics.frame_error(truth[:count], poses)
        row.update(
            mean_error_m=float(errors.mean()),
            std_error_m=float(errors.std()),
            median_error_m=float(np.median(errors)),
            p95_error_m=float(np.percentile(errors, 95)),
            err02_pct=100.0 * metrics.err_ratio(errors),
            input_mean_error_m=metrics.mean_error(truth[:count], recording.positions[:count]),
            truth_jitter_ms2=_jitter(truth[:count], recording.timestamps[:count]),
        )
        arrays["errors"] = errors
        arrays["per_joint_error"] = metrics.per_joint_error(truth[:count], poses)
        arrays["per_joint_root_error"] = metrics.root_relative_error(truth[:count], poses)
        # The field's measures beside Eq. 13: absolute, root-relative and Procrustes-aligned
        # joint distances, bone lengths against the truth, occluded and visible joints apart.
        distances = metrics.joint_distances(truth[:count], poses)
        arrays["per_joint_mpjpe"] = distances.mean(axis=0)
        row.update(
            mpjpe_m=float(distances.mean()),
            root_mpjpe_m=metrics.mpjpe(truth[:count], poses, "root"),
            pa_mpjpe_m=metrics.mpjpe(truth[:count], poses, "procrustes"),
            bone_length_error_mm=1000.0
            * float(metrics.bone_length_error(truth[:count], poses).mean()),
            input_mpjpe_m=metrics.mpjpe(truth[:count], recording.positions[:count]),
        )
        occluded = getattr(recording, "occluded", None)
        if occluded is not None:
            hidden = np.asarray(occluded[:count], dtype=bool)
            row["occluded_joint_frames"] = int(hidden.sum())
            if hidden.any():
                row["occluded_mpjpe_m"] = float(distances[hidden].mean())
            if (~hidden).any():
                row["visible_mpjpe_m"] = float(distances[~hidden].mean())
        if count >= 3:
            frames_lag = metrics.lag(poses, truth[:count])
            row["lag_frames"] = frames_lag
            row["lag_ms"] = 1000.0 * frames_lag * _frame_interval(recording.timestamps[:count])
    return row, arrays


# Worker processes: one runner per process, set by the pool initializer (process-local).
_WORKER_RUNNER: MethodRunner | None = None


def _exit_with_parent(parent: int, interval: float = 1.0) -> None:
    """Exit this worker process as soon as its parent is gone (killed with SIGKILL, say): a
    daemon thread polls the parent's id, and the process exits when it changes."""

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(1)
            time.sleep(interval)

    threading.Thread(target=watch, name="fpg-gym-parent-watch", daemon=True).start()


def _init_worker(
    graph: str,
    exclude: list[str],
    budget: int,
    options: dict[str, Any],
    parent: int | None = None,
) -> None:
    global _WORKER_RUNNER
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if parent is not None:
        _exit_with_parent(parent)
    warnings.simplefilter("ignore")
    _WORKER_RUNNER = MethodRunner(
        load_graph(graph, exclude=exclude), budget=budget, reconstructor_options=options
    )


def _worker_batch(tasks: list[_Task]) -> list[tuple[dict[str, Any], dict[str, np.ndarray]]]:

    assert _WORKER_RUNNER is not None, "worker not initialised"
    return _run_batch(_WORKER_RUNNER, tasks, load_recording)


@dataclass
class CompareOutcome:
    """What :func:`run_compare` did.

    Attributes
    ----------
    out : Path
    summary : dict
        The content of ``summary.json``.
    table : str
        The main table (markdown).
    tasks_run, tasks_skipped : int
        Tasks finished now, and finished ones found from an earlier run.
    interrupted : bool
        Ctrl-C stopped the run (the report covers the finished tasks).
    seconds : float
    files : list of Path
        Everything written at the top of ``out``.
    """

    out: Path
    summary: dict[str, Any]
    table: str
    tasks_run: int
    tasks_skipped: int
    interrupted: bool
    seconds: float
    files: list[Path]


def _check_optimizers(methods: Sequence[str]) -> None:
    """Make every optimiser once, so a missing one or a missing dependency fails first."""

    for name in methods:
        method = parse_method(name)
        if method.optimizer is not None:
            make(method.optimizer)


def _episodes_sensor(config: CompareConfig, folder: Path, episodes: Sequence[EpisodeSpec]) -> str:
    """The sensor of the episodes: ``config.sensor``, else the one their recordings name
    (simulated episodes: ``"simulated"``).

    Raises
    ------
    ValueError
        If the recordings come from several sensors and ``config.sensor`` is not given.
    """
    if config.sensor:
        return config.sensor
    sensors = {sensor_of(load_recording(folder / f"{e.id}.npz")) for e in episodes}
    if len(sensors) > 1:
        raise ValueError(
            f"the episodes come from several sensors ({', '.join(sorted(sensors))}): compare "
            "them separately or give --sensor"
        )
    return sensors.pop() if sensors else "unknown"


def _held_out_warning(
    graph: Any, episodes: Sequence[EpisodeSpec], extra_names: Sequence[str] = ()
) -> str:
    names = {str(n) for n in getattr(graph, "clip_names", ())}
    shared = sorted(({e.clip for e in episodes} | set(extra_names)) & names)
    if not shared:
        return ""
    listed = ", ".join(shared[:5]) + (" ..." if len(shared) > 5 else "")
    return (
        f"{len(shared)} evaluated clip(s) are also graph clips ({listed}): the graph was not "
        "built without the evaluated takes, so accuracy is optimistic"
    )


def _run_batch(
    runner: MethodRunner, tasks: Sequence[_Task], load: Callable[[str], Any]
) -> list[tuple[dict[str, Any], dict[str, np.ndarray]]]:
    """Run a batch of tasks (one method): side by side (:func:`_execute_batch`) or one by one
    (:func:`_execute`), with a failure named: a :class:`~fpg_gym.core.errors.TaskError` says which
    episode(s) and method failed, and why."""
    groups = [list(tasks)] if _side_by_side(tasks) else [[task] for task in tasks]
    out: list[tuple[dict[str, Any], dict[str, np.ndarray]]] = []
    for group in groups:
        try:
            recordings = [load(t.recording_path) for t in group]
            if len(group) == 1:
                out.append(_execute(runner, group[0], recordings[0]))
            else:
                out.extend(_execute_batch(runner, group, recordings))
        except (KeyboardInterrupt, SystemExit):
            raise
        except Exception as error:
            episodes = ", ".join(f"{t.episode.id!r} ({t.recording_path})" for t in group)
            raise TaskError(
                f"episode {episodes}, method {group[0].method!r} "
                f"failed: {type(error).__name__}: {' '.join(str(error).split())}"
            ) from error
    return out


def _run_loaded(
    runner: MethodRunner, tasks: Sequence[_Task], recordings: Sequence[Any]
) -> list[tuple[dict[str, Any], dict[str, np.ndarray]]]:
    """:func:`_run_batch` on recordings already read (a Ray task receives them with the
    batch: the worker may be on another machine)."""
    by_path = {t.recording_path: r for t, r in zip(tasks, recordings, strict=True)}
    return _run_batch(runner, tasks, by_path.__getitem__)


def _batches(tasks: Sequence[_Task], size: int, workers: int = 1) -> list[list[_Task]]:
    """Tasks grouped by method, in chunks of at most ``size`` episodes (one method per chunk,
    reconstructed side by side); a method's chunks are made smaller when that gives each of
    ``workers`` processes work."""
    by_method: dict[str, list[_Task]] = {}
    for task in tasks:
        by_method.setdefault(task.method, []).append(task)
    batches: list[list[_Task]] = []
    for group in by_method.values():
        step = max(1, min(int(size), -(-len(group) // max(1, int(workers)))))
        batches.extend(group[i : i + step] for i in range(0, len(group), step))
    return batches


def run_compare(
    config: CompareConfig,
    *,
    progress: bool = True,
    fresh: bool = False,
    plots: bool = True,
    log: Callable[[str], None] | None = None,
) -> CompareOutcome:
    """Run every episode x method of ``config`` and write the report (see the module docstring).

    Parameters
    ----------
    config : CompareConfig
    progress : bool
        tqdm progress bars on stderr.
    fresh : bool
        Delete the results of an earlier run in ``config.out`` instead of resuming.
    plots : bool
        Write the PNG plots.
    log : callable, optional
        Receives one-line messages (default: print to stderr).

    Raises
    ------
    ValueError
        Bad settings, an unknown optimiser/scenario, or ``out`` holding a run with other
        settings (pass ``fresh=True``).
    """

    say = log or (lambda text: print(text, file=sys.stderr))
    started = time.perf_counter()
    out = Path(config.out)
    _check_optimizers(config.methods)
    if config.backend == "ray":
        require_ray()  # before any episode is simulated
        check_address(config.address)  # a dead address fails now, not after minutes

    method_keys = config.method_keys()  # the models' content, read before any work
    with claim_folder(out, fresh, say) as manifest:
        return _run_claimed(
            config, out, manifest, fresh, plots, progress, say, started, method_keys
        )


def _run_claimed(
    config: CompareConfig,
    out: Path,
    manifest: Manifest,
    fresh: bool,
    plots: bool,
    progress: bool,
    say: Callable[[str], None],
    started: float,
    method_keys: dict[str, str],
) -> CompareOutcome:
    """:func:`run_compare` in a folder it holds (``manifest``)."""
    config_path = out / "config.json"
    results_path = out / "results.csv"
    episodes, embedded, seen, resume_key = resume_folder(
        config, out, manifest, fresh, progress, say, method_keys
    )
    graph_name, exclude, graph, chosen, warning = _pipeline(
        config, out, episodes, embedded, seen, say
    )
    write_text(
        config_path,
        json.dumps(
            {
                "config": asdict(config),
                "resume_key": resume_key,
                "method_keys": method_keys,
                "graph_exclude": exclude,
                "graph_resolved": graph_name,
                "graph_summary": repr(graph),
                "pipeline": chosen.summary(),
                "held_out_warning": warning,
                "episodes": [asdict(e) for e in episodes],
            },
            indent=2,
        ),
    )

    tasks, skipped = _tasks_to_run(config, episodes, out, say)
    options = {"k": config.k, **chosen.options}
    writer = ResultsWriter(results_path)
    bar = tqdm(total=len(tasks), desc="compare", unit="run", disable=not progress)
    completed = [0]

    def finish(row: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        path = frames_path(out, row["episode"], row["method"])
        manifest.add(path)
        save_frames(path, arrays)
        writer.write(row)
        completed[0] += 1
        error = row.get("mean_error_m")
        bar.set_postfix_str(
            f"{row['method']} {error:.3f} m" if isinstance(error, float) else row["method"],
            refresh=False,
        )
        bar.update(1)

    batches = _batches(tasks, config.batch, config.workers)
    try:
        interrupted = _run_batches(config, batches, graph, graph_name, exclude, options, finish)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
        writer.close()
    if interrupted:
        say("interrupted: finished results are kept; writing the report from them")
    summary = write_report(
        out, plots=plots, baseline=config.baseline, interrupted=interrupted, claim=manifest.add
    )
    files = sorted(p for p in out.iterdir() if p.is_file())
    return CompareOutcome(
        out=out,
        summary=summary,
        table=format_table(summary),
        tasks_run=completed[0],
        tasks_skipped=skipped,
        interrupted=interrupted,
        seconds=time.perf_counter() - started,
        files=files,
    )


def _pipeline(
    config: CompareConfig,
    out: Path,
    episodes: Sequence[EpisodeSpec],
    embedded: list[str],
    seen: list[str],
    say: Callable[[str], None],
) -> tuple[str, list[str], Any, Any, str | None]:
    """The graph (name, the clips it leaves out, the graph) and the pipeline chosen for the
    episodes' sensor, with the warning when the graph saw an episode's source."""
    sensor = _episodes_sensor(config, out / "episodes", episodes)
    graph_name = default_graph_name(sensor) if config.graph == "default" else config.graph
    exclude = embedded if graph_name in ("default", "embedded") else []
    graph = load_graph(graph_name, exclude=exclude)
    chosen = choose_pipeline(config.preset, sensor, graph, config.tuning_options())
    say(f"configuration: {chosen.preset}: {chosen.description}")
    if chosen.note:
        say(f"note: {chosen.note}")
    warning = _held_out_warning(graph, episodes, seen)
    if warning:
        say(f"warning: {warning}")
    return graph_name, exclude, graph, chosen, warning


def _tasks_to_run(
    config: CompareConfig, episodes: Sequence[EpisodeSpec], out: Path, say: Callable[[str], None]
) -> tuple[list[_Task], int]:
    """The (episode, method) runs not finished in ``out``'s results, and the number of finished
    ones kept."""
    results_path = out / "results.csv"
    done = {
        (r["episode"], r["method"])
        for r in read_rows(results_path)
        if r.get("interrupted") in ("0", "")  # the others ran again: their file is rewritten
    }
    tasks = [
        _Task(e, m, str(out / "episodes" / f"{e.id}.npz"))
        for e in episodes
        for m in config.methods
        if (e.id, m) not in done
    ]
    skipped = len(episodes) * len(config.methods) - len(tasks)
    if skipped:
        say(f"resuming: {skipped} finished task(s) in {results_path} are kept")
    return tasks, skipped


def _run_batches(
    config: CompareConfig,
    batches: list[list[_Task]],
    graph: Any,
    graph_name: str,
    exclude: list[str],
    options: dict[str, Any],
    finish: Callable[[dict[str, Any], dict[str, np.ndarray]], None],
) -> bool:
    """Run the batches on Ray, in this process or in a pool of workers, each result through
    ``finish``; True when the run was interrupted."""
    workers = max(1, min(int(config.workers), len(batches)))
    if config.backend == "ray":
        return run_on_ray(
            batches,
            graph,
            config.budget,
            options,
            _run_loaded,
            load_recording,
            finish,
            address=config.address,
            num_cpus=config.workers,
        )
    if workers <= 1:
        with MethodRunner(graph, budget=config.budget, reconstructor_options=options) as runner:
            for batch in batches:
                for result in _run_batch(runner, batch, load_recording):
                    finish(*result)
        return False
    return _run_pool(batches, workers, config, graph_name, exclude, options, finish)


def _run_pool(
    batches: Sequence[list[_Task]],
    workers: int,
    config: CompareConfig,
    graph_name: str,
    exclude: list[str],
    options: dict[str, Any],
    finish: Callable[[dict[str, Any], dict[str, np.ndarray]], None],
) -> bool:
    """Run ``batches`` of tasks in ``workers`` spawned processes; True when interrupted by
    Ctrl-C."""

    # The per-frame matrices are tiny: one BLAS thread per worker avoids oversubscription.
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    executor = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(graph_name, list(exclude), config.budget, options, os.getpid()),
    )
    pending: dict[Future[Any], list[_Task]] = {}
    try:
        queue = list(batches)
        # Keep a few batches queued per worker so that Ctrl-C leaves little to cancel.
        while queue or pending:
            while queue and len(pending) < 2 * workers:
                batch = queue.pop(0)
                pending[executor.submit(_worker_batch, batch)] = batch
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                batch = pending.pop(future)
                try:
                    results = future.result()
                except BrokenProcessPool:
                    raise TaskError(
                        f"a worker process died (killed, or out of memory) while running "
                        f"episode {batch[0].episode.id!r}, method {batch[0].method!r} or a task "
                        "beside it; finished results are kept, rerun to resume"
                    ) from None
                for result in results:
                    finish(*result)
    except KeyboardInterrupt:
        _stop_pool(executor, pending)
        return True
    except BaseException:
        _stop_pool(executor, pending)
        raise
    executor.shutdown(wait=True)
    return False


def _stop_pool(executor: ProcessPoolExecutor, pending: Iterable[Future[Any]]) -> None:
    """Cancel what is queued and stop the workers still running (they ignore SIGINT)."""
    for future in pending:
        future.cancel()
    processes = list(getattr(executor, "_processes", {}).values())
    executor.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(timeout=5)
