"""The learned output correction of a linear sampler: data, fit and model (issue 19).

The reconstructor applies a correction model after its output
(:mod:`fpg_gym.reconstruct.output_correction`: the features, the targets and the causal
smoothing are defined there). This module fits one: a ridge regression (:mod:`policies.ridge`)
of the truth's root-relative joints minus the output's, from the outputs of the sampler it will
correct on recordings with ground truth (:func:`correction_data`; by default the sampler's
outputs of its own training recordings; cross-fitted, each group's outputs come from the sampler
fitted without that group, :class:`CorrectionSource`), its penalty and smoothing
chosen by leave-one-group-out cross-validation over groups of whole recordings (subjects, or
sets of clips) on FPG Eq. 13 (:func:`fit_output_correction`). A linear sampler stores its
correction in its own files (:meth:`policies.pose_sampler.LinearPoseSampler.with_correction`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from tqdm import tqdm

from fpg_gym.core import poses as pose_utils
from fpg_gym.reconstruct import Reconstructor
from fpg_gym.reconstruct.output_correction import (
    CORRECTION_FEATURES,
    correction_frames,
    smooth_corrections,
)
from policies.ridge import fit_ridge, predict_ridge, ridge_sums

__all__ = [
    "CORRECTION_ARRAYS",
    "CORRECTION_PENALTIES",
    "CORRECTION_SMOOTHING",
    "CorrectionData",
    "CorrectionSource",
    "RidgeOutputCorrection",
    "correction_data",
    "describe_correction",
    "fit_output_correction",
    "learn_correction",
]

#: Ridge penalties tried by cross-validation (standardised features).
CORRECTION_PENALTIES: tuple[float, ...] = (10.0, 100.0, 1e3, 1e4, 1e5)
#: Smoothing factors ``alpha`` tried by cross-validation (1: none).
CORRECTION_SMOOTHING: tuple[float, ...] = (1.0, 0.5, 0.25, 0.125)
#: The model's arrays as a sampler file stores them (prefixed ``correction_``) and their shapes.
CORRECTION_ARRAYS: dict[str, tuple[int, ...]] = {
    "regressor_mean": (CORRECTION_FEATURES,),
    "regressor_scale": (CORRECTION_FEATURES,),
    "weights": (CORRECTION_FEATURES, 60),
    "bias": (60,),
}


@dataclass
class RidgeOutputCorrection:
    """A ridge model of the output's miss (an
    :class:`~fpg_gym.reconstruct.output_correction.OutputCorrection`).

    Attributes
    ----------
    arrays : dict
        :func:`policies.ridge.fit_ridge`'s ``regressor_mean``, ``regressor_scale``, ``weights``
        and ``bias`` (:data:`CORRECTION_ARRAYS`).
    smoothing : float
        ``alpha`` of the causal smoothing, in (0, 1].
    penalty : float
        The ridge penalty it was fitted with (a record).
    """

    arrays: dict[str, np.ndarray]
    smoothing: float
    penalty: float

    def __post_init__(self) -> None:
        if not 0.0 < self.smoothing <= 1.0:
            raise ValueError(f"smoothing: expected a value in (0, 1], got {self.smoothing}")
        for name, shape in CORRECTION_ARRAYS.items():
            value = np.asarray(self.arrays[name], dtype=np.float64)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"{name}: expected finite values of shape {shape}")
            self.arrays[name] = value
        if np.any(self.arrays["regressor_scale"] <= 0):
            raise ValueError("regressor_scale: expected positive values")

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Offsets ``(n, 60)`` of the output's root-relative joints for feature rows."""
        return predict_ridge(self.arrays, np.asarray(features, dtype=np.float64))


@dataclass
class CorrectionData:
    """One group's frames: features ``(n, F)``, targets ``(n, 60)`` and each frame's episode
    ``(n,)`` (consecutive frames of a stream share one)."""

    features: np.ndarray
    targets: np.ndarray
    episodes: np.ndarray

    def __len__(self) -> int:
        return len(self.targets)


def correction_data(
    reconstructor: Reconstructor,
    recordings: Sequence[Any],
    optimizer: Any,
    *,
    progress: bool = False,
    first_episode: int = 0,
) -> CorrectionData:
    """The frames a correction learns from: ``recordings`` (with ``ground_truth``)
    reconstructed with ``optimizer`` (the sampler to correct, without a correction: e.g.
    ``LearnedSampler(sampler, samples=1, correct_output=False)``), seed 0 each.

    Raises
    ------
    ValueError
        If a recording has no ground truth.
    """
    features, targets, episodes = [], [], []
    for number, recording in enumerate(
        tqdm(recordings, desc="correction data", unit="rec", disable=not progress, leave=False)
    ):
        truth = getattr(recording, "ground_truth", None)
        if truth is None:
            name = getattr(recording, "path", None) or f"recording {number}"
            raise ValueError(f"{name}: a correction learns from ground truth; this has none")
        result = reconstructor.reconstruct(recording, optimizer, rng=0)
        rows, target, _, _ = correction_frames(
            result.poses, recording, result.arrays()["reliability"]
        )
        features.append(rows)
        targets.append(target)
        episodes.append(np.full(len(rows), first_episode + number))
    return CorrectionData(
        np.concatenate(features) if features else np.zeros((0, CORRECTION_FEATURES)),
        np.concatenate(targets) if targets else np.zeros((0, 60)),
        np.concatenate(episodes) if episodes else np.zeros(0, dtype=int),
    )


class CorrectionSource(NamedTuple):
    """One group's part of a correction's training (:func:`learn_correction`).

    Attributes
    ----------
    graph : FilteredPoseGraph
        The graph its recordings are reconstructed with (as on held-out data, one without
        them).
    options : dict
        :class:`~fpg_gym.reconstruct.Reconstructor` settings (sensor map, sensor blend...).
    recordings : sequence of Recording
        Its recordings, with ground truth.
    optimizer : Optimizer
        The sampler whose output is corrected, without a correction (e.g.
        ``LearnedSampler(sampler, samples=1, correct_output=False)``); cross-fitted, one that
        did not learn from this group (:func:`policies.pose_sampler.out_of_group_samplers`).
    """

    graph: Any
    options: dict[str, Any]
    recordings: Sequence[Any]
    optimizer: Any


def learn_correction(
    sources: Sequence[CorrectionSource],
    *,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
) -> tuple[RidgeOutputCorrection | None, dict[str, Any]]:
    """:func:`correction_data` of each group, then :func:`fit_output_correction` over them
    (None: no correction chosen).

    Parameters
    ----------
    sources : sequence of CorrectionSource
        One per cross-validation group.
    progress : bool
        A progress bar per group.
    log : callable, optional
        Receives one line on the choice.
    """
    groups, first = [], 0
    for source in sources:
        with Reconstructor(source.graph, ragdoll=False, **source.options) as reconstructor:
            data = correction_data(
                reconstructor,
                source.recordings,
                source.optimizer,
                progress=progress,
                first_episode=first,
            )
        groups.append(data)
        first += len(source.recordings)
    return fit_output_correction(groups, log=log)


def _episode_errors(offsets: np.ndarray, data: CorrectionData) -> np.ndarray:
    """Each episode's mean FPG Eq. 13 of the outputs moved by ``offsets`` (the bone vectors of
    ``offsets - targets``: the error of ``output + offset`` against the truth)."""
    miss = pose_utils.flat_bone_vectors(offsets - data.targets)
    frame = np.linalg.norm(miss.reshape(len(miss), -1, 3), axis=2).mean(axis=1)
    _, index = np.unique(data.episodes, return_inverse=True)
    return np.bincount(index, weights=frame) / np.bincount(index)


def fit_output_correction(
    groups: Sequence[CorrectionData],
    *,
    penalties: Sequence[float] = CORRECTION_PENALTIES,
    smoothing: Sequence[float] = CORRECTION_SMOOTHING,
    log: Callable[[str], None] | None = None,
) -> tuple[RidgeOutputCorrection | None, dict[str, Any]]:
    """Fit a correction; penalty and smoothing by leave-one-group-out cross-validation.

    Each setting is scored by the mean over every group's episodes of FPG Eq. 13 of the
    outputs corrected by a model fitted on the other groups; the chosen setting is then fitted
    on every group. No correction is a candidate too: when no setting scores below the
    uncorrected outputs, there is none (what a group's data teach does not carry over to the
    others).

    Parameters
    ----------
    groups : sequence of CorrectionData
        At least two (subjects, or sets of clips).
    penalties, smoothing : sequence of float
        The ridge penalties and smoothing factors tried.
    log : callable, optional
        Receives one line on the choice.

    Returns
    -------
    correction : RidgeOutputCorrection or None
        None when no correction is chosen.
    report : dict
        ``penalty``, ``smoothing`` (None with no correction), ``cv_error`` (m, by
        ``"penalty/smoothing"``), ``uncorrected_error`` (the outputs' own), ``frames``,
        ``groups``.
    """
    if len(groups) < 2:
        raise ValueError(f"groups: expected at least 2 for cross-validation, got {len(groups)}")
    if any(len(g) == 0 for g in groups):
        raise ValueError("groups: expected frames in every group")
    if not penalties or min(penalties) < 0:
        raise ValueError(f"penalties: expected non-negative values, got {list(penalties)}")
    if not smoothing or not all(0.0 < a <= 1.0 for a in smoothing):
        raise ValueError(f"smoothing: expected values in (0, 1], got {list(smoothing)}")
    sums = [ridge_sums(g.features, g.targets) for g in groups]
    uncorrected = float(
        np.concatenate([_episode_errors(np.zeros_like(g.targets), g) for g in groups]).mean()
    )
    errors: dict[str, float] = {}
    best: tuple[float, float | None, float | None] = (uncorrected, None, None)
    for penalty in penalties:
        predicted = [
            predict_ridge(fit_ridge(sums[:g] + sums[g + 1 :], penalty), group.features)
            for g, group in enumerate(groups)
        ]
        for alpha in smoothing:
            error = float(
                np.concatenate(
                    [
                        _episode_errors(smooth_corrections(p, group.episodes, alpha), group)
                        for p, group in zip(predicted, groups, strict=True)
                    ]
                ).mean()
            )
            errors[f"{penalty:g}/{alpha:g}"] = error
            if error < best[0]:
                best = (error, penalty, alpha)
    _, chosen_penalty, chosen_alpha = best
    correction = (
        None
        if chosen_penalty is None or chosen_alpha is None
        else RidgeOutputCorrection(fit_ridge(sums, chosen_penalty), chosen_alpha, chosen_penalty)
    )
    report = {
        "penalty": chosen_penalty,
        "smoothing": chosen_alpha,
        "cv_error": errors,
        "uncorrected_error": uncorrected,
        "frames": int(sum(len(g) for g in groups)),
        "groups": len(groups),
    }
    if log is not None:
        log(describe_correction(report))
    return correction, report


def describe_correction(report: dict[str, Any]) -> str:
    """One line on :func:`fit_output_correction`'s ``report``."""
    if report["penalty"] is None:
        best = min(report["cv_error"].values())
        return (
            f"output correction: none (the best cross-validated Eq. 13, {best:.4f} m, is not "
            f"below the uncorrected output's {report['uncorrected_error']:.4f} m; "
            f"{report['groups']} groups, {report['frames']} frames)"
        )
    chosen = report["cv_error"][f"{report['penalty']:g}/{report['smoothing']:g}"]
    return (
        f"output correction: penalty {report['penalty']:g}, smoothing {report['smoothing']:g}; "
        f"cross-validated Eq. 13 {chosen:.4f} m against the uncorrected output's "
        f"{report['uncorrected_error']:.4f} m ({report['groups']} groups, "
        f"{report['frames']} frames)"
    )
