"""Pose-space sampler: a ridge model of the truth's offset from the anchor, in the pose.

The samplers of :mod:`policies.supervised` read a frame's observation and output an offset in
that frame's own whitened latent axes. Those axes are a local PCA of the frame's candidates, so
the same coordinate means another direction of the body on every frame, and a model of them
learns little that carries over to new subjects (issue 19). This sampler learns in a fixed
coordinate system instead: the frame's normalised pose (root at the origin, facing +Z; the
observation's own frame).

Model
-----
For each frame, the anchor's pose ``x_a = decode(anchor)`` (the closed-form point,
:func:`policies.sampler.quadratic_anchor`) and the regressors of :func:`_regressors`: the
anchor pose, the sensor pose, the continuity prediction and the previous reconstruction each as
an offset from the anchor pose (zero when missing), the reliability and its three terms, the
bone lengths and the context. A ridge regression (standardised regressors) predicts
``delta``, the offset of the target pose from ``x_a``; ``x_a + delta`` is the learned pose.
The Gaussian's mean is the point of the frame's latent space that fits it:

* with a *pose weight* ``w > 0`` (the model's ``hyperparameters["pose_weight"]``), the
  minimiser of the closed form's quadratic energy with the learned pose in place of the
  sensor pose, every joint at reliability ``w``, and the closed form's motion term (FPG
  Eq. 14) towards the continuity prediction
  (:func:`fpg_gym.reconstruct.closed_form.quadratic_minimiser`): the motion term keeps the
  point steady from frame to frame, as it keeps the anchor;
* with ``w = 0`` (and in models saved without one), the anchor moved by ``delta`` as closely
  as the frame's latent space allows, measured on the bone vectors (Shum et al. 2013 Eq. 9 is
  linear, ``decode(z) = m + (s z) B``, and FPG Eq. 13 scores bone vectors: a least-squares
  solve per frame); with no motion term it shakes more than the anchor.

Its spread per latent axis is the root-mean-square error of out-of-group means.

The target is the ground truth's latent point of ``collect_imitation_data``: with
``target="bones"`` (the default of ``fpg-gym train-sampler --kind linear``) the point whose
bone directions at the frame's bone lengths are the truth's, which is what Eq. 13 scores after
the reconstructor gives the output those lengths (:func:`policies.imitation.truth_latent`).
:func:`fit_linear` chooses the penalty and the pose weight by leave-one-group-out
cross-validation (groups: subjects or sets of takes) and fits on every group. Deterministic:
no seed changes the model.

``learned:`` and ``learned+search:`` pick among their points by posterior (:data:`SELECTION`),
because a lower energy is not a more accurate pose on real data.

A model may carry a learned correction of the reconstructor's output
(:mod:`policies.output_correction`, :meth:`LinearPoseSampler.with_correction`), fitted on the
sampler's own outputs of its training recordings: ``learned:`` and ``learned+search:`` then
bring it to the reconstructor, which applies it after the output
(:mod:`fpg_gym.reconstruct.output_correction`).

Needs numpy only (no torch). Saved as ``MODEL.json`` (:class:`~policies.sampler.SamplerSpec`,
kind ``"linear"``; the correction's settings in ``hyperparameters["output_correction"]``) and
``MODEL.npz`` (arrays only, the correction's prefixed ``correction_``; read with
``allow_pickle=False``).
"""

from __future__ import annotations

import os
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import atomic_path
from fpg_gym.env_observation import CONTEXT_NAMES
from fpg_gym.io.npz import check_npz
from fpg_gym.reconstruct.closed_form import quadratic_minimiser
from policies.output_correction import CORRECTION_ARRAYS, RidgeOutputCorrection
from policies.ridge import fit_ridge, predict_ridge, ridge_sums
from policies.sampler import (
    DEFAULT_FEATURES,
    FeatureMap,
    GaussianSampler,
    SamplerSpec,
    check_model_values,
    model_paths,
)

__all__ = [
    "LINEAR_FEATURES",
    "LINEAR_WEIGHTS_SUFFIX",
    "PENALTIES",
    "POSE_WEIGHTS",
    "SELECTION",
    "LinearPoseSampler",
    "fit_linear",
]

#: Observation fields the linear sampler reads (its :class:`~policies.sampler.FeatureMap`):
#: the poses, reliabilities, bone lengths, latent space and context, not the fields in the
#: frame's own latent coordinates.
LINEAR_FEATURES: tuple[str, ...] = tuple(
    name for name in DEFAULT_FEATURES if not name.startswith(("x0", "z_", "candidate_"))
)
#: Suffix of the linear sampler's weights (a numpy ``.npz`` of arrays).
LINEAR_WEIGHTS_SUFFIX = ".npz"
#: Ridge penalties tried by cross-validation (standardised regressors).
PENALTIES: tuple[float, ...] = (1.0, 10.0, 100.0, 1000.0, 10000.0, 100000.0)
#: How ``learned:`` and ``learned+search:`` pick among their points with a linear sampler
#: (:class:`policies.learned_optimizers.LearnedSampler`): by posterior, the learned Gaussian as
#: prior with weight 1, the anchor not among the points. A point a standard deviation from the
#: mean on each of ``d`` axes then pays about ``d / 2`` (10 at the defaults), far more than the
#: energy differences between such points (below 1), so the recommendation is in practice the
#: learned mean: on held-out data a lower energy was not a more accurate pose (with weight
#: 0.01 the draws the energy picked added jitter on UI-PRMD and error on the embedded clips).
SELECTION: dict[str, Any] = {"prior_weight": 1.0, "anchor": False}
#: The :attr:`LinearPoseSampler.pose_weight` values tried by cross-validation (0: the learned
#: offset moved into the latent space alone, without the closed form's motion term).
POSE_WEIGHTS: tuple[float, ...] = (0.0, 0.1, 0.25, 0.5, 1.0, 2.0)
#: Arrays of a model file and their shapes (``F`` regressors, ``L`` latent axes, pose size 60).
_ARRAYS = ("regressor_mean", "regressor_scale", "weights", "bias", "std")
#: Prefix of the output correction's arrays in a model file.
_CORRECTION_PREFIX = "correction_"


def _fields(feature_map: FeatureMap, features: np.ndarray) -> dict[str, np.ndarray]:
    """The named parts ``(n, ...)`` of feature rows ``(n, F)`` (:meth:`FeatureMap.split`:
    each field flat, the anchor actions ``(n, L)`` as ``"anchor"``), with the mask of the axes
    in use ``(n, L)`` (``"mask"``), the principal directions scaled by their spread
    ``(n, L, 60)``, zero on unused axes (``"axes"``), and the anchor's pose ``(n, 60)``
    (``"anchor_pose"``)."""
    out = feature_map.split(features)
    out["mask"] = out["latent_mask"] > 0.5
    basis = out["latent_basis"].reshape(len(features), feature_map.layout.latent_dim, -1)
    out["axes"] = basis * np.where(out["mask"], out["latent_std"], 0.0)[:, :, None]
    out["anchor_pose"] = _decode(out, out["anchor"], feature_map.action_scale)
    return out


def _decode(fields: dict[str, np.ndarray], actions: np.ndarray, scale: float) -> np.ndarray:
    """Normalised poses ``(n, 60)`` of absolute actions ``(n, L)`` (``scale`` whitened units
    per action unit): ``m + (s z) B``."""
    z = scale * np.asarray(actions, dtype=np.float64)
    return fields["latent_mean"] + np.einsum("nl,nlp->np", z, fields["axes"])


def _encode_offset(
    fields: dict[str, np.ndarray], delta: np.ndarray, spec: SamplerSpec, design: Any = None
) -> Any:
    """Actions ``(n, L)`` that move a point by pose offsets ``delta`` ``(n, 60)`` as closely as
    each frame's latent space allows, measured on the bone vectors (FPG Eq. 13 scores bone
    vectors, and the reconstructor keeps only the bones' directions): zero on unused axes.
    ``design``: the frames' :func:`~fpg_gym.core.poses.latent_bone_design` when the caller
    has it."""
    design = pose_utils.latent_bone_design(fields["axes"]) if design is None else design
    return (
        pose_utils.fit_bone_vectors(design, pose_utils.flat_bone_vectors(delta)) / spec.action_scale
    )


def _fit_pose(
    spec: SamplerSpec, fields: dict[str, np.ndarray], offsets: np.ndarray, weight: float
) -> np.ndarray:
    """Mean actions ``(n, L)`` relative to the anchor of the closed form fitted to the learned
    pose: the minimiser of the closed form's quadratic energy with the learned pose
    (the anchor's pose plus ``offsets`` ``(n, 60)``) in place of the sensor pose, every joint
    at reliability ``weight``, and its motion term (FPG Eq. 14) towards the continuity
    prediction, which keeps the point steady from frame to frame."""
    scale, mask = spec.action_scale, fields["mask"]
    pose = fields["anchor_pose"] + offsets
    fitted = quadratic_minimiser(
        pose,
        np.full_like(fields["reliability"], weight),
        fields["latent_mean"],
        fields["latent_basis"].reshape(len(mask), spec.latent_dim, -1),
        fields["latent_std"],
        prediction=fields["prediction"],
        has_prediction=fields["context"][:, CONTEXT_NAMES.index("has_prediction")] > 0.5,
        mask=mask,
        weights=spec.energy_weights,
        style=spec.anchor_style,
    )
    return np.where(mask, fitted / scale - fields["anchor"], 0.0)


def _regressors(fields: dict[str, np.ndarray]) -> np.ndarray:
    """The regressors ``(n, R)``: the anchor pose; the sensor pose, the continuity prediction
    and the previous reconstruction minus the anchor pose (the last two zero when the frame has
    no prediction); the reliability and its terms; the bone lengths; the context."""
    anchor_pose = fields["anchor_pose"]
    history = fields["context"][:, [CONTEXT_NAMES.index("has_prediction")]] > 0.5
    return np.concatenate(
        [
            anchor_pose,
            fields["kinect"] - anchor_pose,
            np.where(history, fields["prediction"] - anchor_pose, 0.0),
            np.where(history, fields["previous"] - anchor_pose, 0.0),
            fields["reliability"],
            fields["reliability_terms"],
            fields["bone_lengths"],
            fields["context"],
        ],
        axis=1,
    )


class LinearPoseSampler(GaussianSampler):
    """The linear pose-space sampler (module docstring); build one with :func:`fit_linear`.

    Parameters
    ----------
    spec : SamplerSpec
        Kind ``"linear"``, absolute actions, features :data:`LINEAR_FEATURES`.
    arrays : dict
        ``regressor_mean``, ``regressor_scale`` ``(R,)``, ``weights`` ``(R, 60)``, ``bias``
        ``(60,)`` and ``std`` ``(L,)`` (action units).
    """

    def __init__(self, spec: SamplerSpec, arrays: dict[str, np.ndarray], seed: int | None = 0):
        if spec.kind != "linear" or spec.action_mode != "absolute" or spec.anchor == "none":
            raise ValueError(
                "a linear sampler needs kind 'linear', action_mode 'absolute' and an anchor; "
                f"got {spec.kind!r}, {spec.action_mode!r}, {spec.anchor!r}"
            )
        super().__init__(spec, seed)
        self.arrays = {name: np.asarray(arrays[name], dtype=np.float64) for name in _ARRAYS}
        self.output_correction: RidgeOutputCorrection | None = None
        settings = spec.hyperparameters.get("output_correction")
        if settings is not None:
            self.output_correction = RidgeOutputCorrection(
                {name: arrays[_CORRECTION_PREFIX + name] for name in CORRECTION_ARRAYS},
                float(settings["smoothing"]),
                float(settings["penalty"]),
            )

    def with_correction(
        self, correction: RidgeOutputCorrection | None, report: dict[str, Any] | None = None
    ) -> LinearPoseSampler:
        """This sampler with a learned output correction (None: without one); ``report``
        (:func:`policies.output_correction.fit_output_correction`'s) is kept in the spec."""
        settings = dict(self.spec.hyperparameters)
        settings.pop("output_correction", None)
        if correction is not None:
            settings["output_correction"] = {
                "penalty": correction.penalty,
                "smoothing": correction.smoothing,
                **({} if report is None else {"report": report}),
            }
        self.spec.hyperparameters = settings
        self.output_correction = correction
        return self

    def _all_arrays(self) -> dict[str, np.ndarray]:
        """The arrays a model file stores (the correction's prefixed, when it has one)."""
        arrays = {name: self.arrays[name] for name in _ARRAYS}
        if self.output_correction is not None:
            for name in CORRECTION_ARRAYS:
                arrays[_CORRECTION_PREFIX + name] = self.output_correction.arrays[name]
        return arrays

    @property
    def pose_weight(self) -> float:
        """Reliability given to the learned pose when the closed form is fitted to it
        (:func:`_fit_pose`; 0: no closed form, the learned offset moved into the latent space on
        the bone vectors)."""
        return float(self.spec.hyperparameters.get("pose_weight", 0.0))

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (relative to the anchor) and std ``(n, L)``: the point of each frame's latent
        space that fits the learned pose (the closed form fitted to it, or with no
        :attr:`pose_weight` the offset moved on the bone vectors), and the cross-validated
        spread."""
        fields = _fields(self.features, features)
        offsets = predict_ridge(self.arrays, _regressors(fields))
        if self.pose_weight > 0.0:
            mean = _fit_pose(self.spec, fields, offsets, self.pose_weight)
        else:
            mean = _encode_offset(fields, offsets, self.spec)
        std = np.where(fields["mask"], self.arrays["std"], 0.0)
        return mean, np.maximum(std, 1e-6)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``MODEL.npz`` (arrays) and ``MODEL.json``; returns the JSON's path."""
        json_path, stem = model_paths(path)
        weights = stem.with_name(stem.name + LINEAR_WEIGHTS_SUFFIX)
        with atomic_path(weights) as temporary, open(temporary, "wb") as handle:
            arrays: dict[str, Any] = self._all_arrays()
            np.savez(handle, **arrays)
        self.spec.weights = weights.name
        return self.spec.save(json_path)

    @classmethod
    def load_weights(
        cls, spec: SamplerSpec, weights: str | os.PathLike[str], *, seed: int | None = 0
    ) -> LinearPoseSampler:
        """A sampler from ``spec`` and its ``.npz`` (``allow_pickle=False``).

        Raises
        ------
        DataFormatError
            If the file is not an ``.npz`` of the arrays and shapes ``spec`` describes.
        """
        feature_map = spec.feature_map()
        size = _regressors(_fields(feature_map, np.zeros((1, feature_map.size)))).shape[1]
        shapes = {
            "regressor_mean": (size,),
            "regressor_scale": (size,),
            "weights": (size, 60),
            "bias": (60,),
            "std": (spec.latent_dim,),
        }
        if spec.hyperparameters.get("output_correction") is not None:
            shapes.update({_CORRECTION_PREFIX + k: v for k, v in CORRECTION_ARRAYS.items()})
        names = list(shapes)
        # Shapes and sizes from the array headers, before anything is inflated.
        try:
            check_npz(weights, names, shapes=shapes)
        except DataFormatError as error:
            raise DataFormatError(
                weights, f"not a linear sampler's arrays ({error.reason})", field=error.field
            ) from None
        try:
            with np.load(weights, allow_pickle=False) as data:
                arrays = {name: np.array(data[name], dtype=np.float64) for name in names}
        except (OSError, ValueError, KeyError, EOFError, zlib.error, zipfile.BadZipFile) as error:
            raise DataFormatError(weights, f"not a linear sampler's arrays ({error})") from None
        for name, shape in shapes.items():
            if arrays[name].shape != shape:
                raise DataFormatError(
                    weights, f"expected shape {shape}, got {arrays[name].shape}", field=name
                )
            check_model_values(weights, name, arrays[name])
        if np.any(arrays["regressor_scale"] <= 0):
            raise DataFormatError(weights, "expected positive scales", field="regressor_scale")
        if np.any(arrays["std"] < 0):
            raise DataFormatError(weights, "expected non-negative spreads", field="std")
        try:  # the correction's settings and scales: RidgeOutputCorrection checks them
            return cls(spec, arrays, seed)
        except (TypeError, KeyError, ValueError) as error:
            raise DataFormatError(weights, f"output correction: {error}") from None


def _bone_errors(actions: np.ndarray, part: dict[str, Any], spec: SamplerSpec) -> np.ndarray:
    """Per frame, FPG Eq. 13 between the anchor moved by mean ``actions`` ``(n, L)`` (relative
    to the anchor) and the target, both in the frames' latent spaces."""
    moved = np.einsum("nbl,nl->nb", part["design"], spec.action_scale * actions)
    miss = (moved - part["target_bones"]).reshape(len(moved), -1, 3)
    return np.linalg.norm(miss, axis=2).mean(axis=1)


def _shake(actions: np.ndarray, part: dict[str, Any], spec: SamplerSpec) -> np.ndarray:
    """Per frame with two predecessors in its episode, the mean joint length of the second
    difference of the poses the anchor moved by mean ``actions`` decodes to (m per frame²; the
    jitter of :func:`fpg_gym.core.metrics.jitter` before the output stage, in the frames' normalised
    poses)."""
    fields, episodes = part["fields"], part["episodes"]
    poses = _decode(fields, fields["anchor"] + actions, spec.action_scale)
    poses = poses.reshape(len(actions), -1, 3)
    steady = (episodes[2:] == episodes[1:-1]) & (episodes[1:-1] == episodes[:-2])
    second = poses[2:] - 2.0 * poses[1:-1] + poses[:-2]
    return np.linalg.norm(second, axis=2).mean(axis=1)[steady]


def _regression_data(
    spec: SamplerSpec, feature_map: FeatureMap, observations: np.ndarray, actions: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """A group's fields (:func:`_fields`), regressors ``(n, R)`` and targets ``(n, 60)`` (the
    truth actions' poses minus the anchor's)."""
    fields = _fields(feature_map, feature_map.transform(observations)[0])
    targets = _decode(fields, actions, spec.action_scale) - fields["anchor_pose"]
    return fields, _regressors(fields), targets


def fit_linear(
    spec: SamplerSpec,
    groups: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    *,
    penalties: Sequence[float] = PENALTIES,
    pose_weights: Sequence[float] = POSE_WEIGHTS,
) -> tuple[LinearPoseSampler, dict[str, Any]]:
    """Fit the linear sampler on groups of ``(observations, truth actions, episodes)``.

    Leave-one-group-out cross-validation (groups: subjects, or sets of takes, so that each
    choice is made on data no fit saw) chooses, on the out-of-group means:

    1. the ridge penalty, by the mean FPG Eq. 13 in the frames' latent spaces of the learned
       offsets moved into them (:func:`_encode_offset`);
    2. then the :attr:`LinearPoseSampler.pose_weight`: the lowest mean Eq. 13 among the
       weights whose means shake no more than the anchor's (:func:`_shake`, averaged over the
       frames), else the steadiest. The motion term's target is the continuity prediction of
       the collected streams (which followed the anchor), so this is an open-loop estimate.

    The spread per latent axis is the root-mean-square error of the chosen settings'
    out-of-group means. The model is then fitted on every group.

    Parameters
    ----------
    spec : SamplerSpec
        Kind ``"linear"``; its hyper-parameters receive ``penalty``, ``pose_weight`` and
        ``selection`` (:data:`SELECTION`).
    groups : sequence of (ndarray (n, N), ndarray (n, L), ndarray (n,))
        Observations, ground-truth actions (``collect_imitation_data`` with target ``"bones"``
        or ``"truth"``) and each frame's episode (its consecutive frames are a stream), at
        least two groups.
    penalties, pose_weights : sequence of float
        The ridge penalties and pose weights tried.

    Returns
    -------
    sampler : LinearPoseSampler
    report : dict
        ``penalty``, ``cv_error`` (m, by penalty), ``pose_weight``, ``cv_pose`` (by pose
        weight: ``error`` in m and ``shake`` in m per frame²), ``anchor_error`` and
        ``anchor_shake`` (the anchor's in the same measures), ``frames``, ``groups``.
    """
    _check_linear_inputs(groups, penalties, pose_weights)
    parts = _group_parts(spec, groups)
    frames = sum(len(p["regressors"]) for p in parts)
    sums = [ridge_sums(p["regressors"], p["targets"]) for p in parts]
    errors, penalty, offsets = _choose_penalty(spec, parts, sums, penalties)
    anchor = [np.zeros_like(p["actions"]) for p in parts]
    anchor_error = _mean_over(_bone_errors, anchor, parts, spec)
    anchor_shake = _mean_over(_shake, anchor, parts, spec)
    candidates = {}
    for weight in pose_weights:
        means = [
            _fit_pose(spec, part["fields"], offset, weight)
            if weight > 0.0
            else _encode_offset(part["fields"], offset, spec, part["design"])
            for offset, part in zip(offsets, parts, strict=True)
        ]
        candidates[weight] = (
            _mean_over(_bone_errors, means, parts, spec),
            _mean_over(_shake, means, parts, spec),
            means,
        )
    steady = [w for w, (_, shake, _) in candidates.items() if shake <= anchor_shake]
    if steady:
        pose_weight = min(steady, key=lambda w: candidates[w][0])
    else:
        pose_weight = min(candidates, key=lambda w: candidates[w][1])
    std = _spread(candidates[pose_weight][2], parts, spec.latent_dim)
    spec.hyperparameters = {
        **spec.hyperparameters,
        "penalty": penalty,
        "pose_weight": pose_weight,
        "selection": dict(SELECTION),
    }
    sampler = LinearPoseSampler(spec, {**fit_ridge(sums, penalty), "std": std})
    report = {
        "penalty": penalty,
        "cv_error": errors,
        "pose_weight": pose_weight,
        "cv_pose": {f"{w:g}": {"error": e, "shake": j} for w, (e, j, _) in candidates.items()},
        "anchor_error": anchor_error,
        "anchor_shake": anchor_shake,
        "frames": frames,
        "groups": len(parts),
    }
    return sampler, report


def _check_linear_inputs(
    groups: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
    penalties: Sequence[float],
    pose_weights: Sequence[float],
) -> None:
    """Raise ``ValueError`` on :func:`fit_linear` groups or settings it cannot use."""
    if len(groups) < 2:
        raise ValueError(f"groups: expected at least 2 for cross-validation, got {len(groups)}")
    if any(len(group) != 3 for group in groups):
        raise ValueError("groups: expected (observations, actions, episodes) triples")
    if not penalties or min(penalties) < 0:
        raise ValueError(f"penalties: expected non-negative values, got {list(penalties)}")
    if not pose_weights or not all(np.isfinite(w) and w >= 0 for w in pose_weights):
        raise ValueError(f"pose_weights: expected finite values >= 0, got {list(pose_weights)}")


def _group_parts(
    spec: SamplerSpec, groups: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]
) -> list[dict[str, Any]]:
    """Each group's regression data (:func:`_regression_data`), target bone vectors, latent
    bone design, actions and episodes."""
    feature_map = spec.feature_map()
    parts: list[dict[str, Any]] = []
    for observations, actions, episodes in groups:
        fields, regressors, targets = _regression_data(spec, feature_map, observations, actions)
        parts.append(
            {
                "regressors": regressors,
                "targets": targets,
                "target_bones": pose_utils.flat_bone_vectors(targets),
                "design": pose_utils.latent_bone_design(fields["axes"]),
                "fields": fields,
                "actions": np.asarray(actions, dtype=np.float64),
                "episodes": np.asarray(episodes),
            }
        )
    return parts


def _mean_over(
    measure: Any, means: list[np.ndarray], parts: list[dict[str, Any]], spec: SamplerSpec
) -> float:
    """``measure``'s mean over every group's frames of its out-of-group means."""
    values = [measure(mean, part, spec) for mean, part in zip(means, parts, strict=True)]
    return float(np.concatenate(values).mean())


def _choose_penalty(
    spec: SamplerSpec,
    parts: list[dict[str, Any]],
    sums: list[Any],
    penalties: Sequence[float],
) -> tuple[dict[str, float], float, list[np.ndarray]]:
    """The cross-validated FPG Eq. 13 of each ridge ``penalty`` (by ``f"{penalty:g}"``), the
    lowest's penalty and each group's out-of-group offsets with it."""
    errors: dict[str, float] = {}
    chosen: tuple[float, float, list[np.ndarray]] | None = None
    for penalty in penalties:
        offsets = [
            predict_ridge(fit_ridge(sums[:g] + sums[g + 1 :], penalty), part["regressors"])
            for g, part in enumerate(parts)
        ]
        means = [
            _encode_offset(part["fields"], offset, spec, part["design"])
            for offset, part in zip(offsets, parts, strict=True)
        ]
        errors[f"{penalty:g}"] = error = _mean_over(_bone_errors, means, parts, spec)
        if chosen is None or error < chosen[0]:
            chosen = (error, penalty, offsets)
    assert chosen is not None
    _, penalty, offsets = chosen
    return errors, penalty, offsets


def _spread(means: list[np.ndarray], parts: list[dict[str, Any]], latent_dim: int) -> np.ndarray:
    """The spread per latent axis: the root-mean-square out-of-group error of the chosen
    settings' means (the median of the used axes' on unused ones)."""
    squares, counts = np.zeros(latent_dim), np.zeros(latent_dim)
    for mean, part in zip(means, parts, strict=True):
        mask = part["fields"]["mask"]
        miss = part["actions"] - (part["fields"]["anchor"] + mean)
        squares += (np.where(mask, miss, 0.0) ** 2).sum(axis=0)
        counts += mask.sum(axis=0)
    used = counts > 0
    std = np.sqrt(squares / np.maximum(counts, 1))
    return np.where(used, std, float(np.median(std[used])) if used.any() else 1.0)


def describe_fit(report: dict[str, Any]) -> str:
    """One line on :func:`fit_linear`'s ``report``: the chosen settings and their
    cross-validated errors against the anchor's."""
    chosen = report["cv_error"][f"{report['penalty']:g}"]
    weighted = report["cv_pose"][f"{report['pose_weight']:g}"]["error"]
    return (
        f"linear sampler: penalty {report['penalty']:g}, pose weight "
        f"{report['pose_weight']:g}; cross-validated Eq. 13 in the latent spaces "
        f"{chosen:.4f} m with the offset alone, {weighted:.4f} m with the pose weight, "
        f"against the anchor's {report['anchor_error']:.4f} m"
    )
