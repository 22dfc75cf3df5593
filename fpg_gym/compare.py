"""Compare reconstruction methods on many episodes: ``fpg-gym compare`` and ``fpg-gym demo``.

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
    episodes/*.npz    the simulated recordings (``fpg_gym.io.load_recording``)
    frames/E/M.npz    per-frame error, ms, stage ms, evaluations, energy and output poses
    summary.json      per-method aggregates, the paired tests, the settings
    report.md         the tables (FPG §8 style) and the plots
    *.png             error histogram, cumulative curve, error over time, frame times

Safety: compare writes only into a folder it created (or an empty one) and lists every file it
writes in ``manifest.txt`` before writing it; ``fresh=True`` deletes the listed files and nothing
else, and is refused on a folder without a manifest. Resuming trusts nothing stale: a torn last
row of ``results.csv`` (a kill during a write) is dropped with a warning, and episodes are keyed
by content (:attr:`EpisodeSpec.key`, a hash of the input file or clip and of the episode's
settings), so a different clip under the same file name is recomputed, and two inputs with the
same file name stay two episodes.

Hold-out rule: the graph must not contain the evaluated takes. ``--graph default`` builds the
embedded graph without the evaluated embedded clips; for a graph file, build it from other takes
(``scripts/holdout_split.py``); the report warns when an evaluated clip's name is a graph clip.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import re
import signal
import sys
import threading
import time
import warnings
import zlib
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym import metrics, skeleton
from fpg_gym.definitions import DefinitionMap
from fpg_gym.errors import OutputError, TaskError
from fpg_gym.graph import load_graph
from fpg_gym.jsonable import jsonable
from fpg_gym.methods import BASELINE, MethodRunner, parse_method
from fpg_gym.outputs import save_npz, write_text

__all__ = [
    "CSV_FIELDS",
    "MANIFEST_NAME",
    "TABLE_COLUMNS",
    "CompareConfig",
    "EpisodeSpec",
    "format_table",
    "markdown_table",
    "plan_episodes",
    "resolve_clips",
    "run_compare",
    "summarise",
    "write_report",
]

#: Columns of ``results.csv`` (one row per episode and method).
CSV_FIELDS: tuple[str, ...] = (
    "episode",
    "clip",
    "scenario",
    "seed",
    "method",
    "base",
    "selector",
    "optimizer",
    "ragdoll",
    "budget",
    "frames",
    "input_frames",
    "interrupted",
    "mean_error_m",
    "std_error_m",
    "median_error_m",
    "p95_error_m",
    "err02_pct",
    "input_mean_error_m",
    "bone_length_spread_mm",
    "jitter_ms2",
    "truth_jitter_ms2",
    "ms_median",
    "ms_p95",
    "ms_mean",
    "evaluations_mean",
    "energy_mean",
    "recoveries",
    "ragdoll_divergences",
    "seconds",
    "lag_frames",
    "lag_ms",
    "settled_bone_spread_mm",
    "bone_changes_after_settling",
)

#: Columns of the main table of ``report.md`` (and of what ``compare``/``demo`` print).
TABLE_COLUMNS: tuple[str, ...] = (
    "method",
    "episodes",
    "mean error (m) ± std",
    "Err0.2 (%) min / mean / max",
    "bone-length spread (mm)",
    "jitter (m/s²)",
    "lag (frames)",
    "bone spread after 1 s, max (mm)",
    "ms/frame median / p95",
    "evaluations/frame",
    "mean energy",
)

#: Columns of the paired-test table.
TEST_COLUMNS: tuple[str, ...] = (
    "method",
    "paired episodes",
    "mean error − baseline (m)",
    "lower error in",
    "Wilcoxon p",
)

_SAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def _safe(text: str) -> str:
    """A file-name-safe form of ``text`` (``:`` and spaces become ``_``)."""
    return _SAFE.sub("_", text).strip("_") or "x"


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: a clip simulated in a scenario with a seed, or a recording file.

    Attributes
    ----------
    id : str
        Unique, file-name safe (``clip__scenario__s0``).
    clip : str
        Clip name (or the recording's file stem).
    scenario : str
        Simulator scenario (``""`` for a recording file).
    seed : int
        The user's seed (``--seeds``).
    sim_seed : int
        Seed of the simulator and of the optimisers on this episode (every method gets the
        same one: paired comparisons); derived from ``seed``, the clip and the scenario names.
    recording : str
        Recording file of an input episode (``""`` for simulated ones).
    key : str
        Content key: a hash of the input (the recording file's bytes, or the clip's poses and
        rate) and of the episode's settings (scenario, seeds, frame cap). A rerun reuses an
        episode's files and finished rows only when its key is unchanged (``""``: unknown).
    """

    id: str
    clip: str
    scenario: str
    seed: int
    sim_seed: int
    recording: str = ""
    key: str = ""


@dataclass
class CompareConfig:
    """Everything ``fpg-gym compare`` needs (the CLI fills it from its arguments).

    Attributes
    ----------
    out : str
        Output folder.
    methods : list of str
        Method names (:mod:`fpg_gym.methods`); canonicalised.
    graph : str
        ``"default"`` (the embedded graph without the evaluated embedded clips) or a ``.npz``.
    clips : list of str
        Mocap files/folders, ``"default"`` (the embedded held-out clips
        :data:`fpg_gym.defaults.DEFAULT_HOLDOUT_CLIPS`), embedded clip names (``walk`` or
        ``default:walk``).
    inputs : list of str
        Recording files (``.npz`` with ground truth for errors; other formats give timing and
        smoothness only).
    scenarios : list of str
        Simulator scenarios for ``clips``.
    seeds : list of int
    budget : int
        Energy evaluations per frame (2,000).
    k : int
        Candidates per frame (30).
    max_frames : int or None
        Cap on frames per episode (the first ones).
    workers : int
        Processes; 1 runs in this process.
    baseline : str
        Method the others are tested against (:data:`fpg_gym.methods.BASELINE`).
    units : str
        BVH units for ``clips``.
    sensor_map, output_map : str or None
        Joint-definition map files (:class:`fpg_gym.definitions.DefinitionMap`) for the
        reconstruction methods (``ReconstructorConfig.sensor_map`` / ``output_map``).
    sensor_blend : float
        ``ReconstructorConfig.sensor_blend`` of the reconstruction methods (0).
    calibrate_output : bool
        ``ReconstructorConfig.calibrate_output`` (False).
    calibration_map : str or None
        Map file for ``ReconstructorConfig.calibration_map``.
    input_format : str or None
        Format of the ``inputs`` (:data:`fpg_gym.io.kinect.KINECT_FORMATS`); None guesses it
        per file.
    """

    out: str
    methods: list[str]
    graph: str = "default"
    clips: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    scenarios: list[str] = field(default_factory=list)
    seeds: list[int] = field(default_factory=lambda: [0])
    budget: int = 2000
    k: int = 30
    max_frames: int | None = None
    workers: int = 1
    baseline: str = BASELINE.name
    units: str = "auto"
    sensor_map: str | None = None
    output_map: str | None = None
    sensor_blend: float = 0.0
    calibrate_output: bool = False
    calibration_map: str | None = None
    input_format: str | None = None

    def __post_init__(self) -> None:
        self.methods = [parse_method(m).name for m in self.methods]
        if not self.methods:
            raise ValueError("methods: no method to run")
        self.baseline = parse_method(self.baseline).name
        if self.budget < 0:
            raise ValueError(f"budget: expected >= 0 evaluations per frame, got {self.budget}")
        if self.k < 1:
            raise ValueError(f"k: expected >= 1 candidates, got {self.k}")
        if self.max_frames is not None and self.max_frames < 3:
            raise ValueError(f"max_frames: expected at least 3 frames, got {self.max_frames}")
        if not self.clips and not self.inputs:
            raise ValueError("give --clips (with --scenarios) and/or --inputs")
        if self.clips and not self.scenarios:
            from fpg_gym.defaults import DEFAULT_EPISODE_SCENARIOS

            self.scenarios = list(DEFAULT_EPISODE_SCENARIOS)
        if self.calibrate_output and self.output_map:
            raise ValueError("calibrate_output and output_map: give one (both set the output map)")
        if self.calibration_map and not self.calibrate_output:
            raise ValueError("calibration_map: only used with calibrate_output")
        if not self.seeds:
            raise ValueError("seeds: at least one seed")
        if any(s < 0 for s in self.seeds):
            raise ValueError(f"seeds: expected non-negative integers, got {self.seeds}")

    def resume_key(self) -> dict[str, Any]:
        """Settings that must match for a rerun to reuse finished rows."""
        return {
            "graph": self.graph,
            "budget": self.budget,
            "k": self.k,
            "max_frames": self.max_frames,
            "units": self.units,
            "sensor_map": _file_digest(self.sensor_map),
            "output_map": _file_digest(self.output_map),
            "sensor_blend": self.sensor_blend,
            **({"calibrate_output": True} if self.calibrate_output else {}),
            **(
                {"calibration_map": _file_digest(self.calibration_map)}
                if self.calibration_map
                else {}
            ),
        }

    def reconstructor_options(self) -> dict[str, Any]:
        """The :class:`~fpg_gym.reconstruct.ReconstructorConfig` settings of the methods."""
        options: dict[str, Any] = {"k": self.k, "sensor_blend": self.sensor_blend}
        if self.sensor_map:
            options["sensor_map"] = DefinitionMap.load(self.sensor_map)
        if self.output_map:
            options["output_map"] = DefinitionMap.load(self.output_map)
        if self.calibrate_output:
            options["calibrate_output"] = True
        if self.calibration_map:
            options["calibration_map"] = DefinitionMap.load(self.calibration_map)
        return options


def _file_digest(path: str | None) -> str | None:
    """SHA-256 of a file's bytes (None for no file): settings that name a file are keyed by
    its content, so an edited map is not mistaken for the one a finished row used."""
    if not path:
        return None
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# --------------------------------------------------------------------------- episodes


def resolve_clips(
    items: Sequence[str], units: str = "auto", progress: bool = False
) -> tuple[list[Any], list[str]]:
    """Read the clips named by ``--clips`` (see :class:`CompareConfig`), in order.

    ``default`` means the embedded held-out clips; ``walk`` / ``default:walk`` an embedded clip;
    anything else a mocap file or folder.

    Returns
    -------
    clips : list of Clip
    embedded : list of str
        Names of the embedded clips among them (the default graph leaves these out).
    """
    from fpg_gym.defaults import DEFAULT_HOLDOUT_CLIPS
    from fpg_gym.io import DEFAULT_CLIP_NAMES, load_clips, load_default_clips

    clips: list[Any] = []
    embedded: list[str] = []
    files: list[str] = []

    def flush_files() -> None:
        if files:
            clips.extend(load_clips(list(files), units=units, progress=progress))
            files.clear()

    for item in items:
        text = str(item)
        name = text.removeprefix("default:")
        if text == "default":
            flush_files()
            clips.extend(load_default_clips(list(DEFAULT_HOLDOUT_CLIPS)))
            embedded.extend(DEFAULT_HOLDOUT_CLIPS)
        elif name in DEFAULT_CLIP_NAMES and not Path(text).exists():
            flush_files()
            clips.extend(load_default_clips([name]))
            embedded.append(name)
        elif text.startswith("default:"):
            raise ValueError(
                f"--clips: unknown embedded clip {name!r}; expected one of "
                + ", ".join(DEFAULT_CLIP_NAMES)
            )
        else:
            files.append(text)
    flush_files()
    return clips, sorted(set(embedded))


def _derived_seed(seed: int, *names: str) -> int:
    """A seed from the user's seed and names (stable whatever the order of the lists)."""
    words = [int(seed)] + [zlib.crc32(n.encode()) for n in names]
    return int(np.random.SeedSequence(words).generate_state(1)[0])


def plan_episodes(
    clip_names: Sequence[str],
    scenarios: Sequence[str],
    seeds: Sequence[int],
    recordings: Sequence[str] = (),
    recording_hashes: Sequence[str] = (),
) -> list[EpisodeSpec]:
    """Every clip x scenario x seed, then every recording x seed (ids made unique).

    With ``recording_hashes`` (one content hash per recording), recordings whose file names
    collide but whose contents differ are named ``stem~HASH`` (stable whatever their order),
    and the same file given twice keeps one name.
    """
    episodes: list[EpisodeSpec] = []
    used: set[str] = set()
    stems = [Path(path).name.removesuffix(".npz") for path in recordings]
    if recording_hashes:
        distinct: dict[str, set[str]] = {}
        for stem, digest in zip(stems, recording_hashes, strict=True):
            distinct.setdefault(stem, set()).add(digest)
        stems = [
            f"{stem}~{digest[:8]}" if len(distinct[stem]) > 1 else stem
            for stem, digest in zip(stems, recording_hashes, strict=True)
        ]

    def unique(base: str) -> str:
        name, n = base, 2
        while name in used:
            name, n = f"{base}-{n}", n + 1
        used.add(name)
        return name

    for seed in seeds:
        for clip in clip_names:
            for scenario in scenarios:
                episodes.append(
                    EpisodeSpec(
                        id=unique(_safe(f"{clip}__{scenario}__s{seed}")),
                        clip=clip,
                        scenario=scenario,
                        seed=int(seed),
                        sim_seed=_derived_seed(seed, clip, scenario),
                    )
                )
        for path, stem in zip(recordings, stems, strict=True):
            episodes.append(
                EpisodeSpec(
                    id=unique(_safe(f"{stem}__s{seed}")),
                    clip=stem,
                    scenario="",
                    seed=int(seed),
                    sim_seed=_derived_seed(seed, stem),
                    recording=str(path),
                )
            )
    return episodes


def _file_hash(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _clip_hash(clip: Any) -> str:
    """SHA-256 of a clip's content: its poses (float32) and frame rate (hex)."""
    digest = hashlib.sha256(np.ascontiguousarray(clip.positions, dtype=np.float32).tobytes())
    digest.update(repr(float(clip.fps)).encode())
    return digest.hexdigest()


def _episode_key(episode: EpisodeSpec, content: str, max_frames: int | None) -> str:
    """The content key of an episode (see :attr:`EpisodeSpec.key`)."""
    settings = {
        "content": content,
        "scenario": episode.scenario,
        "seed": episode.seed,
        "sim_seed": episode.sim_seed,
        "max_frames": max_frames,
    }
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:24]


def _unique_clip_names(clips: Sequence[Any], say: Callable[[str], None]) -> dict[str, Any]:
    """Clips by name, distinct clips kept distinct: when different clips share a name (two
    ``walk.bvh`` in different folders) each is named ``name~HASH``; the same clip given twice
    is kept once."""
    groups: dict[str, dict[str, Any]] = {}
    for clip in clips:
        groups.setdefault(clip.name, {}).setdefault(_clip_hash(clip), clip)
    by_name: dict[str, Any] = {}
    for name, variants in groups.items():
        if len(variants) == 1:
            by_name[name] = next(iter(variants.values()))
            continue
        say(
            f"warning: {len(variants)} different clips are named {name!r}; they are kept apart "
            f"as {', '.join(f'{name}~{h[:8]}' for h in variants)}"
        )
        for digest, clip in variants.items():
            renamed = f"{name}~{digest[:8]}"
            by_name[renamed] = replace(clip, name=renamed)
    return by_name


def _plan(
    config: CompareConfig, progress: bool, say: Callable[[str], None]
) -> tuple[list[EpisodeSpec], dict[str, Any], list[str], list[str]]:
    """Plan the episodes with their content keys (reading the clips; nothing is written).

    Returns the episodes, the clips by (unique) name, the embedded clips to leave out of the
    default graph, and the original names of the clips (for the held-out warning).
    """
    from fpg_gym.simulate import get_scenario

    for scenario in config.scenarios:
        get_scenario(scenario)  # unknown names fail here, before any work
    for name in config.inputs:
        if not Path(name).is_file():
            raise FileNotFoundError(f"--inputs: {name}: no such file")
    clips, embedded = (
        resolve_clips(config.clips, config.units, progress=progress) if config.clips else ([], [])
    )
    by_name = _unique_clip_names(clips, say)
    hashes = {name: _clip_hash(clip) for name, clip in by_name.items()}
    recording_hashes = [_file_hash(path) for path in config.inputs]
    planned = plan_episodes(
        list(by_name), config.scenarios, config.seeds, config.inputs, recording_hashes
    )
    # The format an input is read with is part of its content.
    by_path = {
        path: f"{digest}:{config.input_format or 'guessed'}"
        for path, digest in zip(config.inputs, recording_hashes, strict=True)
    }
    episodes = [
        replace(
            e,
            key=_episode_key(
                e, by_path[e.recording] if e.recording else hashes[e.clip], config.max_frames
            ),
        )
        for e in planned
    ]
    return episodes, by_name, embedded, sorted({c.name for c in clips})


def _write_episodes(
    config: CompareConfig,
    episodes: Sequence[EpisodeSpec],
    by_name: dict[str, Any],
    folder: Path,
    progress: bool,
    manifest: _Manifest,
    rewrite: set[str] | frozenset[str] = frozenset(),
) -> list[str]:
    """Write the episodes' recordings, reusing the ones already there except the ``rewrite``
    (stale) ones. Returns the embedded clips the recording files (``--inputs``) were simulated
    from."""
    from tqdm.auto import tqdm

    from fpg_gym.io import read_recording, write_recording
    from fpg_gym.simulate import KinectSimulator

    folder.mkdir(parents=True, exist_ok=True)
    simulators: dict[str, Any] = {}
    bar = tqdm(episodes, desc="episodes", unit="episode", disable=not progress, leave=False)
    try:
        for episode in bar:
            target = folder / f"{episode.id}.npz"
            if target.is_file() and episode.id not in rewrite:
                continue
            if episode.recording:
                recording = read_recording(episode.recording, format=config.input_format)
            else:
                if episode.scenario not in simulators:
                    simulators[episode.scenario] = KinectSimulator(episode.scenario)
                clip = by_name[episode.clip]
                recording = simulators[episode.scenario].simulate(clip, seed=episode.sim_seed)
            recording = recording.head(config.max_frames)
            manifest.add(target)
            write_recording(target, recording)  # atomic: temporary file, then rename
    finally:
        bar.close()
        for simulator in simulators.values():
            simulator.close()
    # A recording simulated from an embedded clip must be held out of the default graph too.
    recorded: list[str] = []
    for episode in episodes:
        if episode.recording:
            clip_name = _recording_clip(folder / f"{episode.id}.npz")
            if clip_name:
                recorded.append(clip_name)
    return recorded


def _recording_clip(path: Path) -> str:
    """The embedded clip a simulated recording came from (``""`` for anything else)."""
    with np.load(path, allow_pickle=False) as archive:
        metadata = json.loads(str(archive["metadata"])) if "metadata" in archive.files else {}
    source = str(metadata.get("source", ""))
    if metadata.get("format") == "simulated" and "pybullet_data" in source:
        return str(metadata.get("clip", ""))
    return ""


# --------------------------------------------------------------------------- one task


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


def _execute(
    runner: MethodRunner, task: _Task, recording: Any
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Run one method on one episode; return the CSV row and the per-frame arrays."""
    method = parse_method(task.method)
    episode = task.episode
    start = time.perf_counter()
    result = runner.run(method, recording, seed=episode.sim_seed)
    seconds = time.perf_counter() - start
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


def _worker_task(task: _Task) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    from fpg_gym.io.recording import load_recording

    assert _WORKER_RUNNER is not None, "worker not initialised"
    return _run_task(_WORKER_RUNNER, task, load_recording)


# --------------------------------------------------------------------------- results files


def _read_rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _repair_results(
    path: Path, say: Callable[[str], None], drop_episodes: Iterable[str] = ()
) -> None:
    """Make ``results.csv`` safe to append to: drop a torn last row (a kill during a write
    leaves a row without its line end, which the next row would be glued to), rows whose
    field count is wrong, and the rows of ``drop_episodes`` (stale episodes); rewrite it with
    the header :data:`CSV_FIELDS` (columns matched by name) when its header differs. Warns
    (``say``) about every row dropped but the stale ones. The file is rewritten atomically,
    and only when something changed."""
    if not path.is_file():
        return
    raw = path.read_bytes()
    if not raw:
        return
    changed = False
    if raw.endswith(b"\r"):  # the row is whole; only its "\n" is missing
        raw += b"\n"
        changed = True
    if not raw.endswith(b"\n"):
        cut = raw.rfind(b"\n") + 1
        torn = raw[cut:].decode("utf-8", errors="replace")
        line = raw.count(b"\n") + 1
        say(
            f"warning: {path}, line {line}: the last row was cut off (an interrupted write); "
            f"dropped it ({torn[:60]!r}); its task runs again"
        )
        raw = raw[:cut]
        changed = True
    rows = list(csv.reader(io.StringIO(raw.decode("utf-8", errors="replace"), newline="")))
    if not rows:
        path.write_bytes(b"")
        return
    header, body = rows[0], rows[1:]
    if tuple(header) != CSV_FIELDS:
        changed = True
    drop = set(drop_episodes)
    kept: list[dict[str, str]] = []
    for number, row in enumerate(body, start=2):
        if len(row) != len(header):
            say(
                f"warning: {path}, line {number}: expected {len(header)} fields, got {len(row)}; "
                "dropped the row; its task runs again"
            )
            changed = True
            continue
        record = dict(zip(header, row, strict=True))
        if record.get("episode") in drop:
            changed = True
            continue
        kept.append(record)
    if not changed:
        return
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(CSV_FIELDS), extrasaction="ignore")
    writer.writeheader()
    for record in kept:
        writer.writerow({k: record.get(k, "") for k in CSV_FIELDS})
    write_text(path, buffer.getvalue())


#: The file listing what compare wrote in its output folder.
MANIFEST_NAME = "manifest.txt"
_MANIFEST_HEADER = (
    "# fpg-gym compare manifest v1: the files fpg-gym compare wrote in this folder, one relative "
    "path per line; compare --fresh deletes these and nothing else\n"
)


class _Manifest:
    """``manifest.txt``: every file compare writes in its folder, listed (appended and flushed)
    before the file is written, so that ``--fresh`` can delete exactly those files."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.path = out / MANIFEST_NAME
        self.listed: set[str] = set(self.entries())
        if not self.path.is_file():
            self.path.write_text(_MANIFEST_HEADER, encoding="utf-8")

    def entries(self) -> list[str]:
        """The listed relative paths (a torn last line, from a kill during a write, is not
        trusted)."""
        if not self.path.is_file():
            return []
        text = self.path.read_text(encoding="utf-8", errors="replace")
        lines = text.split("\n")[:-1]  # the last piece lacks its line end: torn or empty
        return [line for line in lines if line and not line.startswith("#")]

    def add(self, *paths: Path) -> None:
        """List ``paths`` (files inside the folder) before they are written."""
        new = []
        for path in paths:
            relative = path.relative_to(self.out).as_posix()
            if relative not in self.listed:
                self.listed.add(relative)
                new.append(relative)
        if new:
            with self.path.open("a", encoding="utf-8") as handle:
                handle.write("".join(f"{r}\n" for r in new))
                handle.flush()
                os.fsync(handle.fileno())

    def delete_listed(self) -> int:
        """Delete the listed files that are regular files inside the folder (never a link, never
        anything outside it), then the folders they leave empty; empty the list. Returns the
        number of files deleted."""
        root = self.out.resolve()
        deleted = 0
        folders: set[Path] = set()
        for relative in self.entries():
            path = self.out / relative
            try:
                real = path.resolve()
            except OSError:
                continue
            if not real.is_relative_to(root) or real == root or path.is_symlink():
                continue
            # The file, and temporary files of it left by a kill during a write
            # (fpg_gym.outputs.atomic_path names them ".NAME.PID.HEX.tmp").
            leftovers = [p for p in real.parent.glob(f".{real.name}.*.tmp") if p.is_file()]
            for leftover in leftovers:
                leftover.unlink()
            if real.is_file() or leftovers:
                if real.is_file():
                    real.unlink()
                deleted += 1
                parent = real.parent
                while parent != root and parent.is_relative_to(root):
                    folders.add(parent)
                    parent = parent.parent
        for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):
            try:
                folder.rmdir()  # only when empty
            except OSError:
                pass
        self.path.write_text(_MANIFEST_HEADER, encoding="utf-8")
        self.listed = set()
        return deleted


def _is_legacy_compare_folder(out: Path) -> bool:
    """A folder written by an fpg-gym compare of before the manifest (config.json with a
    resume key beside results.csv)."""
    try:
        config = json.loads((out / "config.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(config, dict) and "resume_key" in config and (out / "results.csv").is_file()


def _claim_folder(out: Path, fresh: bool, say: Callable[[str], None]) -> _Manifest:
    """The output folder's manifest, after checking that compare may write (and with
    ``fresh``, delete) there.

    Raises
    ------
    OutputError
        ``out`` is a file, or a folder holding files compare did not write (no manifest),
        or ``fresh`` is asked for a folder of an earlier fpg-gym without a manifest.
    """
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out}: is a file; expected a folder")
    if out.is_dir() and not (out / MANIFEST_NAME).is_file() and any(out.iterdir()):
        if not _is_legacy_compare_folder(out):
            raise OutputError(
                f"--out {out}: the folder holds files that fpg-gym compare did not write (no "
                f"{MANIFEST_NAME}); compare writes only into a new or empty folder, or one it "
                "created: choose another --out"
            )
        if fresh:
            raise OutputError(
                f"--out {out}: --fresh deletes only files listed in {MANIFEST_NAME}, and this "
                "folder (from an earlier fpg-gym) has none; delete what you no longer need "
                "yourself, or choose another --out"
            )
        say(f"{out}: results of an earlier fpg-gym compare; resuming, and listing new files")
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError(f"--out {out}: the folder is not writable")
    manifest = _Manifest(out)
    if fresh:
        count = manifest.delete_listed()
        if count:
            say(f"--fresh: deleted {count} file(s) an earlier compare wrote in {out}")
    return manifest


def _format_value(value: Any) -> Any:
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return value


class _ResultsWriter:
    """Appends rows to ``results.csv`` (header first) and flushes each one."""

    def __init__(self, path: Path) -> None:
        new = not path.is_file() or path.stat().st_size == 0
        self.handle = path.open("a", newline="")
        self.writer = csv.DictWriter(
            self.handle, fieldnames=list(CSV_FIELDS), extrasaction="ignore"
        )
        if new:
            self.writer.writeheader()
            self.handle.flush()

    def write(self, row: dict[str, Any]) -> None:
        self.writer.writerow({k: _format_value(row.get(k, "")) for k in CSV_FIELDS})
        self.handle.flush()
        os.fsync(self.handle.fileno())

    def close(self) -> None:
        self.handle.close()


def _frames_path(out: Path, episode: str, method: str) -> Path:
    return out / "frames" / _safe(episode) / f"{_safe(method)}.npz"


def _save_frames(path: Path, arrays: dict[str, np.ndarray]) -> None:
    save_npz(path, arrays)  # temporary file beside it, then renamed


def _load_frames(path: Path, keys: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """The arrays of a per-frame file (only ``keys`` when given)."""
    with np.load(path, allow_pickle=False) as archive:
        return {key: archive[key] for key in archive.files if keys is None or key in keys}


#: The per-frame arrays the report reads (the poses are not among them).
_REPORT_KEYS = (
    "errors",
    "per_joint_error",
    "per_joint_root_error",
    "ms",
    "stage_names",
    "stage_ms",
)


class _FrameFiles:
    """The per-frame files of a compare folder as the report reads them: each file once."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self._loaded: dict[tuple[str, str], dict[str, np.ndarray] | None] = {}

    def get(self, episode: str, method: str) -> dict[str, np.ndarray] | None:
        """The report's arrays of one task (:data:`_REPORT_KEYS`), None without its file."""
        key = (episode, method)
        if key not in self._loaded:
            path = _frames_path(self.out, episode, method)
            self._loaded[key] = _load_frames(path, _REPORT_KEYS) if path.is_file() else None
        return self._loaded[key]


# --------------------------------------------------------------------------- the run


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
    from optimizers import make

    for name in methods:
        method = parse_method(name)
        if method.optimizer is not None:
            make(method.optimizer)


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


#: Files :func:`write_report` may write at the top of a compare folder.
_REPORT_FILES: tuple[str, ...] = (
    "summary.json",
    "report.md",
    "error_histogram.png",
    "cumulative.png",
    "error_over_time.png",
    "frame_times.png",
)


def _read_config(path: Path) -> dict[str, Any] | None:
    """The ``config.json`` of an earlier run (None when absent or unreadable)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _stale_episodes(
    out: Path, episodes: Sequence[EpisodeSpec], previous_config: dict[str, Any] | None
) -> set[str]:
    """Ids of the planned episodes whose files in ``out`` cannot be trusted: an earlier run
    wrote the id with another content key (or none). Their rows are dropped
    (:func:`_repair_results`), their recordings rewritten (:func:`_write_episodes`) and their
    tasks run again (which rewrites their per-frame files)."""
    previous: dict[str, str] = {}
    if previous_config is not None:
        for entry in previous_config.get("episodes", []):
            if isinstance(entry, dict) and isinstance(entry.get("id"), str):
                previous[entry["id"]] = str(entry.get("key", ""))
    rows = {r.get("episode") for r in _read_rows(out / "results.csv")}
    stale: set[str] = set()
    for episode in episodes:
        episode_file = out / "episodes" / f"{episode.id}.npz"
        frames_folder = out / "frames" / _safe(episode.id)
        exists = episode_file.exists() or frames_folder.exists() or episode.id in rows
        if exists and previous.get(episode.id) != episode.key:
            stale.add(episode.id)
    return stale


def _run_task(
    runner: MethodRunner, task: _Task, load: Callable[[str], Any]
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """:func:`_execute` with its failure named: a :class:`~fpg_gym.errors.TaskError` says which
    episode and method failed, and why."""
    try:
        return _execute(runner, task, load(task.recording_path))
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as error:
        raise TaskError(
            f"episode {task.episode.id!r} ({task.recording_path}), method {task.method!r} "
            f"failed: {type(error).__name__}: {' '.join(str(error).split())}"
        ) from error


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
    from tqdm.auto import tqdm

    say = log or (lambda text: print(text, file=sys.stderr))
    started = time.perf_counter()
    out = Path(config.out)
    _check_optimizers(config.methods)
    manifest = _claim_folder(out, fresh, say)
    config_path = out / "config.json"
    results_path = out / "results.csv"
    previous_config = _read_config(config_path)
    if not fresh and results_path.is_file() and previous_config is not None:
        previous = previous_config.get("resume_key")
        if previous != config.resume_key():
            raise ValueError(
                f"{out} holds results of a run with other settings ({previous}); use another "
                "--out or --fresh"
            )

    episodes, by_name, embedded, clip_names = _plan(config, progress, say)
    stale = _stale_episodes(out, episodes, previous_config)
    if stale:
        say(
            f"resuming: {len(stale)} episode(s) changed since the last run (another input under "
            f"the same name, or no content key): recomputed ({', '.join(sorted(stale)[:3])}"
            + (" ...)" if len(stale) > 3 else ")")
        )
    manifest.add(results_path, config_path)
    _repair_results(results_path, say, drop_episodes=stale)
    recorded = _write_episodes(
        config, episodes, by_name, out / "episodes", progress, manifest, rewrite=stale
    )
    from fpg_gym.io import DEFAULT_CLIP_NAMES

    embedded = sorted({*embedded, *(n for n in recorded if n in DEFAULT_CLIP_NAMES)})
    exclude = embedded if config.graph == "default" else []
    graph = load_graph(config.graph, exclude=exclude)
    warning = _held_out_warning(graph, episodes, [*recorded, *clip_names])
    if warning:
        say(f"warning: {warning}")
    write_text(
        config_path,
        json.dumps(
            {
                "config": asdict(config),
                "resume_key": config.resume_key(),
                "graph_exclude": exclude,
                "graph_summary": repr(graph),
                "held_out_warning": warning,
                "episodes": [asdict(e) for e in episodes],
            },
            indent=2,
        ),
    )

    done = {
        (r["episode"], r["method"])
        for r in _read_rows(results_path)
        if r.get("interrupted") in ("0", "")
        and _frames_path(out, r["episode"], r["method"]).is_file()
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
    options = config.reconstructor_options()
    writer = _ResultsWriter(results_path)
    bar = tqdm(total=len(tasks), desc="compare", unit="run", disable=not progress)
    interrupted = False
    completed = [0]

    def finish(row: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        frames_path = _frames_path(out, row["episode"], row["method"])
        manifest.add(frames_path)
        _save_frames(frames_path, arrays)
        writer.write(row)
        completed[0] += 1
        error = row.get("mean_error_m")
        bar.set_postfix_str(
            f"{row['method']} {error:.3f} m" if isinstance(error, float) else row["method"],
            refresh=False,
        )
        bar.update(1)

    workers = max(1, min(int(config.workers), len(tasks)))
    try:
        if workers <= 1:
            from fpg_gym.io.recording import load_recording

            with MethodRunner(graph, budget=config.budget, reconstructor_options=options) as runner:
                for task in tasks:
                    finish(*_run_task(runner, task, load_recording))
        else:
            interrupted = _run_pool(tasks, workers, config, exclude, options, finish)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
        writer.close()
    if interrupted:
        say("interrupted: finished results are kept; writing the report from them")
    manifest.add(*(out / name for name in _REPORT_FILES))
    summary = write_report(out, plots=plots, baseline=config.baseline, interrupted=interrupted)
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


def _run_pool(
    tasks: Sequence[_Task],
    workers: int,
    config: CompareConfig,
    exclude: list[str],
    options: dict[str, Any],
    finish: Callable[[dict[str, Any], dict[str, np.ndarray]], None],
) -> bool:
    """Run ``tasks`` in ``workers`` spawned processes; True when interrupted by Ctrl-C."""
    import multiprocessing

    # The per-frame matrices are tiny: one BLAS thread per worker avoids oversubscription.
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    executor = ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(config.graph, list(exclude), config.budget, options, os.getpid()),
    )
    pending: dict[Future[Any], _Task] = {}
    try:
        queue = list(tasks)
        # Keep a few tasks queued per worker so that Ctrl-C leaves little to cancel.
        while queue or pending:
            while queue and len(pending) < 2 * workers:
                task = queue.pop(0)
                pending[executor.submit(_worker_task, task)] = task
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                task = pending.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool:
                    raise TaskError(
                        f"a worker process died (killed, or out of memory) while running "
                        f"episode {task.episode.id!r}, method {task.method!r} or a task beside "
                        "it; finished results are kept, rerun to resume"
                    ) from None
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


# --------------------------------------------------------------------------- aggregation


def _num(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _max_column(rows: Sequence[dict[str, str]], column: str) -> float | None:
    """Largest finite value of a CSV column (None without one; older files lack the column)."""
    values = np.array([_num(r.get(column)) for r in rows])
    values = values[np.isfinite(values)]
    return float(values.max()) if values.size else None


def _paired_test(rows: dict[str, dict[str, float]], method: str, baseline: str) -> dict[str, Any]:
    """Wilcoxon signed-rank test of per-episode mean errors, ``method`` vs ``baseline``."""
    from scipy.stats import wilcoxon

    mine, base = rows.get(method, {}), rows.get(baseline, {})
    common = sorted(
        e for e in set(mine) & set(base) if math.isfinite(mine[e]) and math.isfinite(base[e])
    )
    result: dict[str, Any] = {
        "paired_episodes": len(common),
        "mean_difference_m": None,
        "lower_error_episodes": None,
        "wilcoxon_p": None,
        "note": "",
    }
    if not common:
        result["note"] = "no paired episodes"
        return result
    x = np.array([mine[e] for e in common])
    y = np.array([base[e] for e in common])
    diff = x - y
    result["mean_difference_m"] = float(diff.mean())
    result["lower_error_episodes"] = int(np.sum(diff < 0))
    if method == baseline:
        result["note"] = "baseline"
        return result
    nonzero = diff[diff != 0]
    if len(nonzero) < 2:
        result["note"] = "too few episodes that differ"
        return result
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            test = wilcoxon(x, y, zero_method="wilcox", alternative="two-sided")
        except ValueError as error:  # e.g. every difference zero
            result["note"] = str(error)
            return result
    result["wilcoxon_p"] = float(test.pvalue)
    if len(nonzero) < 6:
        result["note"] = f"only {len(nonzero)} differing episodes: p cannot fall below 0.05"
    return result


def summarise(out: str | Path, baseline: str = BASELINE.name) -> dict[str, Any]:
    """Aggregate ``results.csv`` and the per-frame files of a compare folder.

    Rows of interrupted tasks are left out. Returns the structure written to ``summary.json``.
    """
    out = Path(out)
    return _summarise(out, baseline, _FrameFiles(out))


def _summarise(out: Path, baseline: str, files: _FrameFiles) -> dict[str, Any]:
    rows = [r for r in _read_rows(out / "results.csv") if r.get("interrupted") in ("0", "")]
    latest: dict[tuple[str, str], dict[str, str]] = {}
    for row in rows:  # a task rerun after an interruption: the last row counts
        latest[(row["episode"], row["method"])] = row
    rows = list(latest.values())
    config: dict[str, Any] = {}
    if (out / "config.json").is_file():
        config = json.loads((out / "config.json").read_text())
    order = list(config.get("config", {}).get("methods", []))
    for row in rows:
        if row["method"] not in order:
            order.append(row["method"])
    methods = [m for m in order if any(r["method"] == m for r in rows)]
    episodes = sorted({r["episode"] for r in rows})
    if baseline not in methods and methods:
        fallback = next((m for m in methods if m.startswith("fpg:local-search")), methods[0])
        baseline = fallback
    per_episode_error: dict[str, dict[str, float]] = {}
    result: dict[str, Any] = {}
    for method in methods:
        mine = [r for r in rows if r["method"] == method]
        errors, ms, joints, root_joints = [], [], [], []
        stage_sums: dict[str, list[np.ndarray]] = {}
        for r in mine:
            frames = files.get(r["episode"], method)
            if frames is None:
                continue
            if "errors" in frames:
                errors.append(frames["errors"])
                joints.append((frames["per_joint_error"], len(frames["errors"])))
                if "per_joint_root_error" in frames:
                    root_joints.append((frames["per_joint_root_error"], len(frames["errors"])))
            ms.append(frames["ms"])
            for i, stage in enumerate(frames["stage_names"]):
                stage_sums.setdefault(str(stage), []).append(frames["stage_ms"][:, i])
        per_episode_error[method] = {r["episode"]: _num(r["mean_error_m"]) for r in mine}
        episode_err02 = np.array([_num(r["err02_pct"]) for r in mine])
        episode_err02 = episode_err02[np.isfinite(episode_err02)]
        all_errors = np.concatenate(errors) if errors else np.zeros(0)
        all_ms = np.concatenate(ms) if ms else np.zeros(0)
        weights = np.array([_num(r["frames"]) for r in mine])

        def weighted(
            column: str, rows_: list[dict[str, str]] = mine, w: np.ndarray = weights
        ) -> Any:
            values = np.array([_num(r[column]) for r in rows_])
            use = np.isfinite(values) & (w > 0)
            return float(np.average(values[use], weights=w[use])) if use.any() else None

        entry: dict[str, Any] = {
            "episodes": len(mine),
            "frames": int(np.nansum(weights)),
            "mean_error_m": float(all_errors.mean()) if all_errors.size else None,
            "std_error_m": float(all_errors.std()) if all_errors.size else None,
            "median_error_m": float(np.median(all_errors)) if all_errors.size else None,
            "err02_pct": (
                {
                    "min": float(episode_err02.min()),
                    "mean": float(episode_err02.mean()),
                    "max": float(episode_err02.max()),
                    "pooled": 100.0 * metrics.err_ratio(all_errors),
                }
                if episode_err02.size and all_errors.size
                else None
            ),
            "band_shares": (metrics.band_shares(all_errors).tolist() if all_errors.size else None),
            "bone_length_spread_mm": weighted("bone_length_spread_mm"),
            "jitter_ms2": weighted("jitter_ms2"),
            "lag_frames": weighted("lag_frames"),
            "lag_ms": weighted("lag_ms"),
            "settled_bone_spread_mm": _max_column(mine, "settled_bone_spread_mm"),
            "ms_per_frame": metrics.time_summary(all_ms) if all_ms.size else None,
            "stage_ms_median": {
                s: float(np.median(np.concatenate(v))) for s, v in stage_sums.items()
            },
            "evaluations_per_frame": weighted("evaluations_mean"),
            "mean_energy": weighted("energy_mean"),
            "per_joint_error_m": (
                dict(
                    zip(
                        skeleton.JOINT_NAMES,
                        (
                            np.sum([j * n for j, n in joints], axis=0) / sum(n for _, n in joints)
                        ).tolist(),
                        strict=True,
                    )
                )
                if joints
                else None
            ),
            "per_joint_root_error_m": (
                dict(
                    zip(
                        skeleton.JOINT_NAMES,
                        (
                            np.sum([j * n for j, n in root_joints], axis=0)
                            / sum(n for _, n in root_joints)
                        ).tolist(),
                        strict=True,
                    )
                )
                if root_joints
                else None
            ),
            "per_scenario_mean_error_m": {},
        }
        for scenario in sorted({r["scenario"] for r in mine}):
            subset = [r for r in mine if r["scenario"] == scenario]
            entry["per_scenario_mean_error_m"][scenario or "(recording)"] = weighted(
                "mean_error_m", subset, np.array([_num(r["frames"]) for r in subset])
            )
        result[method] = entry
    for method in methods:
        result[method]["vs_baseline"] = _paired_test(per_episode_error, method, baseline)
    truth_rows = [r for r in rows if r["method"] == (methods[0] if methods else "")]
    truth_jitter = np.array([_num(r["truth_jitter_ms2"]) for r in truth_rows])
    truth_jitter = truth_jitter[np.isfinite(truth_jitter)]
    input_error = np.array([_num(r["input_mean_error_m"]) for r in truth_rows])
    input_error = input_error[np.isfinite(input_error)]
    return {
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "baseline": baseline,
        "methods": result,
        "method_order": methods,
        "episodes": episodes,
        "scenarios": sorted({r["scenario"] for r in rows}),
        "clips": sorted({r["clip"] for r in rows}),
        "ground_truth_jitter_ms2": float(truth_jitter.mean()) if truth_jitter.size else None,
        "input_mean_error_m": float(input_error.mean()) if input_error.size else None,
        "config": config.get("config", {}),
        "graph": config.get("graph_summary", ""),
        "graph_exclude": config.get("graph_exclude", []),
        "held_out_warning": config.get("held_out_warning", ""),
    }


# --------------------------------------------------------------------------- report


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}f}"


def table_rows(summary: dict[str, Any]) -> list[list[str]]:
    """The main table's cells, one list per method (columns of :data:`TABLE_COLUMNS`)."""
    rows = []
    for name in summary["method_order"]:
        m = summary["methods"][name]
        error = (
            f"{m['mean_error_m']:.3f} ± {m['std_error_m']:.3f}"
            if m["mean_error_m"] is not None
            else "–"
        )
        err = m["err02_pct"]
        err_text = f"{err['min']:.1f} / {err['mean']:.1f} / {err['max']:.1f}" if err else "–"
        ms = m["ms_per_frame"]
        ms_text = f"{ms['median']:.2f} / {ms['p95']:.2f}" if ms else "–"
        label = f"**{name}**" if name == summary["baseline"] else name
        rows.append(
            [
                label,
                str(m["episodes"]),
                error,
                err_text,
                _fmt(m["bone_length_spread_mm"], 1),
                _fmt(m["jitter_ms2"], 1),
                _fmt(m.get("lag_frames"), 2),
                _fmt(m.get("settled_bone_spread_mm"), 1),
                ms_text,
                _fmt(m["evaluations_per_frame"], 0),
                _fmt(m["mean_energy"], 4),
            ]
        )
    return rows


def markdown_table(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A markdown table: a header row of ``columns``, a ``---`` row, then ``rows`` (cells as
    given)."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join(" --- " for _ in columns) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def format_table(summary: dict[str, Any]) -> str:
    """The main table (markdown) of a summary (:func:`summarise`)."""
    return markdown_table(TABLE_COLUMNS, table_rows(summary))


def format_tests(summary: dict[str, Any]) -> str:
    """The paired-test table (markdown): each method against the baseline."""
    rows = []
    for name in summary["method_order"]:
        test = summary["methods"][name]["vs_baseline"]
        if name == summary["baseline"]:
            continue
        n = test["paired_episodes"]
        p = test["wilcoxon_p"]
        p_text = f"{p:.3g}" if p is not None else "–"
        if test["note"]:
            p_text += f" ({test['note']})"
        rows.append(
            [
                name,
                str(n),
                (
                    f"{test['mean_difference_m']:+.4f}"
                    if test["mean_difference_m"] is not None
                    else "–"
                ),
                f"{test['lower_error_episodes']} of {n}" if n else "–",
                p_text,
            ]
        )
    return markdown_table(TEST_COLUMNS, rows)


def format_scenarios(summary: dict[str, Any]) -> str:
    """Mean error per scenario (rows) and method (columns), markdown."""
    methods = summary["method_order"]
    scenarios = sorted(
        {s for m in methods for s in summary["methods"][m]["per_scenario_mean_error_m"]}
    )
    rows = [
        [s] + [_fmt(summary["methods"][m]["per_scenario_mean_error_m"].get(s)) for m in methods]
        for s in scenarios
    ]
    return markdown_table(["scenario", *methods], rows)


def format_joints(summary: dict[str, Any], limit: int = 8) -> str:
    """Markdown table of the root-relative error per joint (cm), one column per method (the
    first ``limit`` methods); empty when no method has ground truth."""
    methods = [
        m for m in summary["method_order"] if summary["methods"][m].get("per_joint_root_error_m")
    ][:limit]
    if not methods:
        return ""
    rows = []
    for joint in skeleton.JOINT_NAMES[1:]:
        cells = []
        for m in methods:
            value = summary["methods"][m]["per_joint_root_error_m"][joint]
            bone = (summary["methods"][m].get("per_joint_error_m") or {}).get(joint)
            cells.append(f"{100 * value:.1f}" + (f" ({100 * bone:.1f})" if bone else ""))
        rows.append([joint, *cells])
    return markdown_table(["joint", *methods], rows)


def _plot_methods(summary: dict[str, Any], limit: int = 6) -> list[str]:
    """Methods for the per-episode time plot: raw, the baseline, then the most accurate."""
    methods = summary["method_order"]
    if len(methods) <= limit:
        return list(methods)
    chosen = [m for m in ("raw", summary["baseline"]) if m in methods]
    ranked = sorted(
        (
            m
            for m in methods
            if m not in chosen and summary["methods"][m]["mean_error_m"] is not None
        ),
        key=lambda m: summary["methods"][m]["mean_error_m"],
    )
    chosen += ranked[: limit - len(chosen)]
    return [m for m in methods if m in chosen]


def _write_plots(out: Path, summary: dict[str, Any], files: _FrameFiles) -> dict[str, str]:
    from fpg_gym import plots

    methods = summary["method_order"]
    errors: dict[str, np.ndarray] = {}
    ms: dict[str, np.ndarray] = {}
    for method in methods:
        e, t = [], []
        for episode in summary["episodes"]:
            frames = files.get(episode, method)
            if frames is not None:
                if "errors" in frames:
                    e.append(frames["errors"])
                t.append(frames["ms"])
        if e:
            errors[method] = np.concatenate(e)
        if t:
            ms[method] = np.concatenate(t)
    written: dict[str, str] = {}
    colours = plots.method_colours(methods)
    if errors:
        written["error_histogram"] = plots.plot_error_histogram(
            errors, out / "error_histogram.png", colours=colours
        ).name
        written["cumulative"] = plots.plot_cumulative(
            errors, out / "cumulative.png", colours=colours
        ).name
        chosen = _plot_methods(summary)
        episode, series = _time_plot_series(summary, chosen, files)
        if episode:
            written["error_over_time"] = plots.plot_error_over_time(
                series,
                out / "error_over_time.png",
                title=f"Per-frame error, episode {episode}",
                colours=colours,
            ).name
            summary["time_plot_episode"] = episode
    if ms:
        written["frame_times"] = plots.plot_frame_times(
            ms, out / "frame_times.png", colours=colours
        ).name
    return written


def _time_plot_series(
    summary: dict[str, Any], methods: Sequence[str], files: _FrameFiles
) -> tuple[str, dict[str, np.ndarray]]:
    """The first episode that every plotted method finished with ground truth, and the methods'
    per-frame errors on it (``""`` and nothing when there is none)."""
    for episode in summary["episodes"]:
        series: dict[str, np.ndarray] = {}
        for method in methods:
            frames = files.get(episode, method)
            if frames is None or "errors" not in frames:
                break
            series[method] = frames["errors"]
        else:
            return str(episode), series
    return "", {}


def write_report(
    out: str | Path,
    *,
    plots: bool = True,
    baseline: str = BASELINE.name,
    interrupted: bool = False,
) -> dict[str, Any]:
    """Write ``summary.json``, ``report.md`` and the plots of a compare folder from its files.

    Works on a partial run (only finished rows count; ``interrupted`` says so in the report).
    Returns the summary.
    """
    out = Path(out)
    files = _FrameFiles(out)
    summary = _summarise(out, baseline, files)
    summary["interrupted"] = bool(interrupted)
    summary["plots"] = (
        _write_plots(out, summary, files) if plots and summary["method_order"] else {}
    )
    write_text(out / "summary.json", json.dumps(jsonable(summary), indent=2))
    write_text(out / "report.md", report_markdown(summary))
    return summary


def report_markdown(summary: dict[str, Any]) -> str:
    """The text of ``report.md``."""
    config = summary.get("config", {})
    lines = [
        "# fpg-gym compare",
        "",
        f"Generated {summary['generated']} (fpg-gym "
        f"{__import__('fpg_gym').__version__}). Graph: `{config.get('graph', '?')}` "
        f"{summary.get('graph', '')}"
        + (
            f", built without the evaluated embedded clips {', '.join(summary['graph_exclude'])}"
            if summary.get("graph_exclude")
            else ""
        )
        + ".",
        "",
        f"{len(summary['episodes'])} episodes: clips {', '.join(summary['clips'])}; scenarios "
        f"{', '.join(s or '(recording)' for s in summary['scenarios'])}; seeds "
        f"{', '.join(str(s) for s in config.get('seeds', []))}"
        + (f"; at most {config['max_frames']} frames each" if config.get("max_frames") else "")
        + f". Budget {config.get('budget', '?')} evaluations per frame, K = "
        f"{config.get('k', '?')}; {config.get('workers', 1)} worker process(es).",
        "",
    ]
    if summary.get("held_out_warning"):
        lines += [f"**Warning:** {summary['held_out_warning']}.", ""]
    if summary.get("interrupted"):
        lines += ["**Interrupted:** the tables cover the finished runs only.", ""]
    if not summary["method_order"]:
        lines += ["No finished runs.", ""]
        return "\n".join(lines)
    truth_jitter = summary.get("ground_truth_jitter_ms2")
    lines += [
        "## Results",
        "",
        format_table(summary),
        "",
        "Mean error: FPG Eq. 13 (mean over the 19 bones of the bone-vector error) over all "
        "frames, ± its standard deviation over frames. Err0.2: share of frames with error "
        "≥ 0.2 m, min / mean / max over episodes. Bone-length spread: standard deviation of "
        "each bone's length over an episode, mean over bones and episodes. Jitter: mean "
        "acceleration magnitude over joints and frames"
        + (f" (ground truth: {truth_jitter:.1f} m/s²)" if truth_jitter is not None else "")
        + ". Lag: the shift (frames) that best aligns the output with the ground truth "
        "(`fpg_gym.metrics.lag`), mean over episodes; positive is late. Bone spread after 1 s: "
        "the largest range (max − min) of a bone's length after the first second of an episode "
        "(`fpg_gym.metrics.settled_bone_spread`), max over bones and episodes. ms/frame: "
        "computation time of one frame on this machine, ragdoll included, "
        "median / 95th percentile (noisy when workers share cores). Evaluations and energy "
        f"(Shum Eq. 10, lower is better): reconstruction methods only. Bold: the baseline "
        f"`{summary['baseline']}`.",
        "",
        f"## Paired test against `{summary['baseline']}`",
        "",
        format_tests(summary),
        "",
        "Per-episode mean errors, paired by episode; two-sided Wilcoxon signed-rank test "
        "(`scipy.stats.wilcoxon`, zero differences dropped). A negative difference means "
        "lower error than the baseline.",
        "",
        "## Mean error (m) per scenario",
        "",
        format_scenarios(summary),
        "",
    ]
    joints = format_joints(summary)
    if joints:
        lines += [
            "## Error per joint (cm)",
            "",
            joints,
            "",
            "Root-relative error: distance of each joint to the ground truth once both have "
            "their HipCenter at the origin, mean over frames; in brackets the FPG Eq. 13 "
            "summand (the error of the bone that ends at the joint).",
            "",
        ]
    plots = summary.get("plots", {})
    if plots:
        lines += ["## Plots", ""]
        captions = {
            "error_histogram": "Share of frames per error band (FPG §8)",
            "cumulative": "Frames with error above a threshold (FPG Fig. 7)",
            "error_over_time": f"Per-frame error over episode {summary.get('time_plot_episode')}",
            "frame_times": "Computation time per frame",
        }
        for key, name in plots.items():
            lines += [f"![{captions.get(key, key)}]({name})", ""]
    lines += ["## Episodes", "", ", ".join(f"`{e}`" for e in summary["episodes"]), ""]
    return "\n".join(lines)
