"""The linear pose-space sampler's training step: its imitation pairs, its settings
cross-validated over groups of whole clips or recording groups
(:func:`policies.pose_sampler.fit_linear`), and its output correction learnt from its own
outputs (:mod:`policies.output_correction`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from policies.checkpoints import RunCheckpoints
from policies.imitation import ImitationData
from policies.learned_optimizers import LearnedSampler
from policies.output_correction import CorrectionSource, learn_correction
from policies.paired_recordings import GroupDatabase, PairedRecordings
from policies.pose_sampler import LINEAR_FEATURES, LinearPoseSampler, describe_fit, fit_linear
from policies.sampler import GaussianSampler, SamplerSpec
from policies.training.config import TrainConfig
from policies.training.pairs import collect_pairs, imitation_pairs, imitation_spec

__all__ = ["LINEAR_GROUPS", "check_linear_units", "train_linear"]

#: Cross-validation groups of the linear sampler's training episodes (:func:`train_linear`).
LINEAR_GROUPS = 5


def train_linear(
    config: TrainConfig,
    graph: Any,
    source: PairedRecordings | Sequence[Any],
    scenarios: Sequence[str],
    options: dict[str, Any],
    run: RunCheckpoints,
    seconds: dict[str, float],
    say: Callable[[str], None],
    databases: Sequence[GroupDatabase] | None = None,
) -> tuple[GaussianSampler, list[dict[str, Any]]]:
    """The linear pose-space sampler (:mod:`policies.pose_sampler`) on the training
    recordings of paired ``source``, its settings chosen by cross-validation over their
    groups (one per group; with ``databases``, each group's data collected with its graph and
    sensor map, :func:`policies.paired_recordings.group_databases`), or on simulated streams
    of the clips ``source``, over groups of whole clips; with ``config.correction``, its
    output correction learnt from its own outputs of the same recordings, reconstructed as
    their data were, cross-validated over the same groups."""

    spec = imitation_spec(config, "linear", "ridge", LINEAR_FEATURES)
    if isinstance(source, PairedRecordings):
        names = np.array([group for group, _ in source.train])
        recordings = [recording for _, recording in source.train]
        if databases is not None:
            setups = [
                (names == db.group, db.graph, {**options, "sensor_map": db.sensor_map})
                for db in databases
            ]
        else:
            setups = [(np.ones(len(names), dtype=bool), graph, options)]
        data = collect_pairs(
            config,
            [(np.flatnonzero(mine), own, opts) for mine, own, opts in setups],
            recordings,
            spec,
            run,
            frames=config.timesteps,
            started=time.perf_counter(),
            seconds=seconds,
            say=say,
        )
        unit = names[data.episodes]
        # Cross-validation over the recordings' own groups (subjects: each left out whole).
        sampler, history, groups = _fit_linear_groups(spec, data, unit, seconds, say, None)
        setup_of = {int(e): setup for setup in setups for e in np.flatnonzero(setup[0])}
    else:
        data, clip_of_episode, recordings = imitation_pairs(
            config, graph, source, scenarios, options, spec, run, seconds, say
        )
        # Whole clips per group (a clip and its mirror image together), so that
        # cross-validation scores each setting on motions its fit did not see.
        group_of_clip = np.array([c.name.removesuffix("~mirror") for c in source])
        unit = group_of_clip[clip_of_episode[data.episodes]]
        sampler, history, groups = _fit_linear_groups(spec, data, unit, seconds, say, LINEAR_GROUPS)
        setup_of = {int(e): (None, graph, options) for e in np.unique(data.episodes)}
    if config.correction:
        # The correction's groups are the sampler's, its recordings reconstructed by the
        # sampler with the graph and options their data were collected with.
        t0 = time.perf_counter()
        first = np.unique(data.episodes, return_index=True)
        episode_group = dict(zip(first[0].tolist(), groups[first[1]].tolist(), strict=True))
        optimizer = LearnedSampler(sampler, samples=1, correct_output=False)
        sources = []
        for chosen in np.unique(groups).tolist():
            episodes = [e for e, g in episode_group.items() if g == chosen]
            _, own, opts = setup_of[episodes[0]]  # a group's episodes share their setup
            sources.append(
                CorrectionSource(own, opts, [recordings[e] for e in episodes], optimizer)
            )
        correction, report = learn_correction(sources, progress=config.progress, log=say)
        sampler.with_correction(correction, report)
        seconds["correction"] = time.perf_counter() - t0
        history[0]["correction"] = report
    return sampler, history


def check_linear_units(units: Sequence[str]) -> None:
    """Refuse fewer than 2 distinct training clips or groups (the linear fit cross-validates
    its settings over them; a clip's mirror image is the same unit)."""
    distinct = sorted(set(units))
    if len(distinct) < 2:
        raise ValueError(
            "kind 'linear': cross-validation needs at least 2 training clips or groups, got "
            f"{len(distinct)} ({', '.join(distinct) or 'none'}) once the held-out share "
            "(--val-share) is set apart; give more --clips (or --recordings groups), or "
            "--val-clips"
        )


def _fit_linear_groups(
    spec: SamplerSpec,
    data: ImitationData,
    unit: np.ndarray,
    seconds: dict[str, float],
    say: Callable[[str], None],
    most: int | None,
) -> tuple[LinearPoseSampler, list[dict[str, Any]], np.ndarray]:
    """:func:`fit_linear` on ``data``, cross-validated over groups of whole units (``unit``:
    each frame's clip or recording group, a label): one per unit, or at most ``most``, the
    units dealt in sorted order; also each frame's group."""
    units, index = np.unique(unit, return_inverse=True)
    check_linear_units(units.tolist())
    group = index % min(most or len(units), len(units))
    groups = [
        (data.observations[take], data.actions[take], data.episodes[take])
        for take in (group == g for g in np.unique(group))
    ]
    t0 = time.perf_counter()
    sampler, report = fit_linear(spec, groups)
    seconds["train"] = time.perf_counter() - t0
    say(f"{describe_fit(report)} ({seconds['train']:.1f} s)")
    return sampler, [{"linear": report}], group
