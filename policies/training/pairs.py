"""The imitation pairs a supervised or linear sampler learns from: collected from simulated
streams or paired recordings (:func:`policies.imitation.collect_imitation_data`), saved in
chunks and read back from a stopped run's checkpoints (:mod:`policies.checkpoints`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import fields as dataclass_fields
from dataclasses import replace as dataclass_replace
from typing import Any

import numpy as np

from policies.checkpoints import RunCheckpoints
from policies.imitation import ImitationData, collect_imitation_data, frame_caps
from policies.sampler import SamplerSpec
from policies.training.config import TrainConfig
from policies.training.data import simulate_episodes

__all__ = ["collect_pairs", "imitation_pairs", "imitation_spec"]


def imitation_spec(
    config: TrainConfig, kind: str, algo: str, features: Sequence[str], **hyperparameters: Any
) -> SamplerSpec:
    """The spec of a sampler trained on imitation pairs (supervised or linear)."""
    return SamplerSpec.for_layout(
        kind,
        algo,
        config.latent_dim,
        config.k,
        features=list(features),
        anchor=config.anchor,
        anchor_style=config.anchor_style,
        action_mode=config.action_mode,
        action_scale=config.action_scale,
        hyperparameters={
            **config.hyperparameters,
            "target": config.target,
            "follow": config.follow,
            **hyperparameters,
        },
    )


def imitation_pairs(
    config: TrainConfig,
    graph: Any,
    train_clips: Sequence[Any],
    scenarios: Sequence[str],
    options: dict[str, Any],
    spec: SamplerSpec,
    run: RunCheckpoints,
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> tuple[ImitationData, np.ndarray, list[Any]]:
    """The supervised and linear samplers' training pairs: simulated streams of the training
    clips, collected (or read back from a stopped run's checkpoints) as ``config`` says with
    the reconstructor ``options``; the index in ``train_clips`` of each episode's clip; and
    the streams (in episode order)."""

    t0 = time.perf_counter()
    frames_per_pass = sum(
        min(c.num_frames, config.max_frames or c.num_frames) for c in train_clips
    ) * len(scenarios)
    passes = max(1, -(-config.total_timesteps // max(frames_per_pass, 1)))
    seeds = [config.seed * 1000 + i for i in range(passes)]
    recordings = simulate_episodes(train_clips, scenarios, seeds, max_frames=config.max_frames)
    order = np.random.default_rng(config.seed).permutation(len(recordings))
    recordings = [recordings[i] for i in order]
    # Each episode's clip (simulate_episodes: seed outermost, then clip, then scenario).
    clip_of_episode = (order // len(scenarios)) % len(train_clips)
    data = collect_pairs(
        config,
        [(np.arange(len(recordings)), graph, options)],
        recordings,
        spec,
        run,
        frames=config.total_timesteps,
        started=t0,
        seconds=seconds,
        say=say,
    )
    return data, clip_of_episode, recordings


def collect_pairs(
    config: TrainConfig,
    setups: Sequence[tuple[np.ndarray, Any, dict[str, Any]]],
    recordings: Sequence[Any],
    spec: SamplerSpec,
    run: RunCheckpoints,
    *,
    frames: int | None,
    started: float,
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> ImitationData:
    """Imitation pairs of ``recordings`` (at most ``frames``, in recording order), collected
    as ``config`` says, each ``(episodes, graph, reconstructor options)`` of ``setups`` its
    recordings with its graph and options; or read back from a stopped run's checkpoints.
    Episodes are numbered by their index in ``recordings``."""
    collected = run.collected_episodes()
    if collected:
        say(f"{run.folder}: going on from {len(collected)} collected episodes")
    caps = frame_caps(recordings, frames)
    parts = []
    for episodes, graph, options in setups:
        episodes = np.asarray(episodes, dtype=np.int64)

        def save(chunk: Sequence[int], pairs: ImitationData, ids: np.ndarray = episodes) -> Any:
            """A chunk's pairs saved under the episodes' numbers in ``recordings``."""
            pairs = dataclass_replace(pairs, episodes=ids[pairs.episodes])
            return run.save_chunk(ids[np.asarray(chunk)].tolist(), pairs)

        part = collect_imitation_data(
            graph,
            [recordings[e].head(max(caps[e], 1)) for e in episodes],
            spec,
            target=config.target,
            follow=config.follow,
            seed=config.seed,
            progress=config.progress,
            reconstructor_options=options,
            workers=config.workers,
            backend=config.backend,
            address=config.address,
            skip=[i for i, e in enumerate(episodes) if e in collected or caps[e] == 0],
            on_chunk=save,
        )
        parts.append(dataclass_replace(part, episodes=episodes[part.episodes]))
    data = run.merged_data(_in_episode_order(parts))
    seconds["data"] = time.perf_counter() - started
    say(
        f"imitation data: {len(data)} frames from {len(set(data.episodes.tolist()))} episodes "
        f"in {seconds['data']:.1f} s"
    )
    return data


def _in_episode_order(parts: Sequence[ImitationData]) -> ImitationData:
    """The pairs of ``parts`` ordered by episode (each episode's frames in order)."""
    merged = ImitationData.concatenate(parts)
    order = np.argsort(merged.episodes, kind="stable")
    return ImitationData(*(getattr(merged, f.name)[order] for f in dataclass_fields(merged)))
