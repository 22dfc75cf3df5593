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
``delta``, the offset of the target pose from ``x_a``. The Gaussian's mean is the anchor moved
by ``delta`` as closely as the frame's latent space allows, measured on the bone vectors
(Shum et al. 2013 Eq. 9 is linear, ``decode(z) = m + (s z) B``, and FPG Eq. 13 scores bone
vectors: a least-squares solve per frame). With a *fusion* weight ``w`` set in the model's
``hyperparameters["fusion"]`` (none by default) the mean is then the minimiser of the closed
form's quadratic energy (its sensor and motion terms) plus ``w |(z - mu) / sigma|^2``
(:func:`fpg_gym.reconstruct.closed_form.quadratic_minimiser`'s prior): steadier, less far
from the anchor. Its spread per latent axis is the root-mean-square error of out-of-group means.

The target is the ground truth's latent point of ``collect_imitation_data``: with
``target="bones"`` (the default of ``fpg-gym train-sampler --kind linear``) the point whose
bone directions at the frame's bone lengths are the truth's, which is what Eq. 13 scores after
the reconstructor gives the output those lengths (:func:`policies.imitation.truth_latent`).
:func:`fit_linear` chooses the penalty by leave-one-group-out cross-validation (groups:
subjects or sets of takes) and fits on every group. Deterministic: no seed changes the model.

``learned:`` and ``learned+search:`` pick among their points by posterior (:data:`SELECTION`),
because a lower energy is not a more accurate pose on real data.

Needs numpy only (no torch). Saved as ``MODEL.json`` (:class:`~policies.sampler.SamplerSpec`,
kind ``"linear"``) and ``MODEL.npz`` (arrays only, read with ``allow_pickle=False``).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym import poses as pose_utils
from fpg_gym.env_observation import CONTEXT_NAMES
from fpg_gym.errors import DataFormatError
from fpg_gym.outputs import atomic_path
from fpg_gym.reconstruct.closed_form import quadratic_minimiser
from policies.sampler import DEFAULT_FEATURES, GaussianSampler, SamplerSpec, model_paths

__all__ = [
    "LINEAR_FEATURES",
    "LINEAR_WEIGHTS_SUFFIX",
    "PENALTIES",
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
#: Arrays of a model file and their shapes (``F`` regressors, ``L`` latent axes, pose size 60).
_ARRAYS = ("regressor_mean", "regressor_scale", "weights", "bias", "std")


def _fields(spec: SamplerSpec, features: np.ndarray) -> dict[str, np.ndarray]:
    """The named fields ``(n, ...)`` of feature rows ``(n, F)`` as
    :class:`~policies.sampler.FeatureMap` laid them out, the anchor actions ``(n, L)``
    (``"anchor"``), the mask of the axes in use ``(n, L)`` (``"mask"``) and the principal
    directions scaled by their spread ``(n, L, 60)``, zero on unused axes (``"axes"``)."""
    layout = spec.layout
    out: dict[str, np.ndarray] = {}
    start = 0
    for name in spec.features:
        shape = layout.shapes[name]
        size = int(np.prod(shape))
        out[name] = features[:, start : start + size].astype(np.float64)
        start += size
    out["anchor"] = features[:, start : start + layout.latent_dim].astype(np.float64)
    out["mask"] = out["latent_mask"] > 0.5
    basis = out["latent_basis"].reshape(len(features), layout.latent_dim, -1)
    out["axes"] = basis * np.where(out["mask"], out["latent_std"], 0.0)[:, :, None]
    return out


def _decode(fields: dict[str, np.ndarray], actions: np.ndarray, spec: SamplerSpec) -> np.ndarray:
    """Normalised poses ``(n, 60)`` of absolute actions ``(n, L)``: ``m + (s z) B``."""
    z = spec.action_scale * np.asarray(actions, dtype=np.float64)
    return fields["latent_mean"] + np.einsum("nl,nlp->np", z, fields["axes"])


def _bone_offsets(poses: np.ndarray) -> np.ndarray:
    """Bone vectors ``(n, 57)`` of poses or pose offsets ``(n, 60)``."""
    return pose_utils.bone_vectors(poses.reshape(len(poses), -1, 3)).reshape(len(poses), -1)


def _bone_design(fields: dict[str, np.ndarray]) -> np.ndarray:
    """Each frame's bone vectors per unit of its whitened axes ``(n, 57, L)`` (zero on unused
    axes): the bone vectors of ``decode(z)`` are ``bones(m) + design z`` (Shum Eq. 9)."""
    axes = fields["axes"]
    bones = pose_utils.bone_vectors(axes.reshape(*axes.shape[:2], -1, 3))
    return bones.reshape(*axes.shape[:2], -1).transpose(0, 2, 1)


def _solve_bones(design: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Least-squares whitened offsets ``(n, L)`` whose bone vectors are closest to ``bones``
    ``(n, 57)`` (zero on unused axes, a tiny ridge keeps every system regular)."""
    gram = np.einsum("nbl,nbk->nlk", design, design)
    gram += 1e-9 * np.eye(design.shape[2])
    rhs = np.einsum("nbl,nb->nl", design, bones)
    return np.linalg.solve(gram, rhs[..., None])[..., 0]


def _encode_offset(
    fields: dict[str, np.ndarray], delta: np.ndarray, spec: SamplerSpec, design: Any = None
) -> Any:
    """Actions ``(n, L)`` that move a point by pose offsets ``delta`` ``(n, 60)`` as closely as
    each frame's latent space allows, measured on the bone vectors (FPG Eq. 13 scores bone
    vectors, and the reconstructor keeps only the bones' directions): zero on unused axes.
    ``design``: :func:`_bone_design` of ``fields`` when the caller has it."""
    design = _bone_design(fields) if design is None else design
    return _solve_bones(design, _bone_offsets(delta)) / spec.action_scale


def _fuse(
    spec: SamplerSpec,
    fields: dict[str, np.ndarray],
    mean: np.ndarray,
    std: np.ndarray,
    fusion: float,
) -> np.ndarray:
    """Mean actions ``(n, L)`` relative to the anchor: ``mean`` itself, or with a ``fusion``
    weight ``w`` the minimiser of the closed form's quadratic energy plus
    ``w |(z - mu) / sigma|^2`` (the anchor's sensor and motion terms keep the learned point
    steady; ``std``: the spread in action units ``(L,)``)."""
    if fusion <= 0.0:
        return mean
    scale, mask = spec.action_scale, fields["mask"]
    spread = scale * np.maximum(std, 1e-6)
    fused = quadratic_minimiser(
        fields["kinect"],
        fields["reliability"],
        fields["latent_mean"],
        fields["latent_basis"].reshape(len(mask), spec.latent_dim, -1),
        fields["latent_std"],
        prediction=fields["prediction"],
        has_prediction=fields["context"][:, CONTEXT_NAMES.index("has_prediction")] > 0.5,
        mask=mask,
        weights=spec.energy_weights,
        style=spec.anchor_style,
        prior_mean=scale * (fields["anchor"] + mean),
        prior_precision=np.broadcast_to(fusion / spread**2, mask.shape),
    )
    return np.where(mask, fused / scale - fields["anchor"], 0.0)


def _regressors(spec: SamplerSpec, fields: dict[str, np.ndarray]) -> np.ndarray:
    """The regressors ``(n, R)``: the anchor pose; the sensor pose, the continuity prediction
    and the previous reconstruction minus the anchor pose (the last two zero when the frame has
    no prediction); the reliability and its terms; the bone lengths; the context."""
    anchor_pose = _decode(fields, fields["anchor"], spec)
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

    @property
    def fusion(self) -> float:
        """Weight of the learned mean as a prior in the closed form (0: the mean alone)."""
        return float(self.spec.hyperparameters.get("fusion", 0.0))

    def offset(self, features: np.ndarray) -> np.ndarray:
        """The predicted pose offsets ``(n, 60)`` of the target from the anchor's pose, for
        feature rows ``(n, F)``."""
        return _predict(self.arrays, _regressors(self.spec, _fields(self.spec, features)))

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (relative to the anchor) and std ``(n, L)``: the predicted pose offset moved
        into each frame's latent space (fused with the closed form, see :attr:`fusion`), and
        the cross-validated spread."""
        fields = _fields(self.spec, features)
        offsets = _predict(self.arrays, _regressors(self.spec, fields))
        mean = _encode_offset(fields, offsets, self.spec)
        mean = _fuse(self.spec, fields, mean, self.arrays["std"], self.fusion)
        std = np.where(fields["mask"], self.arrays["std"], 0.0)
        return mean, np.maximum(std, 1e-6)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``MODEL.npz`` (arrays) and ``MODEL.json``; returns the JSON's path."""
        json_path, stem = model_paths(path)
        weights = stem.with_name(stem.name + LINEAR_WEIGHTS_SUFFIX)
        with atomic_path(weights) as temporary, open(temporary, "wb") as handle:
            arrays: dict[str, Any] = {name: self.arrays[name] for name in _ARRAYS}
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
        blank = _fields(spec, np.zeros((1, spec.feature_map().size)))
        size = _regressors(spec, blank).shape[1]
        shapes = {
            "regressor_mean": (size,),
            "regressor_scale": (size,),
            "weights": (size, 60),
            "bias": (60,),
            "std": (spec.latent_dim,),
        }
        try:
            with np.load(weights, allow_pickle=False) as data:
                arrays = {name: np.array(data[name], dtype=np.float64) for name in _ARRAYS}
        except (OSError, ValueError, KeyError) as error:
            raise DataFormatError(weights, f"not a linear sampler's arrays ({error})") from None
        for name, shape in shapes.items():
            if arrays[name].shape != shape or not np.all(np.isfinite(arrays[name])):
                raise DataFormatError(
                    weights,
                    f"expected finite values of shape {shape}, got {arrays[name].shape}",
                    field=name,
                )
        if np.any(arrays["regressor_scale"] <= 0):
            raise DataFormatError(weights, "expected positive scales", field="regressor_scale")
        return cls(spec, arrays, seed)


def _sums(x: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    return {"n": len(x), "sx": x.sum(0), "sy": y.sum(0), "xx": x.T @ x, "xy": x.T @ y}


def _ridge(sums: list[dict[str, Any]], penalty: float) -> dict[str, np.ndarray]:
    """The ridge fit of the pooled ``sums`` (regressors standardised by their pooled mean and
    spread, an unpenalised intercept)."""
    n = sum(s["n"] for s in sums)
    mean = sum(s["sx"] for s in sums) / n
    bias = sum(s["sy"] for s in sums) / n
    xx = sum(s["xx"] for s in sums) - n * np.outer(mean, mean)
    xy = sum(s["xy"] for s in sums) - n * np.outer(mean, bias)
    scale = np.sqrt(np.maximum(np.diag(xx) / n, 0.0))
    scale = np.where(scale > 1e-9, scale, 1.0)
    gram = xx / np.outer(scale, scale) + penalty * np.eye(len(mean))
    weights = np.linalg.solve(gram, xy / scale[:, None])
    return {"regressor_mean": mean, "regressor_scale": scale, "weights": weights, "bias": bias}


def _predict(model: dict[str, np.ndarray], regressors: np.ndarray) -> np.ndarray:
    scaled = (regressors - model["regressor_mean"]) / model["regressor_scale"]
    return scaled @ model["weights"] + model["bias"]


def _bone_errors(actions: np.ndarray, part: dict[str, Any], spec: SamplerSpec) -> np.ndarray:
    """Per frame, FPG Eq. 13 between the anchor moved by mean ``actions`` ``(n, L)`` (relative
    to the anchor) and the target, both in the frames' latent spaces."""
    moved = np.einsum("nbl,nl->nb", part["design"], spec.action_scale * actions)
    miss = (moved - part["target_bones"]).reshape(len(moved), -1, 3)
    return np.linalg.norm(miss, axis=2).mean(axis=1)


def fit_linear(
    spec: SamplerSpec,
    groups: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    penalties: Sequence[float] = PENALTIES,
) -> tuple[LinearPoseSampler, dict[str, Any]]:
    """Fit the linear sampler on groups of ``(observations, truth actions)`` pairs.

    Leave-one-group-out cross-validation (groups: subjects, or sets of takes, so that each
    choice is made on data no fit saw) chooses the ridge penalty by the mean FPG Eq. 13 of the
    out-of-group means in the frames' latent spaces; the spread per latent axis is the
    root-mean-square error of the chosen penalty's out-of-group means. The model is then
    fitted on every group.

    Parameters
    ----------
    spec : SamplerSpec
        Kind ``"linear"``; its hyper-parameters receive ``penalty`` and ``selection``
        (:data:`SELECTION`); a ``fusion`` weight already there is kept
        (:attr:`LinearPoseSampler.fusion`).
    groups : sequence of (ndarray (n, N), ndarray (n, L))
        Observations and ground-truth actions (``collect_imitation_data`` with target
        ``"bones"`` or ``"truth"``), at least two groups.
    penalties : sequence of float
        The ridge penalties tried.

    Returns
    -------
    sampler : LinearPoseSampler
    report : dict
        ``penalty``, ``cv_error`` (m, by penalty), ``anchor_error`` (m: the
        anchor's error in the same measure), ``frames``, ``groups``.
    """
    if len(groups) < 2:
        raise ValueError(f"groups: expected at least 2 for cross-validation, got {len(groups)}")
    if not penalties or min(penalties) < 0:
        raise ValueError(f"penalties: expected non-negative values, got {list(penalties)}")
    feature_map = spec.feature_map()
    parts = []
    for observations, actions in groups:
        fields = _fields(spec, feature_map.transform(observations)[0])
        targets = _decode(fields, actions, spec) - _decode(fields, fields["anchor"], spec)
        parts.append(
            {
                "regressors": _regressors(spec, fields),
                "targets": targets,
                "target_bones": _bone_offsets(targets),
                "design": _bone_design(fields),
                "fields": fields,
                "actions": np.asarray(actions, dtype=np.float64),
            }
        )
    frames = sum(len(p["regressors"]) for p in parts)
    sums = [_sums(p["regressors"], p["targets"]) for p in parts]

    def cv_error(means: list[np.ndarray]) -> float:
        """Mean Eq. 13 in the latent spaces of each group's out-of-group means."""
        total = sum(
            _bone_errors(mean, part, spec).sum() for mean, part in zip(means, parts, strict=True)
        )
        return float(total / frames)

    errors: dict[str, float] = {}
    chosen: tuple[float, float, list[np.ndarray]] | None = None
    for penalty in penalties:
        means = [
            _encode_offset(
                part["fields"],
                _predict(_ridge(sums[:g] + sums[g + 1 :], penalty), part["regressors"]),
                spec,
                part["design"],
            )
            for g, part in enumerate(parts)
        ]
        errors[f"{penalty:g}"] = error = cv_error(means)
        if chosen is None or error < chosen[0]:
            chosen = (error, penalty, means)
    assert chosen is not None
    _, penalty, means = chosen
    # The spread: the out-of-group error of the chosen penalty's means, per latent axis.
    squares, counts = np.zeros(spec.latent_dim), np.zeros(spec.latent_dim)
    for mean, part in zip(means, parts, strict=True):
        mask = part["fields"]["mask"]
        miss = part["actions"] - (part["fields"]["anchor"] + mean)
        squares += (np.where(mask, miss, 0.0) ** 2).sum(axis=0)
        counts += mask.sum(axis=0)
    used = counts > 0
    std = np.sqrt(squares / np.maximum(counts, 1))
    std = np.where(used, std, float(np.median(std[used])) if used.any() else 1.0)
    spec.hyperparameters = {
        **spec.hyperparameters,
        "penalty": penalty,
        "selection": dict(SELECTION),
    }
    sampler = LinearPoseSampler(spec, {**_ridge(sums, penalty), "std": std})
    report = {
        "penalty": penalty,
        "cv_error": errors,
        "anchor_error": cv_error([np.zeros_like(m) for m in means]),
        "frames": frames,
        "groups": len(parts),
    }
    return sampler, report
