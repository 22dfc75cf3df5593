"""The learned output correction of a linear sampler: data, fit and model (issue 19).

The reconstructor applies a correction model after its output
(:mod:`fpg_gym.reconstruct.output_correction`: the features, the targets and the causal
smoothing are defined there). This module fits one: a ridge regression (:mod:`policies.ridge`)
of the truth's joints minus the output's (the root included), from the outputs of the sampler it
will correct on recordings with ground truth (:func:`correction_data`: the sampler's outputs of
its own training recordings, each reconstructed as its training data were,
:class:`CorrectionSource`), its penalty and smoothing chosen by leave-one-group-out
cross-validation over groups of whole recordings (subjects, or sets of clips) on the corrected
outputs as the reconstructor gives them (smoothed, their lengths settled): the sum of FPG Eq. 13
and the mean joint distance (MPJPE) (:func:`fit_output_correction`). A linear sampler stores its
correction in its own files (:meth:`policies.pose_sampler.LinearPoseSampler.with_correction`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from tqdm import tqdm

from fpg_gym.core import metrics
from fpg_gym.reconstruct import Reconstructor
from fpg_gym.reconstruct.bones import BoneSettlingConfig
from fpg_gym.reconstruct.output_correction import (
    CORRECTION_FEATURES,
    correction_frames,
    settle_lengths,
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
CORRECTION_PENALTIES: tuple[float, ...] = (10.0, 100.0, 1e3, 1e4, 1e5, 1e6)
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
    """One group's frames: features ``(n, F)``, targets ``(n, 60)``, the outputs' normalised
    poses ``(n, 60)`` (:func:`~fpg_gym.reconstruct.output_correction.correction_frames`), each
    frame's episode ``(n,)`` (consecutive frames of a stream share one) and time ``(n,)``
    (seconds), the settling rule of the reconstructor that made them, and the jitter of a
    reference reconstruction of each episode (``(E,)`` m/s², in episode order; the steadiness
    a correction may not exceed, :func:`fit_output_correction`; empty: none)."""

    features: np.ndarray
    targets: np.ndarray
    local: np.ndarray
    episodes: np.ndarray
    timestamps: np.ndarray
    bones: BoneSettlingConfig = field(default_factory=BoneSettlingConfig)
    reference_jitter: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __len__(self) -> int:
        return len(self.targets)


def correction_data(
    reconstructor: Reconstructor,
    recordings: Sequence[Any],
    optimizer: Any,
    *,
    reference: Any = "closed-form",
    progress: bool = False,
    first_episode: int = 0,
) -> CorrectionData:
    """The frames a correction learns from: ``recordings`` (with ``ground_truth``)
    reconstructed with ``optimizer`` (the sampler to correct, without a correction: e.g.
    ``LearnedSampler(sampler, samples=1, correct_output=False)``), seed 0 each; and each
    recording's jitter reconstructed with ``reference`` (an optimiser or its name; the
    closed-form anchor by default, None: none).

    Raises
    ------
    ValueError
        If a recording has no ground truth.
    """
    parts: dict[str, list[np.ndarray]] = {
        "features": [],
        "targets": [],
        "local": [],
        "episodes": [],
        "timestamps": [],
    }
    steadiness: list[float] = []
    for number, recording in enumerate(
        tqdm(recordings, desc="correction data", unit="rec", disable=not progress, leave=False)
    ):
        truth = getattr(recording, "ground_truth", None)
        if truth is None:
            name = getattr(recording, "path", None) or f"recording {number}"
            raise ValueError(f"{name}: a correction learns from ground truth; this has none")
        result = reconstructor.reconstruct(recording, optimizer, rng=0)
        rows, target, local, _ = correction_frames(
            result.poses, recording, result.arrays()["reliability"]
        )
        parts["features"].append(rows)
        parts["targets"].append(target)
        parts["local"].append(local.reshape(len(local), -1))
        parts["episodes"].append(np.full(len(rows), first_episode + number))
        parts["timestamps"].append(np.asarray(recording.timestamps, dtype=np.float64)[: len(rows)])
        if reference is not None:
            poses = reconstructor.reconstruct(recording, reference, rng=0).poses
            shake = metrics.jitter(poses, timestamps=parts["timestamps"][-1])
            steadiness.append(float(np.nanmean(shake)) if len(poses) >= 3 else np.nan)
    if not recordings:
        empty = {"features": (0, CORRECTION_FEATURES), "targets": (0, 60), "local": (0, 60)}
        return CorrectionData(
            **{name: np.zeros(empty.get(name, (0,))) for name in parts},
            bones=reconstructor.config.bones,
        )
    arrays = {name: np.concatenate(values) for name, values in parts.items()}
    return CorrectionData(
        **arrays, bones=reconstructor.config.bones, reference_jitter=np.array(steadiness)
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
        ``LearnedSampler(sampler, samples=1, correct_output=False)``).
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


def _episode_figures(offsets: np.ndarray, data: CorrectionData) -> np.ndarray:
    """Each episode's ``(error, jitter)`` ``(E, 2)`` for the outputs moved by the (smoothed)
    ``offsets``, their lengths settled as the reconstructor settles them
    (:func:`~fpg_gym.reconstruct.output_correction.settle_lengths`): the mean FPG Eq. 13 plus
    the mean joint distance (MPJPE) against the truth, and the mean joint acceleration (m/s²,
    :func:`fpg_gym.core.metrics.jitter`); in the outputs' normalised frames, where all three are the
    camera space's."""
    local = data.local.reshape(len(data), -1, 3)
    truth = local + data.targets.reshape(local.shape)
    moved = local + offsets.reshape(local.shape)
    if np.any(offsets):
        moved = settle_lengths(moved, data.episodes, data.timestamps, data.bones)
    frame = metrics.frame_error(truth, moved) + metrics.joint_distances(truth, moved).mean(axis=1)
    starts = np.flatnonzero(np.r_[True, data.episodes[1:] != data.episodes[:-1]])
    out = []
    for start, stop in zip(starts, np.r_[starts[1:], len(frame)], strict=True):
        shake = metrics.jitter(moved[start:stop], timestamps=data.timestamps[start:stop])
        out.append((frame[start:stop].mean(), np.nanmean(shake) if len(shake) else np.nan))
    return np.array(out)


def fit_output_correction(
    groups: Sequence[CorrectionData],
    *,
    penalties: Sequence[float] = CORRECTION_PENALTIES,
    smoothing: Sequence[float] = CORRECTION_SMOOTHING,
    log: Callable[[str], None] | None = None,
) -> tuple[RidgeOutputCorrection | None, dict[str, Any]]:
    """Fit a correction; penalty and smoothing by leave-one-group-out cross-validation.

    Each setting is scored on the outputs corrected by a model fitted on the other groups, as
    the reconstructor corrects them (smoothed, lengths settled), by the mean over every group's
    episodes of FPG Eq. 13 plus MPJPE and of the jitter. The chosen setting is the most
    accurate of those that miss the truth less than the uncorrected outputs and shake no more
    than the reference reconstructions of the same recordings (``reference_jitter``: the
    anchor's, as :func:`policies.pose_sampler.fit_linear` keeps its means; without one, no
    more than the uncorrected outputs); it is then fitted on every group.
    When no setting qualifies there is no correction (what a group's data teach does not carry
    over to the others).

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
        ``penalty``, ``smoothing`` (None with no correction), ``cv_error`` (Eq. 13 + MPJPE,
        m) and ``cv_jitter`` (m/s²) by ``"penalty/smoothing"``, ``uncorrected_error`` and
        ``uncorrected_jitter`` (the outputs' own), ``jitter_budget`` (the steadiness kept),
        ``frames``, ``groups``.
    """
    _check_correction_inputs(groups, penalties, smoothing)
    sums = [ridge_sums(g.features, g.targets) for g in groups]

    def mean_figures(offsets: Sequence[np.ndarray]) -> tuple[float, float]:
        """The mean over every group's episodes of the error and the jitter."""
        figures = np.concatenate(
            [_episode_figures(o, g) for o, g in zip(offsets, groups, strict=True)]
        )
        return float(figures[:, 0].mean()), float(np.nanmean(figures[:, 1]))

    uncorrected, own = mean_figures([np.zeros_like(g.targets) for g in groups])
    references = [g.reference_jitter for g in groups]
    # The steadiness to keep: the reference's (the anchor's) where every group has one.
    if all(len(r) == len(np.unique(g.episodes)) for r, g in zip(references, groups, strict=True)):
        steady = float(np.nanmean(np.concatenate(references)))
    else:
        steady = own
    errors: dict[str, float] = {}
    jitters: dict[str, float] = {}
    for penalty in penalties:
        predicted = [
            predict_ridge(fit_ridge(sums[:g] + sums[g + 1 :], penalty), group.features)
            for g, group in enumerate(groups)
        ]
        for alpha in smoothing:
            key = f"{penalty:g}/{alpha:g}"
            errors[key], jitters[key] = mean_figures(
                [
                    smooth_corrections(p, g.episodes, alpha)
                    for p, g in zip(predicted, groups, strict=True)
                ]
            )
    # The most accurate of the settings that shake no more than the reference (or the outputs
    # they correct) and miss the truth less than the uncorrected outputs; else no correction.
    allowed = [k for k in errors if jitters[k] <= steady and errors[k] < uncorrected]
    chosen_penalty = chosen_alpha = None
    if allowed:
        best = min(allowed, key=lambda k: errors[k])
        chosen_penalty, chosen_alpha = (float(v) for v in best.split("/"))
    correction = (
        None
        if chosen_penalty is None or chosen_alpha is None
        else RidgeOutputCorrection(fit_ridge(sums, chosen_penalty), chosen_alpha, chosen_penalty)
    )
    report = {
        "penalty": chosen_penalty,
        "smoothing": chosen_alpha,
        "cv_error": errors,
        "cv_jitter": jitters,
        "uncorrected_error": uncorrected,
        "uncorrected_jitter": own,
        "jitter_budget": steady,
        "frames": int(sum(len(g) for g in groups)),
        "groups": len(groups),
    }
    if log is not None:
        log(describe_correction(report))
    return correction, report


def _check_correction_inputs(
    groups: Sequence[CorrectionData], penalties: Sequence[float], smoothing: Sequence[float]
) -> None:
    """Raise ``ValueError`` on :func:`fit_output_correction` groups or settings it cannot
    use."""
    if len(groups) < 2:
        raise ValueError(f"groups: expected at least 2 for cross-validation, got {len(groups)}")
    if any(len(g) == 0 for g in groups):
        raise ValueError("groups: expected frames in every group")
    if not penalties or min(penalties) < 0:
        raise ValueError(f"penalties: expected non-negative values, got {list(penalties)}")
    if not smoothing or not all(0.0 < a <= 1.0 for a in smoothing):
        raise ValueError(f"smoothing: expected values in (0, 1], got {list(smoothing)}")


def describe_correction(report: dict[str, Any]) -> str:
    """One line on :func:`fit_output_correction`'s ``report``."""
    own = (
        f"the uncorrected output's {report['uncorrected_error']:.4f} m, "
        f"{report['uncorrected_jitter']:.2f} m/s² (jitter kept below "
        f"{report['jitter_budget']:.2f}); {report['groups']} groups, {report['frames']} frames"
    )
    if report["penalty"] is None:
        best = min(report["cv_error"].values())
        return (
            "output correction: none (no setting both steady enough and more accurate than "
            f"the uncorrected output; the most accurate cross-validated Eq. 13 + MPJPE "
            f"{best:.4f} m, against {own})"
        )
    key = f"{report['penalty']:g}/{report['smoothing']:g}"
    return (
        f"output correction: penalty {report['penalty']:g}, smoothing {report['smoothing']:g}; "
        f"cross-validated Eq. 13 + MPJPE {report['cv_error'][key]:.4f} m, jitter "
        f"{report['cv_jitter'][key]:.2f} m/s², against {own}"
    )
