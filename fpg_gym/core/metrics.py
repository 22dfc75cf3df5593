"""Error and quality measures of skeleton streams (FPG 2016 §8, Shum 2013 §VIII).

Every function is vectorised over frames and joints; positions are ``(T, 20, 3)`` arrays in
metres (any space, as long as reference and estimate share it).

* :func:`frame_error` — FPG Eq. 13 (= Shum Eq. 18) per frame: the mean over the 19 bones of the
  distance between reference and estimated *bone vectors*. Comparing bone vectors instead of
  positions makes the error independent of where the root is.
* :func:`mean_error` — Eq. 13 over all frames; :func:`err_ratio` — Err0.2, the share of frames
  whose error is at least 0.2 m (FPG Table 2).
* :func:`bone_length_variation` — standard deviation over time of each bone's length: a clean
  skeleton has none, the Kinect has some because it estimates every joint independently.
* :func:`bones_tracked` — which bones have both joints tracked, from a per-joint mask.
* :func:`acceleration` / :func:`jitter` — acceleration magnitude per joint and frame from second
  differences, and its mean per joint.
* :func:`lag` — the time shift (frames) that best aligns an estimate with the ground truth
  (least-squares cross-correlation, sub-frame by parabolic interpolation).
* :func:`settled_bone_spread` — each bone's length range (max − min) after the first second of
  a stream: bones that keep moving once the user's lengths should be known.
* :func:`error_histogram` / :func:`band_shares` — frames per error band of FPG §8
  (:data:`ERROR_BAND_EDGES`: 0–5, 5–10, 10–15, 15–20, 20–30, ≥ 30 cm).
* :func:`frames_above` — the share of frames whose error is at least each threshold, the
  cumulative curve of FPG Fig. 7 (:func:`err_ratio` is its value at 0.2 m).
* :func:`per_joint_error` — the Eq. 13 summand of each joint (its bone to the parent), averaged
  over frames.
* :func:`root_relative_error` — each joint's distance to the reference once both skeletons have
  their root (HipCenter) at the origin, averaged over frames.
* :func:`joint_distances` / :func:`mpjpe` — the field's mean per-joint position error: absolute
  (``align="none"``, in the space both share), root-relative (``"root"``) or after the
  similarity Procrustes alignment of each frame (``"procrustes"``, PA-MPJPE); an optional
  ``(T, 20)`` mask scores a subset of joints (occluded or visible ones).
* :func:`bone_length_error` — each bone's mean absolute length error against the reference
  (a constant wrong bone has no spread but this error).
* :func:`time_summary` — median, p95, mean and max of per-frame computation times.
* :func:`bootstrap_mean_ci`, :func:`robust_z_scores` — statistics over episodes or sessions,
  defined in :mod:`fpg_gym.core.statistics` and importable from here too.

Examples
--------
>>> import numpy as np
>>> from fpg_gym.core import metrics, poses
>>> clip = np.repeat(poses.rest_pose()[None], 5, axis=0)
>>> round(float(metrics.mean_error(clip, clip + 0.1)), 6)  # a rigid shift moves no bone vector
0.0
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from fpg_gym.core import poses, skeleton
from fpg_gym.core.statistics import bootstrap_mean_ci, robust_z_scores

__all__ = [
    "ERROR_BAND_EDGES",
    "ERR_THRESHOLD_M",
    "acceleration",
    "band_shares",
    "bone_length_error",
    "bone_length_variation",
    "bone_vector_errors",
    "bones_tracked",
    "bootstrap_mean_ci",
    "err_ratio",
    "error_histogram",
    "frame_error",
    "frames_above",
    "jitter",
    "joint_distances",
    "lag",
    "mean_error",
    "mpjpe",
    "per_joint_error",
    "robust_z_scores",
    "root_relative_error",
    "second_difference_norms",
    "settled_bone_spread",
    "time_summary",
]

#: Frames searched on each side by :func:`lag` (a third of a second at 30 Hz).
MAX_LAG_FRAMES = 10
#: Seconds at the start of a stream that :func:`settled_bone_spread` leaves out.
SETTLE_S = 1.0
#: Rounding a frame time may carry (``k / 30`` s is not exact in floating point): a frame within
#: it of ``settle_s`` is past the settling period (:func:`settled_bone_spread`,
#: :class:`fpg_gym.reconstruct.bones.OutputLengths`).
TIME_TOLERANCE_S = 1e-9

#: The threshold of Err0.2 (FPG Table 2), metres.
ERR_THRESHOLD_M = 0.2

#: Edges of the error bands of the FPG §8 histograms, metres: 0–0.05, 0.05–0.1, 0.1–0.15,
#: 0.15–0.2, 0.2–0.3 and ≥ 0.3 (the last band is open).
ERROR_BAND_EDGES: tuple[float, ...] = (0.0, 0.05, 0.10, 0.15, 0.20, 0.30, float("inf"))


def _clip_array(value: object, name: str) -> np.ndarray:
    """Validate a ``(T, 20, 3)`` array (T >= 1) and return it as float64."""
    array = np.asarray(value, dtype=np.float64)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[1:] != (skeleton.NUM_JOINTS, 3):
        raise ValueError(f"{name}: expected shape (T, 20, 3) or (20, 3), got {array.shape}")
    if len(array) == 0:
        raise ValueError(f"{name}: no frames")
    if not np.all(np.isfinite(array)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(array))[0])
        raise ValueError(f"{name}: non-finite value at index {bad}")
    return array


def frame_error(reference: npt.ArrayLike, estimate: npt.ArrayLike) -> np.ndarray:
    """FPG Eq. 13 per frame: mean over bones of ``||(r(j) - r(pa j)) - (x(j) - x(pa j))||``.

    The paper writes the mean over the joints; the root has no parent, so the mean runs over the
    19 bones (joints with a parent), see :data:`fpg_gym.core.skeleton.BONES`.

    Parameters
    ----------
    reference, estimate : array_like, shape (T, 20, 3) or (20, 3)
        Ground truth and estimated joint positions in metres, in the same space.

    Returns
    -------
    ndarray, shape (T,), float64
        Error of each frame in metres.

    Raises
    ------
    ValueError
        If a shape is wrong, the shapes differ, or a value is NaN/inf.
    """
    return _bone_errors(reference, estimate).mean(axis=1)


def _bone_errors(reference: npt.ArrayLike, estimate: npt.ArrayLike) -> np.ndarray:
    """Eq. 13 terms per frame and bone, ``(T, 19)``: ``||(r(j) - r(pa j)) - (x(j) - x(pa j))||``."""
    ref = _clip_array(reference, "reference")
    est = _clip_array(estimate, "estimate")
    if ref.shape != est.shape:
        raise ValueError(f"reference {ref.shape} and estimate {est.shape} differ in shape")
    return bone_vector_errors(poses.bone_vectors(ref), poses.bone_vectors(est))


def bone_vector_errors(reference_bones: np.ndarray, estimate_bones: np.ndarray) -> np.ndarray:
    """Eq. 13 terms of bone vectors ``(T, 19, 3)`` (float64, unchecked), ``(T, 19)``.

    :func:`frame_error` checks its poses and takes the mean over the bones of these; a caller
    that scores many estimates against one reference computes the reference's bone vectors
    (:func:`fpg_gym.core.poses.bone_vectors`) once.
    """
    diff = reference_bones - estimate_bones
    return np.sqrt(np.einsum("tbc,tbc->tb", diff, diff))


def mean_error(reference: npt.ArrayLike, estimate: npt.ArrayLike) -> float:
    """FPG Eq. 13 over a whole sequence: mean over frames and bones, metres."""
    return float(frame_error(reference, estimate).mean())


def err_ratio(errors: npt.ArrayLike, threshold: float = ERR_THRESHOLD_M) -> float:
    """Err0.2 (FPG Table 2): the share of frames whose error is at least ``threshold``.

    Parameters
    ----------
    errors : array_like, shape (T,)
        Per-frame errors, e.g. from :func:`frame_error`.
    threshold : float
        Metres; 0.2 in the paper.

    Returns
    -------
    float
        A share in [0, 1] (multiply by 100 for the paper's percentages).
    """
    return float(np.mean(_errors_array(errors) >= threshold))


def bone_length_variation(
    positions: npt.ArrayLike, states: npt.ArrayLike | None = None, *, min_frames: int = 2
) -> np.ndarray:
    """Standard deviation over time of each bone's length, metres, ``(19,)``.

    Parameters
    ----------
    positions : array_like, shape (T, 20, 3)
    states : array_like, shape (T, 20), optional
        Tracking states (2 tracked, 1 inferred, 0 not tracked). When given, a bone's length
        counts only in frames where both of its joints are tracked (state 2), as a sensor-side
        statistic of independently estimated joints.
    min_frames : int
        A bone seen in fewer frames gets NaN.

    Returns
    -------
    ndarray, shape (19,), float64
        Per-bone standard deviation (NaN where a bone has fewer than ``min_frames`` frames);
        ``np.nanmean`` of it is the summary the realism table reports.
    """
    pos = _clip_array(positions, "positions")
    lengths = poses.bone_lengths(pos)  # (T, 19)
    if states is None:
        use = np.ones_like(lengths, dtype=bool)
    else:
        use = bones_tracked(_states_array(states, len(pos)) == skeleton.TRACKED)
    count = use.sum(axis=0)
    safe = np.maximum(count, 1)
    mean = np.where(use, lengths, 0.0).sum(axis=0) / safe
    var = np.where(use, (lengths - mean) ** 2, 0.0).sum(axis=0) / safe
    return np.where(count >= min_frames, np.sqrt(var), np.nan)


def bones_tracked(tracked: npt.ArrayLike) -> np.ndarray:
    """Bones with both joints tracked: a per-joint mask ``(..., 20)`` -> per-bone ``(..., 19)``.

    ``tracked`` says which joints count as tracked (e.g. ``states == skeleton.TRACKED``); a
    bone's entry is True when its parent and child joints both are.
    """
    mask = np.asarray(tracked, dtype=bool)
    return mask[..., skeleton.BONES[:, 0]] & mask[..., skeleton.BONES[:, 1]]


def acceleration(
    positions: npt.ArrayLike,
    *,
    fps: float = 30.0,
    timestamps: npt.ArrayLike | None = None,
) -> np.ndarray:
    """Acceleration magnitude of each joint at frames 1..T-2, m/s², ``(T - 2, 20)``.

    The second difference of positions over the (possibly uneven) frame intervals:
    ``2 ((p[t+1]-p[t])/h1 - (p[t]-p[t-1])/h0) / (h0 + h1)``.

    Parameters
    ----------
    positions : array_like, shape (T, 20, 3)
    fps : float
        Frame rate used when ``timestamps`` is omitted.
    timestamps : array_like, shape (T,), optional
        Seconds, strictly increasing.
    """
    pos = _clip_array(positions, "positions")
    count = len(pos)
    times = _times(count, fps, timestamps)
    if count > 1 and not np.all(np.diff(times) > 0):
        raise ValueError("timestamps: must be strictly increasing")
    if count < 3:
        return np.zeros((0, skeleton.NUM_JOINTS))
    return second_difference_norms(pos, times)


def second_difference_norms(positions: np.ndarray, times: np.ndarray) -> np.ndarray:
    """:func:`acceleration` of float64 positions ``(T, 20, 3)`` (T >= 3) at strictly
    increasing ``times`` ``(T,)`` (unchecked), m/s², ``(T - 2, 20)``."""
    pos = positions
    h0 = (times[1:-1] - times[:-2])[:, None, None]
    h1 = (times[2:] - times[1:-1])[:, None, None]
    acc = 2.0 * ((pos[2:] - pos[1:-1]) / h1 - (pos[1:-1] - pos[:-2]) / h0) / (h0 + h1)
    # np.linalg.norm(acc, axis=-1)'s reductions, without its dispatch (the same values)
    return np.asarray(np.sqrt(np.add.reduce(acc * acc, axis=-1)))


def jitter(
    positions: npt.ArrayLike,
    *,
    fps: float = 30.0,
    timestamps: npt.ArrayLike | None = None,
    valid: npt.ArrayLike | None = None,
) -> np.ndarray:
    """Mean acceleration magnitude of each joint, m/s², ``(20,)``.

    The mean of :func:`acceleration` over the frames whose three neighbours are valid. On a
    real stream it mixes the motion's own acceleration with the sensor's vibration; compare a
    raw stream with its ground truth, or streams of similar motions.

    Parameters
    ----------
    positions : array_like, shape (T, 20, 3)
    fps : float
        Frame rate used when ``timestamps`` is omitted.
    timestamps : array_like, shape (T,), optional
        Seconds, strictly increasing.
    valid : array_like of bool, shape (T,), optional
        Frames to use (e.g. frames with a body); an acceleration needs three valid frames.

    Returns
    -------
    ndarray, shape (20,), float64
        NaN for every joint when fewer than three consecutive valid frames exist.
    """
    magnitudes = acceleration(positions, fps=fps, timestamps=timestamps)
    count = len(magnitudes) + 2
    ok = np.ones(count, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if ok.shape != (count,) and len(magnitudes):
        raise ValueError(f"valid: expected shape ({count},), got {ok.shape}")
    if not len(magnitudes):
        return np.full(skeleton.NUM_JOINTS, np.nan)
    use = ok[:-2] & ok[1:-1] & ok[2:]
    if not use.any():
        return np.full(skeleton.NUM_JOINTS, np.nan)
    return np.asarray(magnitudes[use].mean(axis=0))


def _states_array(states: npt.ArrayLike, count: int) -> np.ndarray:
    st = np.asarray(states)
    if st.shape != (count, skeleton.NUM_JOINTS):
        raise ValueError(f"states: expected shape ({count}, 20), got {st.shape}")
    return st


def _errors_array(errors: npt.ArrayLike, name: str = "errors") -> np.ndarray:
    values = np.asarray(errors, dtype=np.float64).reshape(-1)
    if values.size == 0:
        raise ValueError(f"{name}: empty")
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name}: non-finite value")
    return values


def _edges_array(edges: npt.ArrayLike) -> np.ndarray:
    array = np.asarray(edges, dtype=np.float64).reshape(-1)
    if len(array) < 2 or np.isnan(array).any() or not np.all(np.diff(array) > 0):
        raise ValueError(
            f"edges: expected at least two strictly increasing values, got {array.tolist()}"
        )
    return array


def error_histogram(errors: npt.ArrayLike, edges: npt.ArrayLike = ERROR_BAND_EDGES) -> np.ndarray:
    """Number of frames in each error band (FPG §8 histograms).

    Band ``i`` holds the errors ``e`` with ``edges[i] <= e < edges[i + 1]``; the last edge may be
    ``inf`` (an open band). Errors outside ``[edges[0], edges[-1])`` are not counted.

    Parameters
    ----------
    errors : array_like, shape (T,)
        Per-frame errors in metres (e.g. :func:`frame_error`).
    edges : array_like, shape (B + 1,)
        Band edges in metres, strictly increasing; :data:`ERROR_BAND_EDGES` by default.

    Returns
    -------
    ndarray, shape (B,), int64
    """
    values = _errors_array(errors)
    bounds = _edges_array(edges)
    # Half-open bands [low, high): searchsorted "right" puts an error equal to an edge in the
    # band that starts there, as "0.2 m or more" counts for Err0.2.
    band = np.searchsorted(bounds, values, side="right") - 1
    inside = (band >= 0) & (band < len(bounds) - 1)
    return np.bincount(band[inside], minlength=len(bounds) - 1).astype(np.int64)


def band_shares(errors: npt.ArrayLike, edges: npt.ArrayLike = ERROR_BAND_EDGES) -> np.ndarray:
    """Share of frames (in [0, 1]) in each band of :func:`error_histogram`, ``(B,)``."""
    values = _errors_array(errors)
    return error_histogram(values, edges) / len(values)


def frames_above(errors: npt.ArrayLike, thresholds: npt.ArrayLike) -> np.ndarray:
    """Share of frames whose error is at least each threshold (FPG Fig. 7).

    A non-increasing curve from 1 (threshold 0) to 0; its value at 0.2 m is
    :func:`err_ratio`.

    Parameters
    ----------
    errors : array_like, shape (T,)
        Per-frame errors in metres.
    thresholds : array_like, shape (N,)
        Thresholds in metres.

    Returns
    -------
    ndarray, shape (N,), float64
        Shares in [0, 1].
    """
    values = np.sort(_errors_array(errors))
    limits = np.asarray(thresholds, dtype=np.float64).reshape(-1)
    if np.isnan(limits).any():
        raise ValueError("thresholds: NaN value")
    below = np.searchsorted(values, limits, side="left")  # errors < threshold
    return 1.0 - below / len(values)


def per_joint_error(reference: npt.ArrayLike, estimate: npt.ArrayLike) -> np.ndarray:
    """Mean over frames of each joint's Eq. 13 summand, metres, ``(20,)``.

    Joint ``j``'s entry is the mean over frames of ``||(r(j) - r(pa j)) - (x(j) - x(pa j))||``,
    the error of the bone that ends at ``j``; the root has no parent and gets NaN. The mean of
    the 19 finite entries is :func:`mean_error`.
    """
    result = np.full(skeleton.NUM_JOINTS, np.nan)
    result[skeleton.BONES[:, 1]] = _bone_errors(reference, estimate).mean(axis=0)
    return result


def root_relative_error(reference: npt.ArrayLike, estimate: npt.ArrayLike) -> np.ndarray:
    """Mean over frames of ``||(r(j) - r(root)) - (x(j) - x(root))||``, metres, ``(20,)``.

    Where :func:`per_joint_error` scores the bone that ends at a joint, this scores where the
    joint is relative to the hips, so errors along the chain add up (a wrong spine moves the
    head and both arms). The root's entry is 0.
    """
    return np.asarray(joint_distances(reference, estimate, "root").mean(axis=0))


ALIGNMENTS: tuple[str, ...] = ("none", "root", "procrustes")
"""Alignments of :func:`joint_distances`: none (absolute), root-relative, Procrustes."""


def _procrustes_aligned(reference: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """Each frame of ``estimate`` moved onto ``reference`` by the similarity transform (scale,
    rotation, translation) that minimises the squared joint distances (Umeyama 1991), as
    PA-MPJPE does; vectorised over frames."""
    ref_mean = reference.mean(axis=1, keepdims=True)
    est_mean = estimate.mean(axis=1, keepdims=True)
    ref_c, est_c = reference - ref_mean, estimate - est_mean
    covariance = np.einsum("tji,tjk->tik", est_c, ref_c)  # (T, 3, 3): sum_j x_j r_j^T
    u, sigma, vt = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(np.einsum("tij,tjk->tik", u, vt)))
    sign[sign == 0] = 1.0
    fix = np.ones_like(sigma)
    fix[:, 2] = sign
    rotation = np.einsum("tij,tj,tjk->tik", u, fix, vt)  # x -> x @ rotation
    variance = np.einsum("tjc,tjc->t", est_c, est_c)
    scale = (sigma * fix).sum(axis=1) / np.maximum(variance, 1e-12)
    aligned: np.ndarray = scale[:, None, None] * np.einsum("tjc,tck->tjk", est_c, rotation)
    return aligned + ref_mean


def joint_distances(
    reference: npt.ArrayLike, estimate: npt.ArrayLike, align: str = "none"
) -> np.ndarray:
    """Each joint's distance to the reference in each frame, metres, ``(T, 20)``.

    Parameters
    ----------
    reference, estimate : array_like, shape (T, 20, 3) or (20, 3)
    align : {"none", "root", "procrustes"}
        ``"none"``: absolute positions in the space both share (MPJPE); ``"root"``: both
        skeletons with their root (HipCenter) at the origin (root-relative MPJPE);
        ``"procrustes"``: the estimate moved onto the reference per frame by the best
        similarity transform (PA-MPJPE).
    """
    if align not in ALIGNMENTS:
        raise ValueError(f"align: expected one of {', '.join(ALIGNMENTS)}, got {align!r}")
    ref = _clip_array(reference, "reference")
    est = _clip_array(estimate, "estimate")
    if ref.shape != est.shape:
        raise ValueError(f"reference {ref.shape} and estimate {est.shape} differ in shape")
    if align == "root":
        ref = ref - ref[:, skeleton.ROOT : skeleton.ROOT + 1]
        est = est - est[:, skeleton.ROOT : skeleton.ROOT + 1]
    elif align == "procrustes":
        est = _procrustes_aligned(ref, est)
    return np.asarray(np.linalg.norm(ref - est, axis=-1))


def mpjpe(
    reference: npt.ArrayLike,
    estimate: npt.ArrayLike,
    align: str = "none",
    mask: npt.ArrayLike | None = None,
) -> float:
    """Mean per-joint position error, metres (:func:`joint_distances` averaged).

    Parameters
    ----------
    reference, estimate : array_like, shape (T, 20, 3)
    align : {"none", "root", "procrustes"}
        See :func:`joint_distances` (MPJPE, root-relative MPJPE, PA-MPJPE).
    mask : array_like of bool, shape (T, 20), optional
        The joint-frames to score (e.g. the occluded ones); NaN when it selects none.
    """
    distances = joint_distances(reference, estimate, align)
    if mask is None:
        return float(distances.mean())
    selected = np.asarray(mask, dtype=bool)
    if selected.shape != distances.shape:
        raise ValueError(f"mask: expected shape {distances.shape}, got {selected.shape}")
    return float(distances[selected].mean()) if selected.any() else float("nan")


def bone_length_error(reference: npt.ArrayLike, estimate: npt.ArrayLike) -> np.ndarray:
    """Mean over frames of ``| |x bone| - |r bone| |`` for each of the 19 bones, metres.

    Where :func:`bone_length_variation` and :func:`settled_bone_spread` measure whether a bone
    keeps its length, this measures whether it has the right one.
    """
    ref = _clip_array(reference, "reference")
    est = _clip_array(estimate, "estimate")
    if ref.shape != est.shape:
        raise ValueError(f"reference {ref.shape} and estimate {est.shape} differ in shape")
    return np.asarray(np.abs(poses.bone_lengths(est) - poses.bone_lengths(ref)).mean(axis=0))


def time_summary(milliseconds: npt.ArrayLike) -> dict[str, float]:
    """Summary of per-frame computation times: ``median``, ``p95``, ``mean``, ``max`` (ms).

    Raises
    ------
    ValueError
        If ``milliseconds`` is empty, not finite or negative.
    """
    values = _errors_array(milliseconds, "milliseconds")
    if (values < 0).any():
        raise ValueError("milliseconds: negative value")
    return {
        "median": float(np.median(values)),
        "p95": float(np.percentile(values, 95)),
        "mean": float(values.mean()),
        "max": float(values.max()),
    }


def _times(count: int, fps: float, timestamps: npt.ArrayLike | None) -> np.ndarray:
    """Frame times in seconds: ``timestamps`` validated, else ``arange(count) / fps``."""
    if timestamps is None:
        if not fps > 0:
            raise ValueError(f"fps: expected a positive frame rate, got {fps}")
        return np.arange(count) / float(fps)
    times = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    if times.shape != (count,):
        raise ValueError(f"timestamps: expected shape ({count},), got {times.shape}")
    if not np.all(np.isfinite(times)):
        raise ValueError("timestamps: non-finite value")
    return times


def lag(
    estimate: npt.ArrayLike,
    reference: npt.ArrayLike,
    *,
    max_frames: int = MAX_LAG_FRAMES,
    valid: npt.ArrayLike | None = None,
) -> float:
    """How many frames ``estimate`` runs behind ``reference`` (negative: ahead).

    The shift ``s`` that best aligns the two streams in the least-squares sense,
    ``argmin_s mean_t ||x(t) - r(t - s)||^2`` over the frames both cover; the expanded square
    is ``|x|^2 + |r|^2 - 2 x . r``, the energy-normalised form of the cross-correlation
    ``sum_t x(t) . r(t - s)``. The plain cross-correlation of a steady motion (a ramp) grows
    with the overlap and peaks nowhere; the least-squares form is exact on it. The signal is
    the root's position and every other joint's position relative to the root, so a lag of the
    limbs counts as much as a lag of the whole body. Integer shifts in ``[-max_frames,
    max_frames]`` are scored, then the minimum is refined to a fraction of a frame by a parabola
    through it and its two neighbours.

    Parameters
    ----------
    estimate, reference : array_like, shape (T, 20, 3)
        Output and ground truth in the same space, same frame times (T >= 3).
    max_frames : int
        Largest shift tried, frames (10; fewer on a stream shorter than ``max_frames + 3``).
    valid : array_like of bool, shape (T,), optional
        Frames to use (e.g. frames with a body); a pair of frames counts when both are valid.

    Returns
    -------
    float
        Frames (multiply by the frame interval for seconds); NaN for fewer than 4 frames or
        when fewer than 3 valid frames overlap at some shift.
    """
    est = _clip_array(estimate, "estimate")
    ref = _clip_array(reference, "reference")
    if est.shape != ref.shape:
        raise ValueError(f"estimate {est.shape} and reference {ref.shape} differ in shape")
    if max_frames < 1:
        raise ValueError(f"max_frames: expected >= 1, got {max_frames}")
    count = len(est)
    max_frames = min(max_frames, count - 3)  # every shift keeps at least 3 common frames
    if max_frames < 1:
        return float("nan")
    ok = np.ones(count, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if ok.shape != (count,):
        raise ValueError(f"valid: expected shape ({count},), got {ok.shape}")

    def local(p: np.ndarray) -> np.ndarray:
        out = p - p[:, skeleton.ROOT : skeleton.ROOT + 1]
        out[:, skeleton.ROOT] = p[:, skeleton.ROOT]
        return out.reshape(count, -1)

    x, r = local(est), local(ref)
    shifts = np.arange(-max_frames, max_frames + 1)
    cost = np.full(len(shifts), np.nan)
    for i, s in enumerate(shifts.tolist()):  # 2 * max_frames + 1 shifts, vectorised over frames
        lo, hi = max(0, s), min(count, count + s)  # x(t), r(t - s) for t in [lo, hi)
        if hi - lo < 3:
            continue
        use = ok[lo:hi] & ok[lo - s : hi - s]
        if use.sum() < 3:
            continue
        diff = x[lo:hi][use] - r[lo - s : hi - s][use]
        cost[i] = float(np.linalg.norm(diff.reshape(len(diff), -1, 3), axis=-1).mean())
    if np.isnan(cost).any():
        return float("nan")
    best = int(np.argmin(cost))
    offset = 0.0
    if 0 < best < len(shifts) - 1:
        left, mid, right = cost[best - 1], cost[best], cost[best + 1]
        curvature = left - 2.0 * mid + right
        if curvature > 0:
            offset = float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5))
    return float(shifts[best] + offset)


def settled_bone_spread(
    positions: npt.ArrayLike,
    *,
    fps: float = 30.0,
    timestamps: npt.ArrayLike | None = None,
    settle_s: float = SETTLE_S,
    valid: npt.ArrayLike | None = None,
) -> np.ndarray:
    """Each bone's length range (max − min, metres) after the first ``settle_s`` seconds.

    A reconstruction knows its user's bone lengths after a short calibration; from then on a
    bone that changes length is an artefact (a rigid body does not grow). The first second is
    left out so that a fast first estimate is not counted against the settled one.

    Parameters
    ----------
    positions : array_like, shape (T, 20, 3)
    fps : float
        Frame rate used when ``timestamps`` is omitted.
    timestamps : array_like, shape (T,), optional
        Seconds; the stream starts at the first one.
    settle_s : float
        Seconds left out at the start (1.0).
    valid : array_like of bool, shape (T,), optional
        Frames to use (e.g. frames with a body).

    Returns
    -------
    ndarray, shape (19,), float64
        NaN for every bone when fewer than two frames remain.
    """
    pos = _clip_array(positions, "positions")
    times = _times(len(pos), fps, timestamps)
    if settle_s < 0:
        raise ValueError(f"settle_s: expected >= 0, got {settle_s}")
    use = times - times[0] >= settle_s - TIME_TOLERANCE_S
    if valid is not None:
        ok = np.asarray(valid, dtype=bool)
        if ok.shape != (len(pos),):
            raise ValueError(f"valid: expected shape ({len(pos)},), got {ok.shape}")
        use &= ok
    if use.sum() < 2:
        return np.full(skeleton.NUM_BONES, np.nan)
    lengths = poses.bone_lengths(pos[use])
    return np.asarray(lengths.max(axis=0) - lengths.min(axis=0))
