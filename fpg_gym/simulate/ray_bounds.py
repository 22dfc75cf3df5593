"""Which of the ray caster's rays pybullet must cast: bounds that settle the others exactly.

:class:`~fpg_gym.simulate.scene.RayCaster` casts rays from the camera to points around each
joint; what counts is the first shape a ray hits (none or the joint's own shape: the ray is not
blocked; a scene box: blocked by it; another body shape: blocked by the body) and, for a
joint's central ray, where it stops. Bullet's ray test costs a few microseconds for each shape
a ray passes near. Three conservative tests, vectorised over every frame, ray and shape, settle
most rays without it, with the answer Bullet gives:

* a ray that passes farther than ``margin`` from every shape that is not its joint's own is
  not blocked (:func:`segment_distances` for the capsules and the head's sphere, a slab test
  of each box grown by ``margin``);
* a ray that enters a box shrunk by ``margin`` before it can come within ``margin`` of any
  other shape (a lower bound of where it meets each one: its bounding sphere, or the box grown
  by ``margin``) first hits that box;
* a ray that passes closer than its radius less ``margin`` to the axis of a capsule that is not
  its joint's own before it can come within ``margin`` of one of its own shapes is blocked by
  the body (the shape it first hits may be another, but it is not the joint's own).

Only the blocking shape is known, not where the ray stops: joints' central rays still go to
pybullet whenever they may be blocked.

Bullet finds the surfaces of these capsules, spheres and boxes to well under a millimetre
(a ray 0.5 mm off a surface misses it, 1 mm inside hits it), so ``margin`` (1 cm) leaves ample
room; :func:`~fpg_gym.simulate.scene.RayCaster.trace` gives pybullet's result to the bit
(tested on every embedded clip in every scenario).
"""

from __future__ import annotations

import numpy as np

from fpg_gym.core.rotations import quaternion_to_matrix

__all__ = ["MARGIN", "rays_to_cast", "segment_distances"]

#: Room (metres) left around every shape's surface.
MARGIN = 0.01


def _dot(u: np.ndarray | list[np.ndarray], v: np.ndarray | list[np.ndarray]) -> np.ndarray:
    """Dot products of vectors given by their coordinates ``(3, ...)``, summed in order as
    ``np.sum(u * v, axis=-1)`` sums them (the same floats, without a reduction per vector)."""
    return np.asarray((u[0] * v[0] + u[1] * v[1]) + u[2] * v[2])


def segment_distances(
    start: np.ndarray, end: np.ndarray, first: np.ndarray, second: np.ndarray
) -> np.ndarray:
    """Distances between segments ``start``-``end`` and ``first``-``second`` (``(..., 3)``,
    broadcast), the closest points clamped to both segments (Ericson 2005, 5.1.9); the second
    segment may be a point."""
    # Coordinates first, (3, ...): every operation runs along the many segments.
    return _distances(
        *(np.moveaxis(x, -1, 0) for x in np.broadcast_arrays(start, end, first, second))
    )


def _distances(
    start: np.ndarray, end: np.ndarray, first: np.ndarray, second: np.ndarray
) -> np.ndarray:
    """:func:`segment_distances` of segments given by their coordinates ``(3, ...)``."""
    return _closest(start, end, first, second)[0]


def _closest(
    start: np.ndarray, end: np.ndarray, first: np.ndarray, second: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_distances`, and where on the first segment (``s`` in [0, 1]) the closest points
    are."""
    d1, d2, r = end - start, second - first, start - first
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    c = _dot(d1, r)
    b = _dot(d1, d2)
    denominator = a * e - b * b
    safe_a = np.maximum(a, 1e-300)
    point = e <= 1e-18
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denominator > 1e-12 * a * e, (b * f - c * e) / denominator, 0.0)
        s = np.clip(np.where(point, -c / safe_a, s), 0.0, 1.0)
        u = np.where(point, 0.0, (b * s + f) / np.maximum(e, 1e-300))
    s = np.where(u < 0.0, np.clip(-c / safe_a, 0.0, 1.0), s)
    s = np.where(u > 1.0, np.clip((b - c) / safe_a, 0.0, 1.0), s)
    u = np.clip(u, 0.0, 1.0)
    gap = [start[k] + d1[k] * s - first[k] - d2[k] * u for k in range(3)]
    return np.asarray(np.sqrt(_dot(gap, gap))), s


def _capsule_entry(
    along: np.ndarray, length: np.ndarray, bound: np.ndarray, t: np.ndarray, r: np.ndarray
) -> np.ndarray:
    """``(C, N)``: a lower bound of where rays ``(t, r)`` come within ``margin`` of each capsule,
    as a fraction of the ray: the projection of the capsule's centre on the ray (``along``
    ``(C, T, R)``: its dot product with the ray's vector, whose norm is ``length``) less its
    bounding radius ``bound`` ``(C, 1, 1)``."""
    length_n = length[t, r]
    return np.asarray((along[:, t, r] / length_n - bound[:, :, 0]) / length_n)


def _slab_entry(
    start: list[np.ndarray], direction: list[np.ndarray], half: np.ndarray
) -> np.ndarray:
    """Where segments ``start + s direction`` (``s`` in [0, 1], in the boxes' own frames, one
    array per coordinate, broadcast against ``(B, T, R)``) enter the boxes of half extents
    ``half`` ``(B, 3)``: ``s``, or inf when they miss."""
    enter: np.ndarray | float = 0.0
    leave: np.ndarray | float = 1.0
    for axis in range(3):
        extent = half[:, axis, None, None]
        origin, step = start[axis], direction[axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            near = (-extent - origin) / step
            far = (extent - origin) / step
        low, high = np.minimum(near, far), np.maximum(near, far)
        parallel = step == 0.0
        if parallel.any():  # a segment parallel to the slab: inside it all along, or never
            inside = np.broadcast_to(np.abs(origin) <= extent, parallel.shape)[parallel]
            low[parallel] = np.where(inside, -np.inf, np.inf)
            high[parallel] = np.where(inside, np.inf, -np.inf)
        enter, leave = np.maximum(enter, low), np.minimum(leave, high)
    return np.where(enter <= leave, enter, np.inf)


def rays_to_cast(
    camera: np.ndarray,
    targets: np.ndarray,
    shape_pos: np.ndarray,
    shape_quat: np.ndarray,
    radius: np.ndarray,
    half_height: np.ndarray,
    box_half: np.ndarray,
    own: np.ndarray,
    central: np.ndarray,
    margin: float = MARGIN,
) -> tuple[np.ndarray, np.ndarray]:
    """The rays pybullet must cast, and the first shape of those it need not.

    Parameters
    ----------
    camera : ndarray, shape (3,)
        Where every ray starts.
    targets : ndarray, shape (T, R, 3)
        Where each ray of each frame ends.
    shape_pos, shape_quat : ndarray, shapes (T, S, 3), (T, S, 4)
        Each shape's centre and orientation (x, y, z, w) per frame.
    radius, half_height : ndarray, shape (C,)
        The first ``C`` shapes are capsules along their local Z (a sphere: ``half_height`` 0).
    box_half : ndarray, shape (S - C, 3)
        The other shapes are boxes of these half extents.
    own : ndarray of bool, shape (R, S)
        The shapes that do not block each ray (its joint's own).
    central : ndarray of bool, shape (R,)
        The rays whose end point counts (always cast when they may be blocked).
    margin : float

    Returns
    -------
    cast : ndarray of bool, shape (T, R)
        The rays to cast.
    first : ndarray of int, shape (T, R)
        For the others, a shape that blocks them (the box they first hit, or a body capsule
        not their joint's own that they go through before any of their own shapes), or -1 when
        none does.
    """
    # Shapes first, (S, T, R): every reduction runs over the few shapes, not the many rays.
    capsules = len(radius)
    ray = np.moveaxis(targets - camera, -1, 0)  # (3, T, R)
    squared = ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2]  # (T, R)
    length = np.sqrt(squared)
    # Boxes: where each ray enters the box grown by the margin, and the box shrunk by it (a ray
    # entering that one hits the box).
    axes = quaternion_to_matrix(shape_quat[:, capsules:][..., [3, 0, 1, 2]])  # (T, B, 3, 3)
    axes = np.moveaxis(axes, 1, 0)  # (B, T, 3, 3): the box's axes as columns
    offset = camera - np.moveaxis(shape_pos[:, capsules:], 1, 0)  # (B, T, 3)
    local_start = [np.sum(axes[..., j] * offset, axis=-1)[..., None] for j in range(3)]
    local_ray = [
        axes[..., 0, j, None] * ray[0]
        + axes[..., 1, j, None] * ray[1]
        + axes[..., 2, j, None] * ray[2]
        for j in range(3)
    ]  # (B, T, R) each
    grown = _slab_entry(local_start, local_ray, box_half + margin)
    shrunk = _slab_entry(local_start, local_ray, np.maximum(box_half - margin, 0.0))
    # The first box a ray surely enters: only such a ray, not a central one, can be settled.
    box = np.argmin(shrunk, axis=0)  # (T, R)
    enters = np.take_along_axis(shrunk, box[None], axis=0)[0]
    settleable = np.isfinite(enters) & ~central
    by_box = np.any(np.isfinite(grown) & ~own.T[capsules:, None, :], axis=0)  # cast anyway
    # Capsules: a lower bound of where each ray meets the capsule's bounding sphere, and the
    # exact distance where the ray passes that sphere.
    centre = np.moveaxis(shape_pos[:, :capsules] - camera, -1, 0)[..., None]  # (3, T, C, 1)
    centre = np.moveaxis(centre, 2, 0)  # (C, 3, T, 1)
    along = centre[:, 0] * ray[0] + centre[:, 1] * ray[1] + centre[:, 2] * ray[2]  # (C, T, R)
    reach = np.clip(along, 0.0, squared)
    distance2 = centre[:, 0] ** 2 + centre[:, 1] ** 2 + centre[:, 2] ** 2
    closest = distance2 - (2.0 * along - reach) * reach / np.maximum(squared, 1e-300)
    bound = (radius + half_height + margin)[:, None, None]  # (C, 1, 1)
    near = np.zeros(along.shape, dtype=bool)
    # Whether a capsule is near a ray matters when it may block the ray (not the ray's own, and
    # no box makes the ray cast anyway) or when the ray may be settled.
    matters = (~own.T[:capsules, None, :] & ~by_box) | settleable
    nc, nt, nr = np.nonzero((closest < bound * bound) & matters)
    distance = passes = np.zeros(0)
    if len(nt):
        # The capsules' axes: their rotations' Z columns, coordinates first (3, T, C).
        rotations = quaternion_to_matrix(shape_quat[:, :capsules][..., [3, 0, 1, 2]])
        z_axes = np.moveaxis(rotations[..., 2], -1, 0)
        axis = z_axes[:, nt, nc] * half_height[nc]
        middle = np.moveaxis(shape_pos, -1, 0)[:, nt, nc]
        ends = np.moveaxis(targets, -1, 0)[:, nt, nr]
        distance, passes = _closest(camera[:, None], ends, middle - axis, middle + axis)
        near[nc, nt, nr] = distance < radius[nc] + margin
    meets = np.concatenate([near, np.isfinite(grown)])  # (S, T, R)
    cast = np.any(meets & ~own.T[:, None, :], axis=0)
    # Whether the first box a ray surely enters comes before any other shape: only for the rays
    # that may be settled, (S, N).
    t, r = np.nonzero(cast & settleable)
    first = np.full(cast.shape, -1)
    if len(t):
        low = np.where(
            meets[:, t, r],
            np.concatenate([_capsule_entry(along, length, bound, t, r), grown[:, t, r]]),
            np.inf,
        )
        entered = capsules + box[t, r]
        low[entered, np.arange(len(t))] = np.inf
        settled = enters[t, r] < low.min(axis=0)
        first[t[settled], r[settled]] = entered[settled]
    # A ray that is not central and goes through a capsule not its own (closer to its axis than
    # its radius less the margin, at ``passes`` along the ray) before it can meet one of its own
    # shapes is blocked by the body.
    through = (distance < radius[nc] - margin) & ~own[nr, nc] & ~central[nr]
    if through.any():
        nc, nt, nr, passes = nc[through], nt[through], nr[through], passes[through]
        blocked_at = np.full(cast.shape, np.inf)
        np.minimum.at(blocked_at, (nt, nr), passes)
        blocker = np.full(cast.shape, -1)
        blocker[nt, nr] = nc
        t, r = np.nonzero(cast & (first < 0) & np.isfinite(blocked_at))
        own_capsule = own.T[:capsules, r] & (closest[:, t, r] < bound[:, :, 0] * bound[:, :, 0])
        own_box = own.T[capsules:, r] & np.isfinite(grown[:, t, r])
        own_low = np.minimum(
            np.where(own_capsule, _capsule_entry(along, length, bound, t, r), np.inf).min(axis=0),
            np.where(own_box, grown[:, t, r], np.inf).min(axis=0),
        )
        settled = blocked_at[t, r] < own_low
        first[t[settled], r[settled]] = blocker[t[settled], r[settled]]
    return cast & (first < 0), first
