"""Resuming a comparison's folder (:func:`resume_folder`): what an earlier run left there is kept
only when it is still right. Another configuration is refused; the rows of episodes whose content
changed, of ``learned:MODEL`` methods whose model changed and of tasks whose per-frame file is
missing or damaged are dropped, so that they run again; rows of other episodes or methods are
kept and counted apart.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from fpg_gym.core.errors import FpgGymError, OutputError
from fpg_gym.experiments.config import CompareConfig, EpisodeSpec, safe_name
from fpg_gym.experiments.planning import plan_keyed_episodes, write_episodes
from fpg_gym.experiments.store import (
    Manifest,
    frames_intact,
    frames_path,
    read_config,
    read_rows,
    repair_results,
)
from fpg_gym.io import DEFAULT_CLIP_NAMES
from fpg_gym.io.recording import load_recording

__all__ = ["resume_folder"]


def _stale_episodes(
    out: Path, episodes: Sequence[EpisodeSpec], previous_config: dict[str, Any] | None
) -> set[str]:
    """Ids of the planned episodes whose files in ``out`` cannot be trusted: an earlier run
    wrote the id with another content key (or none). Their rows are dropped
    (:func:`repair_results`), their recordings rewritten (:func:`write_episodes`) and their
    tasks run again (which rewrites their per-frame files)."""
    previous: dict[str, str] = {}
    entries = previous_config.get("episodes") if previous_config is not None else None
    if isinstance(entries, list):
        for entry in entries:
            if isinstance(entry, dict) and isinstance(entry.get("id"), str):
                previous[entry["id"]] = str(entry.get("key", ""))
    rows = {r.get("episode") for r in read_rows(out / "results.csv")}
    stale: set[str] = set()
    for episode in episodes:
        episode_file = out / "episodes" / f"{episode.id}.npz"
        frames_folder = out / "frames" / safe_name(episode.id)
        exists = episode_file.exists() or frames_folder.exists() or episode.id in rows
        if exists and (previous.get(episode.id) != episode.key or not _readable(episode_file)):
            stale.add(episode.id)
    return stale


def _readable(episode_file: Path) -> bool:
    """Whether an episode's recording reads (a damaged one is written again)."""
    try:
        load_recording(episode_file)
    except (FpgGymError, OSError):
        return False
    return True


def _damaged_tasks(out: Path) -> set[tuple[str, str]]:
    """``(episode, method)`` of the rows of ``results.csv`` whose per-frame file is missing or
    damaged: their rows are dropped and their tasks run again."""
    return {
        (r["episode"], r["method"])
        for r in read_rows(out / "results.csv")
        if isinstance(r.get("episode"), str)
        and isinstance(r.get("method"), str)
        and not frames_intact(frames_path(out, r["episode"], r["method"]))
    }


def _resume_conflict(out: Path, previous: Any, current: dict[str, Any]) -> str:
    """The message refusing to resume a folder whose run had other settings (named)."""
    old = previous if isinstance(previous, dict) else {}
    changed = sorted(k for k in set(old) | set(current) if old.get(k) != current.get(k))
    names = ", ".join(
        f"{k} (its content changed)" if k == "graph" and old.get(k) and current.get(k) else k
        for k in changed
    )
    return (
        f"--out {out} holds results of a run with other settings ({names or 'unknown'}); use "
        "another --out, or --fresh to discard them"
    )


def _stale_methods(
    out: Path, method_keys: dict[str, str], previous_config: dict[str, Any] | None
) -> set[str]:
    """Methods of this run that read files (``learned:MODEL``) whose rows in ``out`` were
    computed from other file contents (or unknown ones): their rows are recomputed."""
    if not method_keys:
        return set()
    previous = previous_config.get("method_keys") if previous_config else None
    previous = previous if isinstance(previous, dict) else {}
    rows = {r.get("method") for r in read_rows(out / "results.csv")}
    return {m for m, key in method_keys.items() if m in rows and previous.get(m) != key}


def resume_folder(
    config: CompareConfig,
    out: Path,
    manifest: Manifest,
    fresh: bool,
    progress: bool,
    say: Callable[[str], None],
    method_keys: dict[str, str],
) -> tuple[list[EpisodeSpec], list[str], list[str], dict[str, Any]]:
    """Plan the episodes and bring the folder's earlier results up to date: another
    configuration is refused; the rows of changed episodes, of changed models and of damaged
    frame files are dropped (they run again); the episode files are written.

    Returns the episodes, the embedded clips they use, the names of their sources (recorded
    episodes and clips) and the configuration's resume key.
    """
    config_path = out / "config.json"
    results_path = out / "results.csv"
    previous_config = read_config(config_path)
    resume_key = config.resume_key()
    if not fresh and results_path.is_file() and previous_config is not None:
        previous = previous_config.get("resume_key")
        if previous != resume_key:
            raise OutputError(_resume_conflict(out, previous, resume_key))

    episodes, by_name, embedded, clip_names = plan_keyed_episodes(config, progress, say)
    stale = _stale_episodes(out, episodes, previous_config)
    if stale:
        say(
            f"resuming: {len(stale)} episode(s) changed since the last run (another input under "
            f"the same name, or no content key): recomputed ({', '.join(sorted(stale)[:3])}"
            + (" ...)" if len(stale) > 3 else ")")
        )
    stale_methods = _stale_methods(out, method_keys, previous_config)
    if stale_methods:
        say(
            f"resuming: the model of {', '.join(sorted(stale_methods))} changed since the last "
            "run (or its content is unknown): its rows are recomputed"
        )
    damaged = _damaged_tasks(out)
    if damaged:
        say(
            f"resuming: {len(damaged)} finished task(s) lack their per-frame file or have a "
            "damaged one: they run again"
        )
    manifest.add(results_path, config_path)
    repair_results(
        results_path, say, drop_episodes=stale, drop_methods=stale_methods, drop_tasks=damaged
    )
    _note_other_rows(results_path, config, episodes, say)
    recorded = write_episodes(
        config, episodes, by_name, out / "episodes", progress, manifest, rewrite=stale
    )

    embedded = sorted({*embedded, *(n for n in recorded if n in DEFAULT_CLIP_NAMES)})
    return episodes, embedded, [*recorded, *clip_names], resume_key


def _note_other_rows(
    results_path: Path,
    config: CompareConfig,
    episodes: Sequence[EpisodeSpec],
    say: Callable[[str], None],
) -> None:
    """Say when ``results.csv`` holds rows of methods or episodes outside this run (an earlier
    run into the same folder with other ``--methods`` or inputs): they are kept in the file
    and left out of this run's report."""
    planned_methods, planned_episodes = set(config.methods), {e.id for e in episodes}
    other = [
        r
        for r in read_rows(results_path)
        if r.get("method") not in planned_methods or r.get("episode") not in planned_episodes
    ]
    if other:
        methods = sorted({str(r.get("method")) for r in other} - planned_methods)
        say(
            f"note: {results_path} holds {len(other)} row(s) of earlier runs outside this one"
            + (f" (methods {', '.join(methods[:5])})" if methods else "")
            + "; they stay in the file and are left out of this report (--fresh discards them)"
        )
