"""The study's ground-truth samplers: their description, one MLP per seed or the linear
pose-space sampler with its output correction."""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from policies.learned_optimizers import LearnedSampler
from policies.output_correction import CorrectionSource, describe_correction, learn_correction
from policies.pose_sampler import LINEAR_FEATURES, describe_fit, fit_linear
from policies.sampler import FEATURE_SETS, SamplerSpec
from policies.supervised import SupervisedSampler
from policies.supervised_fit import fit_supervised


def sampler_spec(task: dict[str, Any]) -> Any:
    """The sampler's description (ground-truth target, the env's layout): the linear
    pose-space sampler (``--model linear``) or the supervised MLP (``--model mlp``)."""

    if task["model"] == "linear":
        return SamplerSpec.for_layout(
            "linear",
            "ridge",
            action_mode="absolute",
            features=list(LINEAR_FEATURES),
            hyperparameters={"target": "bones"},
        )
    return SamplerSpec.for_layout(
        "supervised",
        "mlp",
        action_mode="absolute",
        features=list(FEATURE_SETS[task["features"]]),
        hyperparameters={"hidden": task["hidden"], "target": "truth", "epochs": task["epochs"]},
    )


def train_seeds(
    spec: Any,
    train: list[Any],
    val: Any,
    task: dict[str, Any],
    name: str,
    info: dict[str, Any],
    sources: list[tuple[Any, dict[str, Any], list[Any], int]] | None = None,
) -> dict[str, Any]:
    """One sampler per seed of ``task["seeds"]`` on the ``train`` imitation data, early
    stopping, shrinking and spread calibration on ``val``; saved as ``{out}/sampler_{name}_seedS``.
    A linear sampler learns its output correction from ``sources`` (``(graph, options,
    recordings, group)``: the group's index in ``[*train, val]``; none: no correction, or with
    ``task["correct"]`` false).
    """

    if spec.kind == "linear":
        return _train_linear(spec, [*train, val], task, name, info, sources)
    obs = np.concatenate([d.observations for d in train])
    act = np.concatenate([d.actions for d in train])
    mask = np.concatenate([d.masks for d in train])
    transformed = spec.feature_map().transform(obs)
    features = transformed[0]
    result: dict[str, Any] = {"models": {}, "train_cpu_s": {}, "mean_scale": {}}
    for seed in task["seeds"]:
        t0 = time.process_time()
        sampler = SupervisedSampler.create(
            dataclasses.replace(spec, hyperparameters=dict(spec.hyperparameters)),
            features.mean(axis=0),
            np.maximum(features.std(axis=0), 1e-3),
            seed=seed,
        )
        history = fit_supervised(
            sampler,
            obs,
            act,
            mask,
            epochs=task["epochs"],
            seed=seed,
            validation=(val.observations, val.actions, val.masks),
            transformed=transformed,
        )
        result["train_cpu_s"][str(seed)] = time.process_time() - t0
        result["mean_scale"][str(seed)] = float(history[-1].get("mean_scale", 1.0))
        sampler.spec.training = {
            **info,
            "frames": len(obs),
            "validation_frames": len(val),
            "best_epoch": next(r["epoch"] for r in history if r.get("best")),
            "mean_scale": history[-1].get("mean_scale"),
            "std_scale": history[-1].get("std_scale"),
            "seed": seed,
            "command": task["command"],
        }
        path = Path(task["out"]) / f"sampler_{name}_seed{seed}"
        sampler.save(path)
        result["models"][str(seed)] = str(path)
    result["frames"] = len(obs)
    return result


def _train_linear(
    spec: Any,
    groups: list[Any],
    task: dict[str, Any],
    name: str,
    info: dict[str, Any],
    sources: list[tuple[Any, dict[str, Any], list[Any], int]] | None = None,
) -> dict[str, Any]:
    """The linear pose-space sampler, its settings chosen by leave-one-group-out
    cross-validation over ``groups`` (imitation data of the training subjects, or of the
    simulated protocol's folds); deterministic (one model whatever the seeds); with
    ``sources`` and ``task["correct"]``, its output correction learnt from its outputs of the
    training groups (:func:`policies.output_correction.learn_correction`); saved as
    ``{out}/sampler_{name}_linear``."""

    t0 = time.process_time()
    sampler, report = fit_linear(spec, [(d.observations, d.actions, d.episodes) for d in groups])
    cpu = time.process_time() - t0
    correction_report: dict[str, Any] = {}
    if sources and task.get("correct", True):
        t1 = time.process_time()
        bare = LearnedSampler(sampler, samples=1, correct_output=False)
        correction, correction_report = learn_correction(
            [
                CorrectionSource(graph, options, recordings, bare)
                for graph, options, recordings, _ in sources
            ]
        )
        sampler.with_correction(correction, correction_report)
        correction_report = {**correction_report, "cpu_s": time.process_time() - t1}
        cpu += correction_report["cpu_s"]  # the model's training: the sampler and its correction
        print(f"{name}: {describe_correction(correction_report)}", file=sys.stderr, flush=True)
    sampler.spec.training = {**info, **report, "command": task["command"]}
    path = Path(task["out"]) / f"sampler_{name}_linear"
    sampler.save(path)
    print(
        f"{name}: {describe_fit(report)}; by pose weight {json.dumps(report['cv_pose'])}",
        file=sys.stderr,
        flush=True,
    )
    return {
        "models": {"linear": str(path)},
        "train_cpu_s": {"linear": cpu},
        "mean_scale": {},
        "frames": sum(len(d) for d in groups),
        "linear": report,
        "correction": correction_report,
    }
