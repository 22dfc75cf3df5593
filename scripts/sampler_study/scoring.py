"""Every method of the study on every held-out episode, with the figures the tables pool."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

import optimizers
from fpg_gym.core import metrics
from fpg_gym.filters import make_filter
from fpg_gym.methods import MethodRunner
from fpg_gym.reconstruct import Reconstructor
from fpg_gym.reconstruct.streams import Choice, Stream, reconstruct_stream
from policies.learned_optimizers import LearnedSampler
from policies.training import truth_latent


def mean_only(path: str, **_: Any) -> Any:
    """``mean-only:PATH``: the sampler of ``PATH`` drawing one candidate, its mean."""
    return LearnedSampler(path, samples=1)


def _oracle(
    graph: Any, options: dict[str, Any], recording: Any, metric: str = "joints"
) -> np.ndarray:
    """The stream reconstructed from the ground truth's own latent point every frame
    (:func:`policies.training.truth_latent`, its joints projected or, ``metric="bones"``, its
    bone directions at the frame's bone lengths): what a perfect sampler of this latent space
    would give (a ceiling of every sampler; it sees the truth, so it is no method)."""

    truth = recording.ground_truth

    def truth_points(problems: Sequence[Any], streams: Sequence[Stream]) -> list[Choice]:
        return [
            Choice(
                truth_latent(problem, stream.reconstructor.placement, truth[stream.next], metric)
            )
            for problem, stream in zip(problems, streams, strict=True)
        ]

    with Reconstructor(graph, ragdoll=False, **options) as reconstructor:
        return reconstruct_stream(Stream(reconstructor, recording), truth_points).poses


def _row(truth: np.ndarray, poses: np.ndarray, recording: Any) -> dict[str, float]:
    """One episode's figures: FPG Eq. 13 (``error``), MPJPE absolute, root-relative and
    Procrustes-aligned, jitter, the largest settled bone range (mm) and the mean bone-length
    error against the truth (mm)."""
    spread = metrics.settled_bone_spread(poses, timestamps=recording.timestamps)
    return {
        "error": float(metrics.frame_error(truth, poses).mean()),
        "mpjpe": metrics.mpjpe(truth, poses),
        "mpjpe_root": metrics.mpjpe(truth, poses, "root"),
        "mpjpe_pa": metrics.mpjpe(truth, poses, "procrustes"),
        "jitter": float(np.nanmean(metrics.jitter(poses, timestamps=recording.timestamps))),
        "spread_mm": float(1000 * np.nanmax(spread)) if np.isfinite(spread).any() else np.nan,
        "bone_error_mm": float(1000 * metrics.bone_length_error(truth, poses).mean()),
    }


def score(
    graph: Any, options: dict[str, Any], models: dict[str, str], episodes: list[tuple[str, Any]]
) -> list[dict[str, Any]]:
    """Every method on every ``(name, recording)``: the sensor's baselines (raw, the SDK's
    Holt filter, the sensor through the sensor map and that filtered by Holt), closed-form,
    local-search, each model's ``learned:`` and ``learned+search:`` (and a linear model's
    ``uncorrected``, an MLP's mean alone) and the bones oracle: :func:`_row`'s figures and CPU
    ms per frame."""

    def uncorrected(path: str, **_: Any) -> Any:
        return LearnedSampler(path, correct_output=False)

    optimizers.register_prefix("mean-only", mean_only, overwrite=True)
    optimizers.register_prefix("uncorrected", uncorrected, overwrite=True)
    methods = ["raw", "holt", "fpg:closed-form", "fpg:local-search"]
    for path in models.values():
        methods += [f"fpg:learned:{path}", f"fpg:learned+search:{path}"]
        linear = LearnedSampler(path).sampler.spec.kind == "linear"
        # A linear model's mean alone is its learned: (the posterior picks the mean).
        methods.append(f"fpg:uncorrected:{path}" if linear else f"fpg:mean-only:{path}")
    sensor_map = options.get("sensor_map")
    rows = []
    with MethodRunner(graph, budget=2000, reconstructor_options=options) as runner:
        for name, recording in episodes:
            truth = recording.ground_truth
            assert truth is not None
            baselines: dict[str, Any] = {}
            if sensor_map is not None:  # the sensor in the truth's definitions, no database
                mapped = sensor_map.apply(recording.positions)
                holt = make_filter("holt")
                baselines["mapped"] = mapped
                baselines["mapped+holt"] = holt.filter_sequence(
                    mapped, recording.states, recording.timestamps
                )
            for method in [*methods, *baselines, "oracle-bones"]:
                c0 = time.process_time()
                if method == "oracle-bones":
                    poses = _oracle(graph, options, recording, "bones")
                elif method in baselines:
                    poses = baselines[method]
                else:
                    poses = runner.run(method, recording, seed=0).poses
                cpu = 1000 * (time.process_time() - c0) / recording.num_frames
                rows.append(
                    {
                        "episode": name,
                        "method": method,
                        **_row(truth, poses, recording),
                        "cpu_ms": cpu,
                    }
                )
    return rows
