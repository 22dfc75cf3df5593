"""Paired recordings to train a sampler on: sensor streams with their ground truth.

``fpg-gym train-sampler --kind linear --recordings PATH ...`` learns from real paired data (a
Kinect stream recorded with a mocap reference, such as ``fpg-gym import-uiprmd``'s repetitions)
instead of simulated streams of mocap clips. Recordings are grouped (by default each is its own
group; ``group_pattern``, a regular expression on the file name whose first group names the
group, puts a subject's recordings together): a seeded share of the groups is held out for the
final evaluation (none with ``val_share=0``: every group trains), and the cross-validation of
:func:`policies.pose_sampler.fit_linear` leaves whole groups out, so no setting is chosen on a
group its fit saw.

Cross-fitting (:func:`group_databases`): a held-out subject is reconstructed with a graph and a
sensor map that never saw it, so each training group's data is collected with a graph and a map
built the same way from the other training groups' recordings (their ground truth as the
graph's clips, their pairs for the map), not with ones that contain it.

Occlusions (:func:`with_occlusions`): real paired recordings are mostly of a visible body, and
a sampler and output correction fitted on them alone learn to follow the sensor where it fails.
Each training recording is also given once with an occlusion of
:mod:`fpg_gym.simulate.occlude` put in (the cases in turn, seeded), in its own group; the
graphs and maps are built from the recordings as they are.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.seeding import derive_seed
from fpg_gym.definitions import DefinitionMap
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import Clip, expand_inputs, read_recording
from fpg_gym.io.files import file_digest
from fpg_gym.simulate.occlude import check_occlusion_cases, occlude

__all__ = [
    "GroupDatabase",
    "PairedRecordings",
    "group_databases",
    "group_pattern",
    "paired_recordings",
    "recording_paths",
    "with_occlusions",
]


def recording_paths(items: Sequence[str | Path]) -> list[Path]:
    """The recording files of ``items``: files as given, folders read (recursively, sorted)
    for ``.npz`` files (:func:`fpg_gym.io.expand_inputs`).

    Raises
    ------
    FileNotFoundError
        An item that does not exist, or a folder without recordings.
    """
    return expand_inputs(items, lambda path: path.suffix == ".npz", "recordings (.npz)")


def group_pattern(pattern: str | None) -> re.Pattern[str] | None:
    """``pattern`` compiled, checked to have a group (None stays None).

    Raises
    ------
    ValueError
        Not a regular expression, or one without a group.
    """
    if pattern is None:
        return None
    try:
        compiled = re.compile(pattern)
    except re.error as error:
        raise ValueError(
            f"group_pattern: {pattern!r} is not a regular expression ({error})"
        ) from None
    if compiled.groups < 1:
        raise ValueError(
            f"group_pattern: {pattern!r} has no group; its first group names a recording's "
            "group, e.g. '_(s[0-9]+)_' for UI-PRMD's subjects"
        )
    return compiled


@dataclass
class PairedRecordings:
    """Recordings split into training and held-out groups.

    Attributes
    ----------
    train : list of (str, Recording)
        The training recordings with their group.
    validation : list of Recording
        Recordings of the held-out groups, spread over them (at most ``episodes``; none with
        ``val_share=0``).
    info : dict
        Files, groups and the split, for the model's ``training`` record.
    names : list of str
        The training recordings' names (file stems), in the order of ``train``.
    """

    train: list[tuple[str, Any]]
    validation: list[Any]
    info: dict[str, Any]
    names: list[str]


def paired_recordings(
    items: Sequence[str | Path],
    *,
    pattern: str | None = None,
    val_share: float = 0.2,
    episodes: int = 6,
    max_frames: int | None = None,
    seed: int = 0,
    log: Callable[[str], None] | None = None,
) -> PairedRecordings:
    """Read paired recordings and hold out a seeded share of their groups.

    Parameters
    ----------
    items : sequence of path
        Recording files or folders (:func:`recording_paths`), in any format
        :func:`fpg_gym.io.read_recording` reads that carries ground truth.
    pattern : str, optional
        Regular expression searched in each file name (without suffix); its first group is the
        recording's group. None: each recording is its own group (named by its file name, or
        by its path when files in two folders share a name).
    val_share : float
        Share of the groups held out (at least one, and at least two groups stay for the
        cross-validation; 0: none, every group trains).
    episodes : int
        Held-out recordings kept for the evaluation, spread over the held-out ones.
    max_frames : int, optional
        Keep the first frames of each recording.
    seed : int
        Seed of the held-out groups' draw.
    log : callable, optional
        Receives a note for each file whose content was already read (given twice, or a copy):
        it is read once.

    Raises
    ------
    DataFormatError
        A recording without ground truth.
    ValueError
        A file name the pattern does not match, fewer than 3 groups (2 with ``val_share=0``),
        or ``val_share`` outside [0, 1).
    """
    if not 0.0 <= val_share < 1.0:
        raise ValueError(f"val_share: expected a share in [0, 1), got {val_share}")
    compiled = group_pattern(pattern)
    say = log or (lambda _text: None)
    loaded: list[tuple[str, Path, Any]] = []
    paths = _distinct_recordings(items, say)
    stems = [path.stem for path in paths]
    for path in paths:
        recording = read_recording(path)
        if recording.ground_truth is None:
            raise DataFormatError(
                path,
                "no ground truth: a sampler learns from paired recordings (a sensor stream "
                "with its reference, e.g. fpg-gym import-uiprmd's repetitions)",
            )
        if compiled is None:  # its own group: named by its path where two share a name
            group = path.stem if stems.count(path.stem) == 1 else path.with_suffix("").as_posix()
        else:
            match = compiled.search(path.stem)
            if match is None or match.group(1) is None:
                raise ValueError(
                    f"{path}: group_pattern {compiled.pattern!r} does not match {path.stem!r}"
                )
            group = match.group(1)
        loaded.append((group, path, recording.head(max_frames)))
    groups = sorted({group for group, _, _ in loaded})
    needed = 3 if val_share > 0 else 2
    if len(groups) < needed:
        raise ValueError(
            f"recordings: {len(groups)} group(s) ({', '.join(groups)}); "
            + (
                "a held-out group and cross-validation over the others need at least 3"
                if val_share > 0
                else "cross-validation needs at least 2"
            )
        )
    held = min(max(1, round(val_share * len(groups))), len(groups) - 2) if val_share > 0 else 0
    rng = np.random.default_rng(seed)
    held_out = sorted(str(g) for g in rng.choice(groups, size=held, replace=False))
    train = [(group, recording) for group, _, recording in loaded if group not in held_out]
    names = [path.stem for group, path, _ in loaded if group not in held_out]
    candidates = [recording for group, _, recording in loaded if group in held_out]
    step = max(1, len(candidates) // max(episodes, 1))
    validation = candidates[::step][:episodes]
    info = {
        "recordings": [str(path) for _, path, _ in loaded],
        "group_pattern": pattern,
        "training_groups": [g for g in groups if g not in held_out],
        "validation_groups": held_out,
    }
    return PairedRecordings(train, validation, info, names)


def _distinct_recordings(items: Sequence[str | Path], say: Callable[[str], None]) -> list[Path]:
    """The recording files ``items`` name (:func:`recording_paths`), each content once: a
    file whose content was already given is left out with a note (one recording twice would
    weigh twice in the fit)."""
    paths: list[Path] = []
    seen: dict[str, Path] = {}
    for path in recording_paths(items):
        digest = file_digest(path)
        if digest in seen:  # one recording twice would weigh twice in the fit
            say(f"note: --recordings {path}: the same recording as {seen[digest]}; read once")
            continue
        seen[digest] = path
        paths.append(path)
    return paths


def with_occlusions(paired: PairedRecordings, cases: Sequence[str], seed: int) -> PairedRecordings:
    """``paired`` with each training recording also once with an occlusion put in.

    Parameters
    ----------
    paired : PairedRecordings
    cases : sequence of str
        Occlusion cases (:func:`fpg_gym.simulate.occlude.occlusion_case_names`), given to the
        training recordings in turn; empty: ``paired`` unchanged.
    seed : int
        Same seed, same occlusions (recording ``i`` is occluded with
        ``derive_seed(seed, "occlusion", i)``).

    Returns
    -------
    PairedRecordings
        The training recordings, then their occluded copies (same group, name
        ``NAME~CASE``); validation and info unchanged.

    Raises
    ------
    ValueError
        On an unknown case name.
    """
    check_occlusion_cases(cases)
    if not cases:
        return paired
    occluded = []
    names = []
    for i, ((group, recording), name) in enumerate(zip(paired.train, paired.names, strict=True)):
        case = cases[i % len(cases)]
        occluded.append((group, occlude(recording, case, derive_seed(seed, "occlusion", i))))
        names.append(f"{name}~{case}")
    return PairedRecordings(
        paired.train + occluded, paired.validation, paired.info, paired.names + names
    )


@dataclass
class GroupDatabase:
    """The graph and sensor map one training group's data is collected with.

    Attributes
    ----------
    group : str
    graph : FilteredPoseGraph
    sensor_map : DefinitionMap or None
    """

    group: str
    graph: FilteredPoseGraph
    sensor_map: DefinitionMap | None


def group_databases(
    paired: PairedRecordings,
    graph: FilteredPoseGraph,
    sensor_map: DefinitionMap | None,
    *,
    source: str | Path = "graph",
) -> list[GroupDatabase]:
    """Per training group, a graph and a sensor map built without it (cross-fitting).

    ``graph`` (the evaluation's database, built from the ground truth of these recordings)
    and ``sensor_map`` (fitted on their pairs) saw every training group; a new subject's never
    do. So each group's graph is built, with ``graph``'s parameters (``thres1``, ``thres2``,
    mirroring), from the ground truth of the other training groups' recordings (in their
    order, each a clip named by its file stem), and its map is fitted, as ``fpg-gym fit-map``
    fits one, on their pairs.

    Raises
    ------
    ValueError
        If ``graph`` was not built from these recordings (none of its clips is named as a
        training recording), or ``sensor_map`` goes into a database's definitions (fitted with
        ``fit-map --graph``), which this does not refit.
    """
    if not set(graph.clip_names) & set(paired.names):
        raise ValueError(
            f"{source}: no clip of the graph is one of the training recordings (by file name); "
            "cross-fitting builds each group's graph from the other groups' ground truth, as "
            "the graph of these recordings' ground truth is built (fpg-gym build-graph of "
            "import-uiprmd's clips): give that graph, or do not cross-fit (--no-cross-fit)"
        )
    if sensor_map is not None and (sensor_map.inverted or "database_map" in sensor_map.info):
        raise ValueError(
            "sensor map: cross-fitting refits a map from the sensor into the ground truth's "
            "definitions; this one goes into a database's (fit-map --graph): do not cross-fit "
            "(--no-cross-fit)"
        )
    groups = sorted({group for group, _ in paired.train})
    params = graph.params
    out = []
    for group in groups:
        others = [
            (name, recording)
            for (member, recording), name in zip(paired.train, paired.names, strict=True)
            if member != group
        ]
        clips = [
            Clip(name, np.asarray(recording.ground_truth, dtype=np.float32), recording.fps)
            for name, recording in others
        ]
        built = FilteredPoseGraph.build(
            clips,
            thres1=float(params.get("thres1", graph.thres1)),
            thres2=params.get("thres2"),
            mirror=bool(params.get("mirror", False)),
            progress=False,
        )
        fitted = None
        if sensor_map is not None:
            fitted = DefinitionMap.fit(
                np.concatenate([r.positions for _, r in others]),
                np.concatenate([r.ground_truth for _, r in others]),
                source=sensor_map.source,
                target=sensor_map.target,
            )
        out.append(GroupDatabase(group, built, fitted))
    return out
