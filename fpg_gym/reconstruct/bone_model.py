"""A sensor's bone vectors, corrected by a model learned from paired recordings.

A definition map (:class:`fpg_gym.definitions.DefinitionMap`) moves each joint by a constant
offset in its body part's frame; what a sensor gets wrong also depends on the pose (a Kinect
v2's knee and hip centres move with the flexion, its spine tilts with the trunk). On UI-PRMD's
real Kinect v2 streams paired with Vicon, the mapped sensor's bone vectors still miss the
truth's by 5 cm on average (FPG Eq. 13), a quarter of it in the bone lengths.

:class:`LinearBoneModel` predicts the missing part from the whole mapped pose: a ridge
regression (:mod:`fpg_gym.core.ridge`) from the pose, root-relative and turned to face +Z (60
numbers), and its unit bone directions (57), to the offsets between the truth's and the
sensor's bone vectors in that frame (57). The penalty is chosen by leave-one-group-out
cross-validation (groups: the recordings' subjects), the score being the mean bone-vector
error of the corrected poses. The fusion stage (:mod:`fpg_gym.reconstruct.fusion`) uses the
corrected bone vectors with the sensor's joint positions, so the correction improves bone
vectors without rebuilding the pose from them.

Files are ``.npz`` (no pickle) with a JSON ``metadata`` entry; the packaged Kinect v2 model
(:func:`packaged_bone_model`) was fitted on UI-PRMD's eight shared subjects.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import save_npz
from fpg_gym.core.ridge import fit_ridge, predict_ridge, ridge_sums
from fpg_gym.io.npz import load_npz

__all__ = ["FORMAT", "PENALTIES", "LinearBoneModel", "packaged_bone_model"]

#: ``format`` of a bone-model file's metadata.
FORMAT = "fpg-gym-bone-model-1"
#: Ridge penalties the cross-validation chooses from.
PENALTIES: tuple[float, ...] = (1e1, 1e2, 1e3, 1e4, 1e5)
_NUM_FEATURES = skeleton.NUM_JOINTS * 3 + skeleton.NUM_BONES * 3
_NUM_TARGETS = skeleton.NUM_BONES * 3
_DATA = Path(__file__).resolve().parents[1] / "data"
_ARRAYS = ("regressor_mean", "regressor_scale", "weights", "bias")
_ORIGIN = np.zeros(3)


def _features(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Regressors ``(N, 117)`` of poses ``(N, 20, 3)`` and each pose's turn ``(N, 3, 3)``
    (camera -> facing +Z, as row vectors: ``local = (p - root) @ turn``)."""
    yaw = pose_utils.facing_yaw(poses)
    turn = pose_utils.yaw_matrix(yaw)
    local = np.einsum("njc,ncd->njd", poses - poses[:, skeleton.ROOT : skeleton.ROOT + 1], turn)
    return _regressors(local), turn


def _regressors(local: np.ndarray) -> np.ndarray:
    """Regressors ``(N, 117)`` of poses ``(N, 20, 3)`` root-relative and facing +Z."""
    bones = pose_utils.bone_vectors(local)
    directions = bones / np.maximum(np.linalg.norm(bones, axis=-1, keepdims=True), 1e-9)
    count = len(local)
    return np.concatenate([local.reshape(count, -1), directions.reshape(count, -1)], 1)


def _targets(sensor: np.ndarray, truth: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Truth minus sensor bone vectors in each sensor pose's facing frame, ``(N, 57)``."""
    miss = pose_utils.bone_vectors(truth) - pose_utils.bone_vectors(sensor)
    return np.einsum("nbc,ncd->nbd", miss, turn).reshape(len(sensor), -1)


def _poses(value: npt.ArrayLike, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[1:] != (skeleton.NUM_JOINTS, 3):
        raise ValueError(f"{name}: expected shape (N, 20, 3), got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: NaN or inf value")
    return array


class LinearBoneModel:
    """Corrected bone vectors of a sensor's (mapped) poses (see the module docstring).

    Parameters
    ----------
    arrays : dict of ndarray
        The ridge fit: ``regressor_mean``, ``regressor_scale`` ``(117,)``, ``weights``
        ``(117, 57)``, ``bias`` ``(57,)`` (:func:`fpg_gym.core.ridge.fit_ridge`).
    source, target : str
        The definitions of the input poses and of the truth it was fitted on.
    info : dict
        JSON-serialisable facts (penalty, cross-validation scores, what it was fitted on).
    """

    def __init__(
        self,
        arrays: dict[str, np.ndarray],
        *,
        source: str,
        target: str,
        info: dict[str, Any] | None = None,
    ) -> None:
        shapes = {
            "regressor_mean": (_NUM_FEATURES,),
            "regressor_scale": (_NUM_FEATURES,),
            "weights": (_NUM_FEATURES, _NUM_TARGETS),
            "bias": (_NUM_TARGETS,),
        }
        model = {}
        for name, shape in shapes.items():
            value = np.asarray(arrays.get(name), dtype=np.float64)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"{name}: expected {shape} finite values, got {value.shape}")
            model[name] = value
        if np.any(model["regressor_scale"] <= 0):
            raise ValueError("regressor_scale: expected positive values")
        if np.abs(model["bias"]).max() > 0.5 or np.abs(model["weights"]).max() > 10.0:
            raise ValueError("weights: corrections beyond 0.5 m; not a sensor's bias")
        self._model = model
        self.source, self.target = str(source), str(target)
        self.info = dict(info or {})

    @classmethod
    def fit(
        cls,
        sensor_poses: npt.ArrayLike,
        truth_poses: npt.ArrayLike,
        groups: Sequence[str] | npt.ArrayLike,
        *,
        source: str,
        target: str,
        penalties: Sequence[float] = PENALTIES,
    ) -> LinearBoneModel:
        """Fit from paired poses of the same moments.

        Parameters
        ----------
        sensor_poses, truth_poses : array_like, shape (N, 20, 3)
            The (mapped) sensor and the reference system, in one space.
        groups : sequence of str, length N
            The group of each pair (e.g. its subject): the cross-validation leaves one group
            out at a time (one penalty, the largest, when there is a single group).
        source, target : str
            Names of the two definitions.
        penalties : sequence of float
            Candidates of the ridge penalty.
        """
        sensor = _poses(sensor_poses, "sensor_poses")
        truth = _poses(truth_poses, "truth_poses")
        labels = np.asarray(groups).astype(str)
        if truth.shape != sensor.shape or labels.shape != (len(sensor),):
            raise ValueError(
                f"fit: expected sensor and truth (N, 20, 3) and N groups, got {sensor.shape}, "
                f"{truth.shape}, {labels.shape}"
            )
        if not penalties:
            raise ValueError("penalties: expected at least one")
        features, turn = _features(sensor)
        targets = _targets(sensor, truth, turn)
        names = np.unique(labels)
        sums = {g: ridge_sums(features[labels == g], targets[labels == g]) for g in names}
        scores: dict[str, float] = {}
        if len(names) > 1:
            for penalty in penalties:
                errors = []
                for g in names:  # leave one group out (pooled sums: one small solve each)
                    model = fit_ridge([sums[h] for h in names if h != g], penalty)
                    miss = targets[labels == g] - predict_ridge(model, features[labels == g])
                    errors.append(np.linalg.norm(miss.reshape(-1, 3), axis=-1).mean())
                scores[f"{penalty:g}"] = float(np.mean(errors))
            best = float(min(penalties, key=lambda p: scores[f"{p:g}"]))
        else:
            best = float(max(penalties))
        before = float(np.linalg.norm(targets.reshape(-1, 3), axis=-1).mean())
        info = {
            "pairs": len(sensor),
            "groups": [str(g) for g in names],
            "penalty": best,
            "cross_validation_m": scores,
            "bone_error_before_m": round(before, 5),
        }
        return cls(fit_ridge(list(sums.values()), best), source=source, target=target, info=info)

    def corrections(self, poses: npt.ArrayLike) -> np.ndarray:
        """Predicted truth-minus-sensor bone vectors ``(N, 19, 3)`` in the poses' space."""
        return self._corrections(_poses(poses, "poses"))

    def _corrections(self, sensor: np.ndarray) -> np.ndarray:
        """:meth:`corrections` of checked poses ``(N, 20, 3)`` float64."""
        compiled = compiled_module("fpg_gym.core.compiled_poses") if len(sensor) == 1 else None
        if compiled is not None:
            # One pose (the fusion's, every frame): both turns by the compiled placement, the
            # products of the einsums below in their order (equal to the bit).
            pose = np.ascontiguousarray(sensor[0])
            yaw = float(pose_utils.facing_yaw(pose))
            local = compiled.place_pose(pose, pose[skeleton.ROOT], yaw, False)
            turned = predict_ridge(self._model, _regressors(local[None]))
            offsets = turned.reshape(skeleton.NUM_BONES, 3)
            return np.asarray(compiled.place_pose(offsets, _ORIGIN, yaw, True))[None]
        features, turn = _features(sensor)
        local = predict_ridge(self._model, features).reshape(len(sensor), skeleton.NUM_BONES, 3)
        return np.asarray(np.einsum("nbd,ncd->nbc", local, turn))

    def bone_vectors(self, pose: npt.ArrayLike) -> np.ndarray:
        """Corrected bone vectors ``(19, 3)`` of one pose ``(20, 3)`` (:class:`BoneModel`)."""
        sensor = _poses(pose, "pose")
        return np.asarray(pose_utils.bone_vectors(sensor)[0] + self._corrections(sensor)[0])

    # ------------------------------------------------------------------ files

    def save(self, path: str | Path) -> Path:
        """Write the model (``.npz``, no pickle, JSON metadata)."""
        metadata = {"format": FORMAT, "source": self.source, "target": self.target}
        arrays = {name: self._model[name].astype(np.float32) for name in _ARRAYS}
        arrays["metadata"] = np.array(json.dumps({**metadata, "info": self.info}))
        return save_npz(Path(path), arrays)

    @classmethod
    def load(cls, path: str | Path) -> LinearBoneModel:
        """Read a model written by :meth:`save`.

        Raises
        ------
        DataFormatError
            On a file that is not such a model (naming the file and what is wrong).
        """
        path = Path(path)
        arrays = load_npz(path)
        missing = [n for n in (*_ARRAYS, "metadata") if n not in arrays]
        if missing:
            raise DataFormatError(path, f"not a bone model: missing {missing}")
        try:
            metadata = json.loads(str(arrays["metadata"]))
        except json.JSONDecodeError as error:
            raise DataFormatError(path, f"invalid JSON ({error})", field="metadata") from None
        if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
            raise DataFormatError(path, f"not a bone model (format {FORMAT!r} expected)")
        try:
            return cls(
                {name: arrays[name] for name in _ARRAYS},
                source=str(metadata.get("source", "")),
                target=str(metadata.get("target", "")),
                info=metadata.get("info") if isinstance(metadata.get("info"), dict) else {},
            )
        except ValueError as error:
            raise DataFormatError(path, str(error)) from None

    def __repr__(self) -> str:
        return (
            f"LinearBoneModel({self.source} -> {self.target}, "
            f"penalty {self.info.get('penalty', '?')})"
        )


def packaged_bone_model(name: str) -> LinearBoneModel:
    """A bone model shipped with the package, by name (``"kinect-v2-to-vicon"``)."""
    path = _DATA / f"{name}-bones.npz"
    if not path.is_file():
        known = sorted(p.name[: -len("-bones.npz")] for p in _DATA.glob("*-bones.npz"))
        raise ValueError(f"bone model: unknown name {name!r}; packaged: {', '.join(known)}")
    return LinearBoneModel.load(path)
