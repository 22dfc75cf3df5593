"""What a training run learns from and is evaluated on.

* :func:`training_clips` / :func:`split_clips`: the clips a sampler learns from and the held-out
  ones it is validated on (by whole clips, seeded). By default the embedded DeepMimic clips of
  the default graph (:data:`fpg_gym.io.DEFAULT_CLIP_NAMES` less
  :data:`fpg_gym.core.defaults.DEFAULT_HOLDOUT_CLIPS`): never the evaluation clips.
* :func:`simulate_episodes`: Kinect streams simulated from clips x scenarios x seeds.
* :func:`run_data`: a run's training clips or paired recordings and its held-out episodes
  (:class:`RunData`), as its :class:`~policies.training.config.TrainConfig` says.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
from fpg_gym.core.poses import mirror
from fpg_gym.graph import GRAPH_NAMES, load_graph
from fpg_gym.io import DEFAULT_CLIP_NAMES, Clip, resolve_clips
from fpg_gym.simulate import simulate_clips
from policies.paired_recordings import (
    GroupDatabase,
    PairedRecordings,
    group_databases,
    paired_recordings,
    with_occlusions,
)
from policies.training.config import TrainConfig

__all__ = [
    "RunData",
    "default_training_clip_names",
    "held_out_clash",
    "load_training_graph",
    "mirror_clip",
    "run_data",
    "simulate_episodes",
    "split_clips",
    "training_clips",
]


def default_training_clip_names() -> list[str]:
    """The embedded clips of the default graph (all but the held-out evaluation clips)."""

    return [n for n in DEFAULT_CLIP_NAMES if n not in DEFAULT_HOLDOUT_CLIPS]


def training_clips(
    items: Sequence[str] | None, *, units: str = "auto", progress: bool = False
) -> list[Any]:
    """Clips named by ``--clips``: None or ``"default"`` for :func:`default_training_clip_names`,
    embedded clip names, mocap files or folders (as ``fpg-gym compare --clips``)."""

    names: list[str] = []
    for item in items or ["default"]:
        if str(item) == "default":
            names.extend(default_training_clip_names())
        else:
            names.append(str(item))
    clips, _ = resolve_clips(names, units=units, progress=progress)
    unique: dict[str, Any] = {}
    for clip in clips:
        unique.setdefault(clip.name, clip)
    if not unique:
        raise ValueError("--clips: no clip to train on")
    return list(unique.values())


def mirror_clip(clip: Any) -> Any:
    """The left/right mirror image of a clip (``name~mirror``), for data augmentation."""

    return Clip(
        name=f"{clip.name}~mirror",
        positions=mirror(clip.positions).astype(np.float32),
        fps=clip.fps,
        source=clip.source,
        metadata={**clip.metadata, "mirrored": True},
    )


def split_clips(
    clips: Sequence[Any], share: float = 0.2, seed: int = 0
) -> tuple[list[Any], list[Any]]:
    """``(training, validation)``: a seeded ``share`` of the clips (at least one, by whole
    clips) held out for validation; with a single clip both are that clip."""
    if not 0.0 < share < 1.0:
        raise ValueError(f"share: expected a value in (0, 1), got {share}")
    if len(clips) < 2:
        return list(clips), list(clips)
    order = np.random.default_rng(seed).permutation(len(clips))
    count = max(1, round(share * len(clips)))
    held = sorted(int(i) for i in order[:count])
    kept = sorted(int(i) for i in order[count:])
    return [clips[i] for i in kept], [clips[i] for i in held]


def simulate_episodes(
    clips: Sequence[Any],
    scenarios: Sequence[str],
    seeds: Sequence[int],
    *,
    max_frames: int | None = None,
) -> list[Any]:
    """Recordings of every clip x scenario x seed (first ``max_frames`` frames), in that
    order (seed outermost), seeded by the episode planner's rule
    (:func:`fpg_gym.simulate.simulate_clips`)."""

    return simulate_clips(clips, scenarios, seeds, max_frames=max_frames)


def load_training_graph(name: str) -> Any:
    """``--graph``: a file, ``default`` (the embedded graph without the held-out clips) or a
    packaged graph by name (:data:`fpg_gym.graph.GRAPH_NAMES`)."""
    if name not in GRAPH_NAMES and not Path(name).is_file():
        raise FileNotFoundError(f"--graph: {name}: no such file")
    return load_graph(name, exclude=DEFAULT_HOLDOUT_CLIPS)


def held_out_clash(graph_name: str, clips: Sequence[Any]) -> list[str]:
    """Training clips that are evaluation clips of the default protocol."""

    if graph_name != "default":
        return []
    return sorted({c.name for c in clips} & set(DEFAULT_HOLDOUT_CLIPS))


@dataclass
class RunData:
    """What a run learns from and is evaluated on (:func:`run_data`).

    Attributes
    ----------
    validation : list
        The held-out episodes of the periodic and final evaluations (empty: none).
    info : dict
        What the run trains on, for the model's JSON (``training``).
    clips : list
        The training clips, with their mirror images (empty with paired recordings).
    paired : PairedRecordings, optional
        The paired recordings (with occlusions put in) of a run on recordings.
    databases : list of GroupDatabase, optional
        Each training group's graph and sensor map built without it (cross-fitting).
    """

    validation: list[Any]
    info: dict[str, Any]
    clips: list[Any] = field(default_factory=list)
    paired: PairedRecordings | None = None
    databases: list[GroupDatabase] | None = None

    def units(self) -> list[str]:
        """The units the linear fit cross-validates over: each training recording's group,
        or each training clip's name (a clip's mirror image is the same unit)."""
        if self.paired is not None:
            return [group for group, _ in self.paired.train]
        return [c.name.removesuffix("~mirror") for c in self.clips]


def run_data(
    config: TrainConfig,
    graph: Any,
    options: dict[str, Any],
    scenarios: Sequence[str],
    say: Callable[[str], None],
) -> RunData:
    """The training data and held-out episodes of a run: ``config.recordings``' paired
    recordings (:func:`_recordings_data`) or simulated streams of ``config.clips``
    (:func:`_clips_data`).

    Raises
    ------
    ValueError
        Training clips that are the default protocol's evaluation clips, or recordings that
        cannot be grouped or cross-fitted.
    """
    if config.recordings is not None:
        return _recordings_data(config, graph, options, say)
    return _clips_data(config, scenarios, say)


def _recordings_data(
    config: TrainConfig, graph: Any, options: dict[str, Any], say: Callable[[str], None]
) -> RunData:
    """Paired recordings, a seeded share of their groups held out; with ``cross_fit``, each
    training group's graph and sensor map built without it; with ``occlusions``, each
    training recording also with an occlusion case put in."""
    assert config.recordings is not None
    paired = paired_recordings(
        config.recordings,
        pattern=config.group_pattern,
        val_share=config.val_share,
        episodes=config.eval_episodes,
        max_frames=config.max_frames,
        seed=config.seed,
        log=say,
    )
    validation = paired.validation
    held = (
        f"{len(validation)} held-out recordings of the groups "
        f"{', '.join(paired.info['validation_groups'])}"
        if validation
        else "no group held out (--val-share 0: no final evaluation)"
    )
    say(
        f"train-sampler: linear (target {config.target}), "
        f"{len(paired.train)} training recordings in "
        f"{len(paired.info['training_groups'])} groups, {held}, "
        + ("each group's data with a graph and sensor map without it, " * config.cross_fit)
        + f"seed {config.seed}"
    )
    info: dict[str, Any] = {
        **paired.info,
        "cross_fit": config.cross_fit,
        "occlusions": list(config.occlusions),
    }
    databases: list[GroupDatabase] | None = None
    if config.cross_fit:  # before any other work: a graph that cannot be cross-fitted
        t0 = time.perf_counter()
        databases = group_databases(paired, graph, options.get("sensor_map"), source=config.graph)
        say(
            f"cross-fitting: {len(databases)} graphs and sensor maps, each without its "
            f"group ({time.perf_counter() - t0:.1f} s)"
        )
    if config.occlusions:  # after the databases: they are built from the real streams
        paired = with_occlusions(paired, config.occlusions, config.seed)
        say(
            f"occlusions: each training recording also with one of "
            f"{', '.join(config.occlusions)} put in ({len(paired.train)} recordings)"
        )
    return RunData(validation, info, paired=paired, databases=databases)


def _clips_data(
    config: TrainConfig, scenarios: Sequence[str], say: Callable[[str], None]
) -> RunData:
    """Training clips (with their mirror images) and simulated held-out episodes of the
    validation clips (``val_clips``, or a seeded ``val_share`` of the clips)."""
    clips = training_clips(config.clips, units=config.units, progress=config.progress)
    if config.val_clips:
        val_clips = training_clips(config.val_clips, units=config.units)
        train_clips = clips
    else:
        train_clips, val_clips = split_clips(clips, config.val_share, config.seed)
    clash = held_out_clash(config.graph, list(train_clips) + list(val_clips))
    if config.mirror:
        train_clips = list(train_clips) + [mirror_clip(c) for c in train_clips]
    if clash:
        raise ValueError(
            f"--clips {clash}: these are the held-out evaluation clips of the default "
            "graph; train on other clips (the default: the clips the default graph is "
            "built from)"
        )
    say(
        f"train-sampler: {config.kind}"
        + (f" ({config.algo})" if config.kind == "rl" else f" (target {config.target})")
        + f", {len(train_clips)} training clips, {len(val_clips)} validation clips, "
        f"scenarios {','.join(scenarios)}, {config.total_timesteps} timesteps, "
        f"seed {config.seed}"
    )
    val_seeds = [10_000 + config.seed]
    validation = simulate_episodes(val_clips, scenarios, val_seeds, max_frames=config.max_frames)[
        : config.eval_episodes
    ]
    info = {
        "clips": [c.name for c in train_clips],
        "validation_clips": [c.name for c in val_clips],
        "scenarios": scenarios,
    }
    return RunData(validation, info, clips=list(train_clips))
