"""Joint definitions: map one system's body points onto another's (a sensor is not a database).

Every source names its points "Head", "Spine", "HipLeft", but places them differently: a Kinect
v2 ``Head`` is the head tip in UI-PRMD's export, a Kinect v1 ``Spine`` sits low on the trunk,
marker-derived joint centres (Vicon) sit centimetres away from both, and a mocap database has
its own rig. Bone lengths can be retargeted; definitions cannot. A :class:`DefinitionMap` moves
each joint by a constant offset expressed in a frame attached to the body part it belongs to::

    mapped(j) = p(j) + F_j(p) · o_j                     (o_j: 3 numbers per joint, metres)

Frames ``F_j`` (:func:`joint_frames`; columns: the body's left, up, forward):

* pelvis frame (HipCenter, Spine, HipLeft, HipRight): left = HipRight→HipLeft, up =
  HipCenter→ShoulderCenter made orthogonal to it, forward = left × up;
* thorax frame (ShoulderCenter, ShoulderLeft, ShoulderRight): left = ShoulderRight→
  ShoulderLeft, up = Spine→ShoulderCenter;
* every other joint: the frame of the bone that ends at it (for a hand: the forearm), i.e. the
  pelvis (legs) or thorax (arms, head) frame turned by the smallest rotation that takes the
  bone's rest direction onto its current direction (rest: thighs and shanks down, feet forward,
  upper arms outwards, forearms forward, head up) — smooth except when a bone points exactly
  opposite its rest direction.

The map is rigid-motion equivariant (the frames move with the body), exact to fit by least
squares from paired poses (:meth:`DefinitionMap.fit`: the offsets are a mean of residuals
expressed in the frames) and invertible by fixed-point iteration (:meth:`DefinitionMap.inverse`).
Files are JSON (:meth:`DefinitionMap.save`, :meth:`DefinitionMap.load`).

Examples
--------
>>> import numpy as np
>>> from fpg_gym.core import poses
>>> from fpg_gym.definitions import DefinitionMap
>>> pose = poses.rest_pose()
>>> offsets = np.zeros((20, 3)); offsets[3] = (0.0, 0.1, 0.0)   # head 10 cm further up
>>> head_up = DefinitionMap(offsets, source="a", target="b")
>>> float(np.round(head_up.apply(pose)[3, 1] - pose[3, 1], 6))
0.1
>>> fitted = DefinitionMap.fit(pose[None], head_up.apply(pose)[None], source="a", target="b")
>>> bool(np.allclose(fitted.offsets, offsets, atol=1e-6))
True
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import write_text
from fpg_gym.core.rotations import quaternion_to_matrix, shortest_arc
from fpg_gym.io.files import read_json

__all__ = [
    "FORMAT",
    "KINECT_V2_TO_VICON",
    "TRUNK_JOINTS",
    "ComposedMap",
    "DefinitionMap",
    "PoseMap",
    "fit_sensor_maps",
    "fit_to_database",
    "joint_frames",
    "load_map",
    "packaged_map",
    "packaged_map_names",
    "sensor_to_output_map",
    "symmetrise_offsets",
]

#: ``format`` entry of a definition-map JSON file.
FORMAT = "fpg-gym-definition-map-1"
#: Name of the packaged Kinect v2 -> Vicon joint-centre map (:func:`packaged_map`), fitted on
#: UI-PRMD subjects s01-s07 (``scripts/package_data.py``, see ``fpg_gym/data/README.md``).
KINECT_V2_TO_VICON = "kinect-v2-to-vicon"
_DATA = Path(__file__).resolve().parent / "data"

_J = skeleton.joint_index
_PELVIS = (_J("HipCenter"), _J("Spine"), _J("HipLeft"), _J("HipRight"))
_THORAX = (_J("ShoulderCenter"), _J("ShoulderLeft"), _J("ShoulderRight"))
_LEFT, _UP, _FORWARD = np.eye(3)
#: Joints whose frame follows a bone: (joint, the joint whose incoming bone turns the frame, base
#: frame "pelvis"/"thorax", that bone's rest direction in the base frame's (left, up, forward)
#: coordinates). Hands follow the forearm: the hand bone is short and its end poorly measured.
_BONE_FRAMES: tuple[tuple[int, int, str, np.ndarray], ...] = (
    (_J("Head"), _J("Head"), "thorax", _UP),
    (_J("ElbowLeft"), _J("ElbowLeft"), "thorax", _LEFT),
    (_J("WristLeft"), _J("WristLeft"), "thorax", _FORWARD),
    (_J("HandLeft"), _J("WristLeft"), "thorax", _FORWARD),
    (_J("ElbowRight"), _J("ElbowRight"), "thorax", -_LEFT),
    (_J("WristRight"), _J("WristRight"), "thorax", _FORWARD),
    (_J("HandRight"), _J("WristRight"), "thorax", _FORWARD),
    (_J("KneeLeft"), _J("KneeLeft"), "pelvis", -_UP),
    (_J("AnkleLeft"), _J("AnkleLeft"), "pelvis", -_UP),
    (_J("FootLeft"), _J("FootLeft"), "pelvis", _FORWARD),
    (_J("KneeRight"), _J("KneeRight"), "pelvis", -_UP),
    (_J("AnkleRight"), _J("AnkleRight"), "pelvis", -_UP),
    (_J("FootRight"), _J("FootRight"), "pelvis", _FORWARD),
)
_BONE_JOINTS = np.array([j for j, _, _, _ in _BONE_FRAMES])
_BONE_ENDS = np.array([end for _, end, _, _ in _BONE_FRAMES])
_BONE_ON_THORAX = np.array([base == "thorax" for _, _, base, _ in _BONE_FRAMES])
_BONE_REST = np.stack([rest for _, _, _, rest in _BONE_FRAMES])
_BONE_PARENTS = skeleton.PARENTS[_BONE_ENDS]
_PELVIS_JOINTS, _THORAX_JOINTS = np.array(_PELVIS), np.array(_THORAX)
#: The trunk frames' joints, in the order the compiled frames take them.
_TRUNK_JOINTS = tuple(
    _J(name)
    for name in (
        "HipLeft",
        "HipRight",
        "ShoulderCenter",
        "HipCenter",
        "ShoulderLeft",
        "ShoulderRight",
        "Spine",
    )
)
#: Joints where capture systems disagree most (the trunk and the head); limb joints are
#: anatomical joint centres in every system.
TRUNK_JOINTS: tuple[int, ...] = (*_PELVIS, *_THORAX, _J("Head"))
#: Left/right mirror of an offset in the (left, up, forward) frame coordinates.
_MIRROR_OFFSET = np.array([-1.0, 1.0, 1.0])


class PoseMap(Protocol):
    """Anything that maps poses ``(..., 20, 3)`` from one joint definition to another."""

    @property
    def source(self) -> str:
        """Definitions mapped from."""
        ...

    @property
    def target(self) -> str:
        """Definitions mapped to."""
        ...

    def apply(self, poses: npt.ArrayLike) -> np.ndarray:
        """The mapped poses, float64, same shape."""
        ...


def symmetrise_offsets(offsets: np.ndarray) -> np.ndarray:
    """Each left offset averaged with the mirror image of its right twin; midline joints do not
    move sideways (the body's definitions are symmetric)."""
    offsets = offsets.copy()
    left, right = skeleton.MIRROR_PAIRS[:, 0], skeleton.MIRROR_PAIRS[:, 1]
    mean = 0.5 * (offsets[left] + offsets[right] * _MIRROR_OFFSET)
    offsets[left] = mean
    offsets[right] = mean * _MIRROR_OFFSET
    middle = np.setdiff1d(np.arange(skeleton.NUM_JOINTS), skeleton.MIRROR_PAIRS.ravel())
    offsets[middle, 0] = 0.0
    return offsets


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9)


def _trunk_frame(left: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` with columns (left, up, forward), Gram-Schmidt from ``left``."""
    x = _unit(left)
    y = _unit(up - np.sum(up * x, axis=-1, keepdims=True) * x)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=-1)


def joint_frames(poses: npt.ArrayLike) -> np.ndarray:
    """The frame ``F_j`` of every joint (see the module docstring), ``(..., 20, 3, 3)``.

    Columns are the frame's left, up and forward axes in the poses' space.
    """
    p = np.asarray(poses, dtype=np.float64)
    if p.shape[-2:] != (skeleton.NUM_JOINTS, 3):
        raise ValueError(f"poses: expected shape (..., 20, 3), got {p.shape}")
    if p.shape == (skeleton.NUM_JOINTS, 3):
        compiled = compiled_module("fpg_gym.core.compiled_poses")
        frames_of_pose = None if compiled is None else _pose_frames(compiled, p)
        if frames_of_pose is not None:
            return frames_of_pose
    pelvis = _trunk_frame(
        p[..., _J("HipLeft"), :] - p[..., _J("HipRight"), :],
        p[..., _J("ShoulderCenter"), :] - p[..., _J("HipCenter"), :],
    )
    thorax = _trunk_frame(
        p[..., _J("ShoulderLeft"), :] - p[..., _J("ShoulderRight"), :],
        p[..., _J("ShoulderCenter"), :] - p[..., _J("Spine"), :],
    )
    frames = np.empty((*p.shape[:-2], skeleton.NUM_JOINTS, 3, 3))
    frames[..., list(_PELVIS), :, :] = pelvis[..., None, :, :]
    frames[..., list(_THORAX), :, :] = thorax[..., None, :, :]
    base = np.where(
        _BONE_ON_THORAX[:, None, None], thorax[..., None, :, :], pelvis[..., None, :, :]
    )  # (..., B, 3, 3)
    direction = _unit(p[..., _BONE_ENDS, :] - p[..., _BONE_PARENTS, :])  # (..., B, 3) in space
    local = np.einsum("...bji,...bj->...bi", base, direction)  # in the base frame's coordinates
    quaternion = shortest_arc(np.broadcast_to(_BONE_REST, local.shape), local)  # (x, y, z, w)
    turn = quaternion_to_matrix(quaternion[..., [3, 0, 1, 2]])
    frames[..., _BONE_JOINTS, :, :] = base @ turn
    return frames


def _pose_frames(compiled: Any, pose: np.ndarray) -> np.ndarray | None:
    """:func:`joint_frames` of one pose ``(20, 3)`` float64 in one compiled call and numpy's
    product of the bones' base frames and turns (its operations in its order); None when a
    bone points opposite its rest direction."""
    trunks, base, turn, ok = compiled.bone_frame_turns(
        np.ascontiguousarray(pose),
        _TRUNK_JOINTS,
        _BONE_ENDS,
        _BONE_PARENTS,
        _BONE_ON_THORAX,
        _BONE_REST,
    )
    if not ok:
        return None
    frames = np.empty((skeleton.NUM_JOINTS, 3, 3))
    frames[_PELVIS_JOINTS] = trunks[0]
    frames[_THORAX_JOINTS] = trunks[1]
    frames[_BONE_JOINTS] = base @ turn
    return frames


def _offset_pose(compiled: Any, pose: np.ndarray, offsets: np.ndarray) -> np.ndarray | None:
    """``p + F(p) · o`` of one pose ``(20, 3)`` float64 in two compiled calls around numpy's
    product of the bones' base frames and turns (:func:`joint_frames`' operations in its order);
    None when a bone points opposite its rest direction (:func:`joint_frames` then)."""
    pose = np.ascontiguousarray(pose)
    trunks, base, turn, ok = compiled.bone_frame_turns(
        pose, _TRUNK_JOINTS, _BONE_ENDS, _BONE_PARENTS, _BONE_ON_THORAX, _BONE_REST
    )
    if not ok:
        return None
    mapped: np.ndarray = compiled.offset_pose(
        pose, trunks, base @ turn, _PELVIS_JOINTS, _THORAX_JOINTS, _BONE_JOINTS, offsets
    )
    return mapped


@dataclass(frozen=True, eq=False)
class DefinitionMap:
    """Per-joint offsets from one system's joint definitions to another's.

    Parameters
    ----------
    offsets : array_like, shape (20, 3)
        ``o_j`` in metres, in the joint's frame (left, up, forward).
    source, target : str
        Names of the definitions mapped from and to (e.g. ``"kinect-v2"``, ``"vicon"``).
    info : dict
        JSON-serialisable facts: what it was fitted on, residuals, ...
    inverted : bool
        Apply the inverse of the offsets' map (:meth:`inverse`): then :attr:`source` and
        :attr:`target` name the inverse's definitions.
    """

    offsets: np.ndarray
    source: str
    target: str
    info: dict[str, Any] = field(default_factory=dict)
    inverted: bool = False

    def __post_init__(self) -> None:
        offsets = np.asarray(self.offsets, dtype=np.float64)
        if offsets.shape != (skeleton.NUM_JOINTS, 3) or not np.all(np.isfinite(offsets)):
            raise ValueError(f"offsets: expected 20 × 3 finite values, got shape {offsets.shape}")
        if np.abs(offsets).max() > 0.5:
            raise ValueError("offsets: a joint moves more than 0.5 m; not a definition change")
        offsets = offsets.copy()
        offsets.flags.writeable = False
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "info", dict(self.info))

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Unpickled (e.g. in a worker process) with its offsets read-only again, as built (a
        writeable array would compile the offsets' kernel a second time)."""
        self.__dict__.update(state)
        self.offsets.flags.writeable = False

    @classmethod
    def identity(cls, definitions: str = "same") -> DefinitionMap:
        """The map that moves nothing."""
        return cls(np.zeros((skeleton.NUM_JOINTS, 3)), source=definitions, target=definitions)

    @functools.cached_property
    def is_identity(self) -> bool:
        """Whether every offset is zero (the offsets are read-only: looked at once)."""
        return not np.any(self.offsets)

    def apply(self, poses: npt.ArrayLike) -> np.ndarray:
        """Map poses ``(..., 20, 3)`` from :attr:`source` to :attr:`target` definitions."""
        p = np.asarray(poses, dtype=np.float64)
        if self.is_identity:
            return p.copy()
        if self.inverted:
            return self._solve(p)
        if p.shape == (skeleton.NUM_JOINTS, 3):
            compiled = compiled_module("fpg_gym.core.compiled_poses")
            mapped = None if compiled is None else _offset_pose(compiled, p, self.offsets)
            if mapped is not None:
                return mapped
        return p + np.einsum("...jab,jb->...ja", joint_frames(p), self.offsets)

    def _solve(self, p: np.ndarray, iterations: int = 10) -> np.ndarray:
        """``q`` with ``q + F(q) o = p``: the fixed point of ``q = p - F(q) o`` (a few
        iterations suffice for offsets small against the bones)."""
        q = p.copy()
        for _ in range(iterations):
            q = p - np.einsum("...jab,jb->...ja", joint_frames(q), self.offsets)
        return q

    def inverse(self) -> DefinitionMap:
        """The map from :attr:`target` back to :attr:`source` definitions."""
        return DefinitionMap(
            self.offsets,
            source=self.target,
            target=self.source,
            info=self.info,
            inverted=not self.inverted,
        )

    @classmethod
    def fit(
        cls,
        source_poses: npt.ArrayLike,
        target_poses: npt.ArrayLike,
        *,
        source: str,
        target: str,
        symmetric: bool = True,
        robust: bool = True,
        joints: npt.ArrayLike | None = None,
        info: dict[str, Any] | None = None,
    ) -> DefinitionMap:
        """Least-squares offsets from paired poses of the same moments.

        Parameters
        ----------
        source_poses, target_poses : array_like, shape (N, 20, 3)
            The same N moments in the two definitions, in one space.
        symmetric : bool
            Average each left offset with the mirror image of its right twin (the body's
            definitions are symmetric; halves the variance).
        robust : bool
            Per-component median of the residuals instead of the mean (the least-absolute
            solution; tracking failures then do not drag the offsets).
        joints : array_like of int, optional
            Fit these joints' offsets only; the others stay zero (all joints by default).
        info : dict, optional
            Stored with the map; the fit adds ``pairs`` and ``residual_m`` (mean distance of
            mapped source to target after the fit).
        """
        s = np.asarray(source_poses, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
        t = np.asarray(target_poses, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
        if s.shape != t.shape or len(s) == 0:
            raise ValueError(f"fit: expected two equal (N, 20, 3) arrays, got {s.shape}, {t.shape}")
        # F is orthonormal, so min ||s + F o - t||² gives o = mean(F^T (t - s)).
        residual = np.einsum("njab,nja->njb", joint_frames(s), t - s)
        offsets = np.median(residual, axis=0) if robust else residual.mean(axis=0)
        if symmetric:
            offsets = symmetrise_offsets(offsets)
        if joints is not None:
            keep = np.zeros(skeleton.NUM_JOINTS, dtype=bool)
            keep[np.asarray(joints, dtype=np.intp)] = True
            offsets[~keep] = 0.0
        fitted = cls(offsets, source=source, target=target, info=dict(info or {}))
        after = np.linalg.norm(fitted.apply(s) - t, axis=-1).mean()
        fitted.info.update({"pairs": len(s), "residual_m": round(float(after), 5)})
        fitted.info.setdefault(
            "residual_before_m", round(float(np.linalg.norm(s - t, axis=-1).mean()), 5)
        )
        return fitted

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (offsets per joint name, millimetre precision and below)."""
        return {
            "format": FORMAT,
            "source": self.source,
            "target": self.target,
            "inverted": self.inverted,
            "offsets_m": {
                name: [round(float(v), 6) for v in self.offsets[j]]
                for j, name in enumerate(skeleton.JOINT_NAMES)
            },
            "info": self.info,
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "definition map") -> DefinitionMap:
        """Rebuild from :meth:`to_dict` output.

        Raises
        ------
        DataFormatError
            If an entry is missing or malformed.
        """
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise DataFormatError(where, f"not a definition map (expected format {FORMAT!r})")
        table = data.get("offsets_m")
        if not isinstance(table, dict) or set(table) != set(skeleton.JOINT_NAMES):
            raise DataFormatError(
                where, "offsets_m: expected one [left, up, forward] entry per Kinect-20 joint"
            )
        inverted = data.get("inverted", False)
        if not isinstance(inverted, bool):  # bool("false") is True: never guess
            raise DataFormatError(
                where, f"expected true or false, got {inverted!r}", field="inverted"
            )
        info = data.get("info") or {}
        if not isinstance(info, dict):
            raise DataFormatError(where, f"expected a JSON object, got {info!r:.60}", field="info")
        for name in ("source", "target"):
            if not isinstance(data.get(name, ""), str):
                raise DataFormatError(where, f"expected a name, got {data[name]!r:.60}", field=name)
        try:
            offsets = np.array([table[name] for name in skeleton.JOINT_NAMES], dtype=np.float64)
            return cls(
                offsets,
                source=data.get("source", ""),
                target=data.get("target", ""),
                info=info,
                inverted=inverted,
            )
        except (TypeError, ValueError, OverflowError) as error:
            raise DataFormatError(where, f"offsets_m: {error}", field="offsets_m") from None

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the map as JSON (through a temporary file renamed into place)."""
        return write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> DefinitionMap:
        """Read a map written by :meth:`save`.

        Raises
        ------
        FileNotFoundError
            If the file does not exist.
        DataFormatError
            If the path is not a readable file (:func:`fpg_gym.io.files.read_json`), or the
            file is not JSON or not a definition map.
        """
        return cls.from_dict(read_json(path), str(path))

    def __repr__(self) -> str:
        size = 1000 * float(np.linalg.norm(self.offsets, axis=-1).max())
        return f"DefinitionMap({self.source} -> {self.target}, largest offset {size:.0f} mm)"


def fit_to_database(
    poses: npt.ArrayLike,
    database: npt.ArrayLike,
    *,
    source: str,
    target: str,
    joints: npt.ArrayLike = TRUNK_JOINTS,
    max_pairs: int = 4000,
    block: int = 512,
) -> DefinitionMap:
    """Fit the map from ``poses``' definitions to a database's, without paired data.

    A database built from another capture system has no moment in common with the user's
    data, so the pairs are made by matching: each pose (mapped by the current estimate) is
    paired with the database pose whose *limb* bone directions (upper arms, forearms, hands,
    thighs, shanks, feet; bone-length weighted) are closest, retargeted to the pose's own bone
    lengths and placed where the pose is; the offsets of ``joints`` (the trunk by default:
    where capture systems disagree) are fitted on these pairs (:meth:`DefinitionMap.fit`, robust
    median). One pass: matching on the limbs with the source's own lengths does not depend on
    the map, whereas re-matching mapped poses drifts (measured: the offsets grew with every
    round). Offsets along a bone change only its length, which retargeting absorbs, so what
    this finds is the part of a definition change that bends the skeleton (a head set forward,
    a spine joint set back); use the map in both directions (into the database's definitions
    and back out) so that the part it cannot see cancels.

    Parameters
    ----------
    poses : array_like, shape (N, 20, 3)
        Poses in the ``source`` definitions (e.g. Vicon joint centres of training subjects).
    database : array_like, shape (M, 20, 3)
        The database's (normalised) poses, in the ``target`` definitions.
    joints : array_like of int
        Joints whose offsets are fitted (:data:`TRUNK_JOINTS`); the others stay zero.
    max_pairs : int
        At most this many poses, evenly spaced, are used.
    block : int
        Poses matched per block (memory ``block × M``).
    """
    p = np.asarray(poses, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
    db = np.asarray(database, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
    if len(p) == 0 or len(db) == 0:
        raise ValueError("fit_to_database: expected at least one pose and one database pose")
    if len(p) > max_pairs:
        p = p[np.linspace(0, len(p) - 1, max_pairs).astype(np.intp)]
    fitted = np.asarray(joints, dtype=np.intp)
    limb_bones = np.flatnonzero(~np.isin(skeleton.BONES[:, 1], fitted))
    db_directions = pose_utils.bone_directions(db)[:, limb_bones].reshape(len(db), -1)
    local, placement = pose_utils.normalise(p)
    lengths = pose_utils.bone_lengths(local)  # (N, 19): the source's own lengths
    weighted = (pose_utils.bone_directions(local) * lengths[..., None])[:, limb_bones]
    weighted = weighted.reshape(len(p), -1)
    # min over nodes of sum_b l_b |d_q - d_n|^2 = max over nodes of sum_b l_b d_q . d_n
    best = np.concatenate(
        [
            np.argmax(weighted[i : i + block] @ db_directions.T, axis=1)
            for i in range(0, len(p), block)
        ]
    )
    # The matched database pose with the source's bone lengths, where the source pose is: what
    # is left between the two is how the database bends the same body differently.
    paired = pose_utils.denormalise(pose_utils.retarget(db[best], lengths), placement)
    current = DefinitionMap.fit(p, paired, source=source, target=target, joints=fitted)
    current.info["database_poses"] = len(db)
    return current


@dataclass(frozen=True)
class ComposedMap:
    """Maps applied one after the other (a :class:`PoseMap`): ``maps[-1](...maps[0](p))``."""

    maps: tuple[PoseMap, ...]

    def __post_init__(self) -> None:
        if not self.maps:
            raise ValueError("ComposedMap: expected at least one map")

    @property
    def source(self) -> str:
        """The first map's source definitions."""
        return self.maps[0].source

    @property
    def target(self) -> str:
        """The last map's target definitions."""
        return self.maps[-1].target

    def apply(self, poses: npt.ArrayLike) -> np.ndarray:
        """Apply every map in turn."""
        result = np.asarray(poses, dtype=np.float64)
        for mapping in self.maps:
            result = mapping.apply(result)
        return result


def sensor_to_output_map(options: Any) -> PoseMap | None:
    """The map that puts the *sensor's* joints in the definitions a reconstruction outputs.

    ``options`` holds the reconstructor's maps (a mapping or an object with the
    :class:`~fpg_gym.reconstruct.ReconstructorConfig` fields ``sensor_map``, ``output_map``,
    ``calibrate_output`` and ``calibration_map``): the calibration map when the output is
    calibrated online; else the sensor map followed by the output map, when given. None when
    the output is in the sensor's own definitions (no map at all, or a calibration without a
    calibration map). The mapped sensor is the baseline a reconstruction must beat on the same
    definitions (``raw+map``, ``holt+map``).
    """

    def get(name: str) -> Any:
        return options.get(name) if isinstance(options, dict) else getattr(options, name, None)

    if get("calibrate_output"):
        return get("calibration_map")
    maps = tuple(m for m in (get("sensor_map"), get("output_map")) if m is not None)
    if not maps:
        return None
    return maps[0] if len(maps) == 1 else ComposedMap(maps)


def load_map(name: str | Path) -> DefinitionMap:
    """A definition map from a JSON file, or a packaged map by name (``kinect-v2-to-vicon``,
    :func:`packaged_map`)."""
    if not Path(name).suffix and str(name) in packaged_map_names():
        return packaged_map(str(name))
    return DefinitionMap.load(name)


def packaged_map_names() -> tuple[str, ...]:
    """Names of the maps shipped in ``fpg_gym/data`` (``kinect-v2-to-vicon``, ...)."""
    return tuple(sorted(p.stem for p in _DATA.glob("*.json")))


def packaged_map(name: str) -> DefinitionMap:
    """A definition map shipped with fpg-gym (``fpg_gym/data/NAME.json``).

    :data:`KINECT_V2_TO_VICON` maps Kinect v2 joints onto marker-based joint centres; it was
    fitted on UI-PRMD subjects s01-s07, so never score one of them with it (fit per fold with
    :func:`fit_sensor_maps` instead, as ``scripts/real_kinect.py`` does).

    Raises
    ------
    ValueError
        If no such map is packaged.
    """
    path = _DATA / f"{name}.json"
    if not path.is_file():
        names = sorted(p.stem for p in _DATA.glob("*.json"))
        raise ValueError(f"unknown packaged map {name!r}; expected one of {', '.join(names)}")
    return DefinitionMap.load(path)


def fit_sensor_maps(
    sensor_poses: npt.ArrayLike,
    truth_poses: npt.ArrayLike,
    *,
    sensor: str,
    truth: str,
    database: npt.ArrayLike | None = None,
    database_name: str = "database",
    database_joints: npt.ArrayLike = TRUNK_JOINTS,
) -> tuple[DefinitionMap, DefinitionMap | None]:
    """The maps a reconstruction needs, from a sensor's poses paired with reference poses.

    Parameters
    ----------
    sensor_poses, truth_poses : array_like, shape (N, 20, 3)
        The same moments seen by the sensor and by the reference system (e.g. UI-PRMD's
        Kinect v2 and Vicon joint centres), in one space.
    sensor, truth : str
        Names of the two definitions.
    database : array_like, shape (M, 20, 3), optional
        A database in other definitions than ``truth``'s. Without it the database is taken to
        be in the ``truth`` definitions (e.g. built from the same reference system).
    database_joints : array_like of int
        Joints whose database definitions are fitted (:func:`fit_to_database`).

    Returns
    -------
    sensor_map : DefinitionMap
        Sensor -> database definitions (``ReconstructorConfig.sensor_map``).
    output_map : DefinitionMap or None
        Database -> ``truth`` definitions (``ReconstructorConfig.output_map``); None when the
        database is in the ``truth`` definitions.
    """
    if database is None:
        return DefinitionMap.fit(sensor_poses, truth_poses, source=sensor, target=truth), None
    truth_to_database = fit_to_database(
        truth_poses, database, source=truth, target=database_name, joints=database_joints
    )
    sensor_map = DefinitionMap.fit(
        sensor_poses,
        truth_to_database.apply(truth_poses),
        source=sensor,
        target=database_name,
        info={"database_map": truth_to_database.info},
    )
    return sensor_map, truth_to_database.inverse()
