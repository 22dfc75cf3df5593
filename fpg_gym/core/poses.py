"""Pose utilities: FPG Eq. 1 distance, normalisation, bone lengths, retargeting, mirroring.

A pose is a float array ``(20, 3)`` of Kinect-20 joint positions in metres, Y up, right-handed;
a batch or clip is ``(..., 20, 3)``. Every function here is vectorised over leading axes.

Normalisation (DESIGN.md, "data flow") moves the root (HipCenter) to the origin and removes the
rotation about the vertical axis so that the body faces +Z. The facing direction comes from the
hip line: with ``right = HipRight - HipLeft`` projected on the ground plane,
``forward = up x right``. When the hips collapse onto each other (an untracked frame), the
shoulder line is used instead, and the yaw is 0 when both are degenerate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module

FloatArray = npt.NDArray[np.floating]


@runtime_checkable
class RecordingLike(Protocol):
    """What the reconstruction drivers read from a stream: a
    :class:`~fpg_gym.io.recording.Recording`, or any object with these arrays.

    ``timestamps`` (T,) seconds is read when the object has it (else frames are ``frame_dt``
    apart).
    """

    @property
    def positions(self) -> np.ndarray:
        """Joint positions ``(T, 20, 3)`` in metres, camera space."""
        ...

    @property
    def states(self) -> np.ndarray:
        """Tracking states ``(T, 20)``: 2 tracked, 1 inferred, 0 not tracked."""
        ...


_HIP_LEFT = skeleton.joint_index("HipLeft")
_HIP_RIGHT = skeleton.joint_index("HipRight")
_SHOULDER_LEFT = skeleton.joint_index("ShoulderLeft")
_SHOULDER_RIGHT = skeleton.joint_index("ShoulderRight")
#: A hip or shoulder line shorter than this (m, in the ground plane) gives no heading.
DEGENERATE_LINE_M = 1e-4
#: The joints whose lines give a pose's heading: hips (left, right), then shoulders.
FACING_JOINTS = (_HIP_LEFT, _HIP_RIGHT, _SHOULDER_LEFT, _SHOULDER_RIGHT)


def as_poses(value: object, name: str = "poses", *, ndim: int | None = None) -> np.ndarray:
    """Validate an array of poses and return it as float32.

    Parameters
    ----------
    value : array_like
        Candidate array of shape ``(..., 20, 3)``.
    name : str
        Argument name used in error messages.
    ndim : int, optional
        Required number of dimensions (2 for one pose, 3 for a clip or batch).

    Raises
    ------
    ValueError
        If the shape is not ``(..., 20, 3)`` (or not ``ndim``-dimensional) or a value is NaN/inf.
    """
    array = np.asarray(value, dtype=np.float32)
    if (
        array.ndim < 2
        or array.shape[-2:] != (skeleton.NUM_JOINTS, 3)
        or (ndim is not None and array.ndim != ndim)
    ):
        expected = "(..., 20, 3)" if ndim is None else "(" + "N, " * (ndim - 2) + "20, 3)"
        raise ValueError(f"{name}: expected shape {expected}, got {array.shape}")
    if not np.isfinite(array).all():
        bad = np.argwhere(~np.isfinite(array))[0]
        raise ValueError(f"{name}: non-finite value at index {tuple(int(i) for i in bad)}")
    return array


# --------------------------------------------------------------------------- distances (Eq. 1)


def pose_distance(a: FloatArray, b: FloatArray) -> np.ndarray:
    """FPG Eq. 1: ``max_j ||a(j) - b(j)||``, broadcasting over leading axes.

    ``pose_distance(pose, poses)`` scores one pose against N poses.
    """
    diff = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return np.sqrt(np.einsum("...jc,...jc->...j", diff, diff)).max(axis=-1)


def pairwise_pose_distance(
    a: FloatArray, b: FloatArray, *, max_block_bytes: int = 256 * 2**20
) -> np.ndarray:
    """FPG Eq. 1 for every pair: ``(N, 20, 3) x (M, 20, 3) -> (N, M)`` float64.

    Computed in row blocks so that no temporary exceeds ``max_block_bytes``.
    """
    a64 = np.asarray(a, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
    b64 = np.asarray(b, dtype=np.float64).reshape(-1, skeleton.NUM_JOINTS, 3)
    out = np.empty((len(a64), len(b64)))
    per_row = max(1, len(b64) * skeleton.NUM_JOINTS * 3 * 8)
    rows = max(1, max_block_bytes // per_row)
    for start in range(0, len(a64), rows):
        block = a64[start : start + rows, None] - b64[None]
        out[start : start + rows] = np.sqrt(np.einsum("nmjc,nmjc->nmj", block, block)).max(-1)
    return out


# --------------------------------------------------------------------------- normalisation


@dataclass(frozen=True)
class Placement:
    """Where a normalised pose was in the original space: root position and yaw.

    ``original = R_y(yaw) @ normalised + root``.

    Attributes
    ----------
    root : ndarray, shape (..., 3)
        Root (HipCenter) position in the original space.
    yaw : ndarray, shape (...)
        Heading angle in radians: the angle from +Z towards +X of the facing direction.
    """

    root: np.ndarray
    yaw: np.ndarray


def _one_pose_kernels(pose: np.ndarray, placement: Placement | None = None) -> Any:
    """The compiled pose kernels (:mod:`fpg_gym.core.compiled_poses`) when ``pose`` is one pose
    ``(20, 3)`` (and ``placement`` one root and one yaw) and numba is installed, else None."""
    if pose.shape != (skeleton.NUM_JOINTS, 3):
        return None
    if placement is not None and (np.shape(placement.root) != (3,) or np.ndim(placement.yaw)):
        return None
    return compiled_module("fpg_gym.core.compiled_poses")


def _place_one_pose(pose: np.ndarray, placement: Placement, inverse: bool) -> np.ndarray | None:
    """One pose ``(20, 3)`` float64 into ``placement``'s frame (or back, with ``inverse``) by
    the compiled kernel, or None when it does not apply (several poses, no numba)."""
    compiled = _one_pose_kernels(pose, placement)
    if compiled is None:
        return None
    placed: np.ndarray = compiled.place_pose(
        np.ascontiguousarray(pose),
        np.asarray(placement.root, dtype=np.float64),
        float(placement.yaw),
        inverse,
    )
    return placed


def yaw_matrix(yaw: FloatArray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` about +Y by ``yaw`` radians (right-handed)."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    out = np.zeros((*yaw.shape, 3, 3))  # filled in place: a frame's hot path calls it 4 times
    out[..., 0, 0] = c
    out[..., 0, 2] = s
    out[..., 1, 1] = 1.0
    out[..., 2, 0] = -s
    out[..., 2, 2] = c
    return out


def facing_yaw(poses: FloatArray) -> np.ndarray:
    """Heading angle of each pose from its hip line (shoulder line as fallback), radians."""
    poses = np.asarray(poses, dtype=np.float64)
    right = poses[..., _HIP_RIGHT, :] - poses[..., _HIP_LEFT, :]
    shoulders = poses[..., _SHOULDER_RIGHT, :] - poses[..., _SHOULDER_LEFT, :]
    hip_ok = np.hypot(right[..., 0], right[..., 2]) > DEGENERATE_LINE_M
    right = np.where(hip_ok[..., None], right, shoulders)
    # forward = up x right = (r_z, 0, -r_x); yaw measured from +Z towards +X.
    forward_x, forward_z = right[..., 2], -right[..., 0]
    ok = np.hypot(forward_x, forward_z) > DEGENERATE_LINE_M
    return np.where(ok, np.arctan2(forward_x, forward_z), 0.0)


def normalise(poses: FloatArray) -> tuple[np.ndarray, Placement]:
    """Move the root to the origin and turn each pose to face +Z.

    Parameters
    ----------
    poses : array_like, shape (..., 20, 3)

    Returns
    -------
    normalised : ndarray, shape (..., 20, 3), float32
    placement : Placement
        What :func:`denormalise` needs to undo the transform.
    """
    poses64 = np.asarray(poses, dtype=np.float64)
    root = poses64[..., skeleton.ROOT, :]
    compiled = _one_pose_kernels(poses64)
    if compiled is not None:  # one pose: one compiled call
        normalised, angle = compiled.normalise_pose(
            np.ascontiguousarray(poses64), skeleton.ROOT, *FACING_JOINTS, DEGENERATE_LINE_M
        )
        return normalised, Placement(root=root, yaw=np.asarray(angle))
    yaw = facing_yaw(poses64)
    # p_norm = R_y(-yaw) (p - root), i.e. for row vectors (p - root) @ R_y(yaw)
    normalised = np.einsum("...jc,...cd->...jd", poses64 - root[..., None, :], yaw_matrix(yaw))
    return normalised.astype(np.float32), Placement(root=root, yaw=yaw)


def denormalise(poses: FloatArray, placement: Placement) -> np.ndarray:
    """Inverse of :func:`normalise`: ``R_y(yaw) p + root``, float32."""
    poses64 = np.asarray(poses, dtype=np.float64)
    placed = _place_one_pose(poses64, placement, inverse=True)
    if placed is not None:
        return placed.astype(np.float32)
    rotation = yaw_matrix(placement.yaw)
    out = (
        np.einsum("...jc,...dc->...jd", poses64, rotation)
        + np.asarray(placement.root)[..., None, :]
    )
    return out.astype(np.float32)


# --------------------------------------------------------------------------- bones


def bone_vectors(poses: FloatArray) -> np.ndarray:
    """Child minus parent for the 19 bones: ``(..., 20, 3) -> (..., 19, 3)``."""
    poses = np.asarray(poses)
    return poses[..., skeleton.BONES[:, 1], :] - poses[..., skeleton.BONES[:, 0], :]


def flat_bone_vectors(poses: FloatArray) -> np.ndarray:
    """:func:`bone_vectors` of flat poses (or offsets, directions): ``(..., 60) -> (..., 57)``."""
    poses = np.asarray(poses)
    return bone_vectors(poses.reshape(*poses.shape[:-1], -1, 3)).reshape(*poses.shape[:-1], -1)


def latent_bone_design(axes: FloatArray) -> np.ndarray:
    """Bone vectors per unit of each latent axis: ``(..., L, 60) -> (..., 57, L)``.

    A pose linear in its latent coordinates, ``m + z A`` (Shum Eq. 9, ``A`` the axes scaled by
    their spread), has the bone vectors ``bones(m) + design @ z``: the design of a
    least-squares fit on bone vectors (:func:`fit_bone_vectors`; FPG Eq. 13 scores bone
    vectors).
    """
    return np.swapaxes(flat_bone_vectors(axes), -1, -2)


def fit_bone_vectors(design: FloatArray, bones: FloatArray) -> np.ndarray:
    """Least-squares latent coordinates ``(..., L)`` whose bone vectors ``design @ z`` are
    closest to ``bones`` ``(..., 57)``.

    ``design`` is :func:`latent_bone_design` ``(..., 57, L)``. Solved by the normal equations
    with a ridge of 1e-10 of the system's mean diagonal: it keeps every system regular and
    gives unused (all-zero) axes 0; on UI-PRMD's frames the others equal ``lstsq``'s to
    float32 rounding.
    """
    design = np.asarray(design, dtype=np.float64)
    gram = np.einsum("...bl,...bk->...lk", design, design)
    diagonal = np.einsum("...ll->...l", gram)
    ridge = np.maximum(1e-10 * diagonal.mean(axis=-1), 1e-300)
    gram += ridge[..., None, None] * np.eye(design.shape[-1])
    rhs = np.einsum("...bl,...b->...l", design, np.asarray(bones, dtype=np.float64))
    return np.linalg.solve(gram, rhs[..., None])[..., 0]


def bone_lengths(poses: FloatArray) -> np.ndarray:
    """Bone lengths in metres: ``(..., 20, 3) -> (..., 19)``."""
    poses64 = np.asarray(poses, dtype=np.float64)
    if poses64.shape == (skeleton.NUM_JOINTS, 3):
        compiled = compiled_module("fpg_gym.core.compiled_poses")
        if compiled is not None:  # one pose: one compiled call, the same sums
            lengths: np.ndarray = compiled.bone_lengths_pose(
                np.ascontiguousarray(poses64), skeleton.BONES
            )
            return lengths
    return np.linalg.norm(bone_vectors(poses64), axis=-1)


def rest_pose(lengths: FloatArray | None = None) -> np.ndarray:
    """A neutral standing pose facing +Z, root at the origin, float32 ``(20, 3)``.

    Parameters
    ----------
    lengths : array_like, shape (19,), optional
        Bone lengths in metres; :data:`DEFAULT_BONE_LENGTHS` when omitted.
    """
    lengths = DEFAULT_BONE_LENGTHS if lengths is None else np.asarray(lengths, dtype=np.float64)
    return _assemble(np.zeros(3), REST_DIRECTIONS, lengths).astype(np.float32)


def _assemble(root: np.ndarray, directions: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Joint positions from the root, unit bone directions and bone lengths (tree walk as a
    matrix product with :data:`skeleton.PATH_MATRIX`)."""
    vectors = directions * np.asarray(lengths)[..., :, None]
    return root[..., None, :] + np.einsum("jb,...bc->...jc", skeleton.PATH_MATRIX, vectors)


def retarget(poses: FloatArray, lengths: FloatArray) -> np.ndarray:
    """Give each pose the given bone lengths, keeping every bone's direction and the root.

    A zero-length bone takes its direction from :data:`REST_DIRECTIONS`.

    Parameters
    ----------
    poses : array_like, shape (..., 20, 3)
    lengths : array_like, shape (19,) or (..., 19)
        Target bone lengths in metres, broadcast against the poses.

    Returns
    -------
    ndarray, shape (..., 20, 3), float32
    """
    poses64 = np.asarray(poses, dtype=np.float64)
    lengths64 = np.asarray(lengths, dtype=np.float64)
    if lengths64.shape[-1:] != (skeleton.NUM_BONES,):
        raise ValueError(f"lengths: expected shape (..., 19), got {lengths64.shape}")
    if poses64.shape == (skeleton.NUM_JOINTS, 3) and lengths64.ndim == 1:
        compiled = compiled_module("fpg_gym.core.compiled_poses")
        if compiled is not None:  # one pose (a frame's output): one compiled call
            out: np.ndarray = compiled.retarget_pose(
                np.ascontiguousarray(poses64), lengths64, skeleton.BONES, REST_DIRECTIONS
            )
            return out
    directions = bone_directions(poses64)
    return _assemble(poses64[..., skeleton.ROOT, :], directions, lengths64).astype(np.float32)


# --------------------------------------------------------------------------- mirroring, time


def mirror(poses: FloatArray, axis: int = 0) -> np.ndarray:
    """Left/right mirror image: swap left and right joints and negate coordinate ``axis``.

    For normalised poses (facing +Z) the default ``axis=0`` mirrors about the sagittal plane.
    """
    out = np.array(np.asarray(poses)[..., skeleton.MIRROR_PERMUTATION, :], copy=True)
    out[..., axis] *= -1
    return out


def resample(positions: FloatArray, fps_in: float, fps_out: float = 30.0) -> np.ndarray:
    """Linearly resample a clip ``(T, ...)`` from ``fps_in`` to ``fps_out`` frames per second.

    The output covers the same duration, ``floor((T - 1) * fps_out / fps_in) + 1`` frames,
    starting at the first input frame.
    """
    if fps_in <= 0 or fps_out <= 0:
        raise ValueError(f"frame rates must be positive, got fps_in={fps_in}, fps_out={fps_out}")
    positions = np.asarray(positions)
    if len(positions) == 0:
        raise ValueError("resample: empty clip")
    if np.isclose(fps_in, fps_out):
        return positions.copy()
    count = int(np.floor((len(positions) - 1) * fps_out / fps_in + 1e-9)) + 1
    source_time = np.arange(count) * (fps_in / fps_out)
    lower = np.minimum(np.floor(source_time).astype(np.intp), len(positions) - 1)
    upper = np.minimum(lower + 1, len(positions) - 1)
    frac = (source_time - lower).reshape((-1,) + (1,) * (positions.ndim - 1))
    out = positions[lower] * (1.0 - frac) + positions[upper] * frac
    return out.astype(positions.dtype)


def height(poses: FloatArray) -> np.ndarray:
    """Vertical extent (max Y minus min Y) of each pose in metres (posture dependent)."""
    y = np.asarray(poses)[..., 1]
    return y.max(axis=-1) - y.min(axis=-1)


_STATURE_CHAIN = [
    skeleton.BONE_OF_JOINT[skeleton.joint_index(name)]
    for name in ("Spine", "ShoulderCenter", "Head")
]
_LEG_BONES = [
    [skeleton.BONE_OF_JOINT[skeleton.joint_index(f"{part}{side}")] for part in ("Knee", "Ankle")]
    for side in ("Left", "Right")
]
#: Share of stature below the ankle joint (0.039) and above the head centre (0.065), from the
#: segment proportions of Drillis & Contini (1966) as tabulated by Winter (2009, Fig. 4.1).
_STATURE_OUTSIDE_CHAIN = 0.039 + 0.065


def stature(lengths: FloatArray) -> np.ndarray:
    """Posture-independent standing height estimated from bone lengths ``(..., 19)``, metres.

    The ankle-to-head-centre chain (mean leg, spine, neck and head bones) divided by the share of
    stature it spans in anthropometric tables (Drillis & Contini 1966).
    """
    lengths = np.asarray(lengths, dtype=np.float64)
    chain = lengths[..., _STATURE_CHAIN].sum(-1)
    legs = np.mean([lengths[..., bones].sum(-1) for bones in _LEG_BONES], axis=0)
    return (chain + legs) / (1.0 - _STATURE_OUTSIDE_CHAIN)


# --------------------------------------------------------------------------- rest pose data

_REST_DIRECTION_BY_JOINT: dict[str, tuple[float, float, float]] = {
    # Unit direction of the bone ending at each joint, for a body facing +Z (its left is +X).
    "Spine": (0.0, 1.0, 0.0),
    "ShoulderCenter": (0.0, 1.0, 0.0),
    "Head": (0.0, 1.0, 0.0),
    "ShoulderLeft": (1.0, -0.25, 0.0),
    "ElbowLeft": (0.0, -1.0, 0.0),
    "WristLeft": (0.0, -1.0, 0.0),
    "HandLeft": (0.0, -1.0, 0.0),
    "ShoulderRight": (-1.0, -0.25, 0.0),
    "ElbowRight": (0.0, -1.0, 0.0),
    "WristRight": (0.0, -1.0, 0.0),
    "HandRight": (0.0, -1.0, 0.0),
    "HipLeft": (1.0, -0.4, 0.0),
    "KneeLeft": (0.0, -1.0, 0.0),
    "AnkleLeft": (0.0, -1.0, 0.0),
    "FootLeft": (0.0, -0.3, 1.0),
    "HipRight": (-1.0, -0.4, 0.0),
    "KneeRight": (0.0, -1.0, 0.0),
    "AnkleRight": (0.0, -1.0, 0.0),
    "FootRight": (0.0, -0.3, 1.0),
}

#: Unit bone directions of the neutral standing pose, ``(19, 3)``, in :data:`skeleton.BONES` order.
REST_DIRECTIONS: np.ndarray = np.array(
    [_REST_DIRECTION_BY_JOINT[skeleton.JOINT_NAMES[c]] for _, c in skeleton.BONES]
)
REST_DIRECTIONS /= np.linalg.norm(REST_DIRECTIONS, axis=1, keepdims=True)
REST_DIRECTIONS.flags.writeable = False

_DEFAULT_LENGTH_BY_JOINT: dict[str, float] = {
    # Typical adult Kinect-20 bone lengths in metres (stature about 1.7 m, see stature()).
    "Spine": 0.24,
    "ShoulderCenter": 0.26,
    "Head": 0.16,
    "ShoulderLeft": 0.18,
    "ElbowLeft": 0.28,
    "WristLeft": 0.25,
    "HandLeft": 0.08,
    "ShoulderRight": 0.18,
    "ElbowRight": 0.28,
    "WristRight": 0.25,
    "HandRight": 0.08,
    "HipLeft": 0.10,
    "KneeLeft": 0.42,
    "AnkleLeft": 0.41,
    "FootLeft": 0.13,
    "HipRight": 0.10,
    "KneeRight": 0.42,
    "AnkleRight": 0.41,
    "FootRight": 0.13,
}

#: Default bone lengths in metres, ``(19,)``, used when a user's lengths are unknown.
DEFAULT_BONE_LENGTHS: np.ndarray = np.array(
    [_DEFAULT_LENGTH_BY_JOINT[skeleton.JOINT_NAMES[c]] for _, c in skeleton.BONES]
)
DEFAULT_BONE_LENGTHS.flags.writeable = False


# --------------------------------------------------------------------------- shared helpers


def into_placement(poses: FloatArray, placement: Placement) -> np.ndarray:
    """Camera-space poses moved into a placement's frame: ``R_y(-yaw) (p - root)``, float64.

    The inverse of :func:`denormalise` (without its cast to float32): with the placement that
    :func:`normalise` returned for a pose, this is that pose's normalised form; with another
    pose's placement, the pose seen from that frame (root at ``placement.root``, heading
    ``placement.yaw`` turned to +Z).

    Parameters
    ----------
    poses : array_like, shape (..., 20, 3)
    placement : Placement
        Root ``(..., 3)`` and yaw ``(...)``, broadcast against the poses' leading axes.

    Returns
    -------
    ndarray, shape (..., 20, 3), float64
    """
    poses64 = np.asarray(poses, dtype=np.float64)
    placed = _place_one_pose(poses64, placement, inverse=False)
    if placed is not None:
        return placed
    local = poses64 - np.asarray(placement.root)[..., None, :]
    out: np.ndarray = local @ yaw_matrix(placement.yaw)
    return out


def bone_directions(poses: FloatArray) -> np.ndarray:
    """Unit bone directions ``(..., 19, 3)`` float64 of poses ``(..., 20, 3)``.

    Computed in the input's precision; a bone shorter than 1e-9 m takes its direction from
    :data:`REST_DIRECTIONS`.
    """
    vectors = bone_vectors(poses)
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    safe = norms > 1e-9
    directions: np.ndarray = np.where(safe, vectors / np.where(safe, norms, 1.0), REST_DIRECTIONS)
    return directions


class FloorShift:
    """Camera space has no floor: a stream of camera-space poses is shifted down by the lowest
    joint seen so far (a running minimum, the best floor estimate without a calibrated camera)
    before the ragdoll, and back up after it.

    Examples
    --------
    >>> floor = FloorShift()                                   # doctest: +SKIP
    >>> out = floor.up(body.track(floor.down(target)))         # doctest: +SKIP
    """

    def __init__(self) -> None:
        self.floor_y: float | None = None

    def reset(self) -> None:
        """A new stream: forget the floor."""
        self.floor_y = None

    def down(self, target: np.ndarray) -> np.ndarray:
        """``target`` (20, 3) in the simulation world (float64); updates the floor estimate."""
        target = np.asarray(target, dtype=np.float64)
        lowest = float(target[:, 1].min())
        self.floor_y = lowest if self.floor_y is None else min(self.floor_y, lowest)
        return target - np.array([0.0, self.floor_y, 0.0])

    def up(self, pose: np.ndarray) -> np.ndarray:
        """A simulated pose back in camera space, float32."""
        assert self.floor_y is not None, "down() first"
        return (np.asarray(pose, dtype=np.float64) + np.array([0.0, self.floor_y, 0.0])).astype(
            np.float32
        )
