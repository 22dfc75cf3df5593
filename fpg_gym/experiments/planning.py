"""Planning a comparison's episodes: clips x scenarios x seeds, keyed by content, and the
simulated recordings written once.

The clip episodes and their simulator seeds come from the one episode planner,
:func:`fpg_gym.simulate.plan_episodes` (its seeding rule is documented there); this module adds
episode ids, recording files and content keys.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from fpg_gym.core.outputs import same_file
from fpg_gym.experiments.config import CompareConfig, EpisodeSpec, safe_name
from fpg_gym.experiments.store import Manifest
from fpg_gym.io import read_recording, resolve_clips, write_recording
from fpg_gym.io.files import file_digest
from fpg_gym.simulate import EpisodeSimulator, episode_seed, get_scenario
from fpg_gym.simulate import plan_episodes as plan_simulated


def plan_episodes(
    clip_names: Sequence[str],
    scenarios: Sequence[str],
    seeds: Sequence[int],
    recordings: Sequence[str] = (),
    recording_hashes: Sequence[str] = (),
) -> list[EpisodeSpec]:
    """Every clip x scenario x seed, then every recording x seed (ids made unique).

    The clip episodes and their ``sim_seed`` are :func:`fpg_gym.simulate.plan_episodes`'s;
    a recording's ``sim_seed`` (the optimisers' seed) is ``episode_seed(seed, stem)``.

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
        for planned in plan_simulated(clip_names, scenarios, [seed]):
            episodes.append(
                EpisodeSpec(
                    id=unique(safe_name(f"{planned.clip}__{planned.scenario}__s{seed}")),
                    clip=planned.clip,
                    scenario=planned.scenario,
                    seed=planned.seed,
                    sim_seed=planned.sim_seed,
                )
            )
        for path, stem in zip(recordings, stems, strict=True):
            episodes.append(
                EpisodeSpec(
                    id=unique(safe_name(f"{stem}__s{seed}")),
                    clip=stem,
                    scenario="",
                    seed=int(seed),
                    sim_seed=episode_seed(seed, stem),
                    recording=str(path),
                )
            )
    return episodes


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
        variants = groups.setdefault(clip.name, {})
        digest = _clip_hash(clip)
        if digest in variants:
            say(f"note: clip {clip.name!r} given more than once ({clip.source}); counted once")
        variants.setdefault(digest, clip)
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


def _unique_inputs(
    inputs: Sequence[str], say: Callable[[str], None]
) -> tuple[list[str], list[str]]:
    """The ``--inputs`` with their content hashes, each content once: a file given twice (or
    two copies of one recording) would count one episode twice in every mean and paired test.

    Raises
    ------
    FileNotFoundError, DataFormatError
        An input is missing or not a readable file (named with ``--inputs``).
    """
    kept: list[str] = []
    digests: list[str] = []
    first: dict[str, str] = {}
    for name in inputs:
        try:
            digest = file_digest(name)
        except FileNotFoundError:
            raise FileNotFoundError(f"--inputs: {name}: no such file") from None
        if digest in first:
            same = (
                "given twice" if same_file(name, first[digest]) else f"the same as {first[digest]}"
            )
            say(f"note: --inputs {name}: {same}; counted once")
            continue
        first[digest] = name
        kept.append(name)
        digests.append(digest)
    return kept, digests


def plan_keyed_episodes(
    config: CompareConfig, progress: bool, say: Callable[[str], None]
) -> tuple[list[EpisodeSpec], dict[str, Any], list[str], list[str]]:
    """Plan the episodes with their content keys (reading the clips; nothing is written).

    Returns the episodes, the clips by (unique) name, the embedded clips to leave out of the
    default graph, and the original names of the clips (for the held-out warning).
    """

    for scenario in config.scenarios:
        get_scenario(scenario)  # unknown names fail here, before any work
    inputs, recording_hashes = _unique_inputs(config.inputs, say)
    clips, embedded = (
        resolve_clips(config.clips, config.units, progress=progress) if config.clips else ([], [])
    )
    by_name = _unique_clip_names(clips, say)
    hashes = {name: _clip_hash(clip) for name, clip in by_name.items()}
    planned = plan_episodes(list(by_name), config.scenarios, config.seeds, inputs, recording_hashes)
    # The format an input is read with is part of its content.
    by_path = {
        path: f"{digest}:{config.input_format or 'guessed'}"
        for path, digest in zip(inputs, recording_hashes, strict=True)
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


def write_episodes(
    config: CompareConfig,
    episodes: Sequence[EpisodeSpec],
    by_name: dict[str, Any],
    folder: Path,
    progress: bool,
    manifest: Manifest,
    rewrite: set[str] | frozenset[str] = frozenset(),
) -> list[str]:
    """Write the episodes' recordings, reusing the ones already there except the ``rewrite``
    (stale) ones. Returns the embedded clips the recording files (``--inputs``) were simulated
    from."""

    folder.mkdir(parents=True, exist_ok=True)
    simulator = EpisodeSimulator()
    bar = tqdm(episodes, desc="episodes", unit="episode", disable=not progress, leave=False)
    try:
        for episode in bar:
            target = folder / f"{episode.id}.npz"
            if target.is_file() and episode.id not in rewrite:
                continue
            if episode.recording:
                recording = read_recording(episode.recording, format=config.input_format)
            else:
                recording = simulator.simulate(by_name[episode.clip], episode.planned)
            recording = recording.head(config.max_frames)
            manifest.add(target)
            write_recording(target, recording)  # atomic: temporary file, then rename
    finally:
        bar.close()
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
