"""A learned correction of the output pose (beyond the papers; issues 19 and 35).

The papers' output is a point of the frame's local PCA space (Shum et al. 2013 Eq. 9) given the
frame's bone lengths; on real sensors it keeps a systematic miss, because the database's joints
are not the sensor's. A correction model maps what a frame's output and input say, in the
output's own normalised frame (root at the origin, facing +Z, :func:`fpg_gym.core.poses.normalise`),
to an offset of the output's joints (:func:`correction_features`):

* the output pose (60 values);
* the raw sensor frame seen from that frame, its joints not tracked zeroed (60);
* the reliability of each joint (20, Shum Eq. 4);
* the sensor's tracking state of each joint, one-hot (60).

The targets (:func:`correction_targets`) are the truth seen from the output's frame minus the
output, every joint the root included: the root's offset is where the output is placed, which
FPG Eq. 13 (bone vectors) does not see and the absolute joint error (MPJPE) does. A correction
of joints relative to the root would carry the root's own miss to every joint.

The predicted offsets are smoothed causally per stream (:class:`CorrectionState`,
``c_t = alpha p_t + (1 - alpha) c_{t-1}``, starting at ``c_0 = p_0``), because an offset
predicted frame by frame adds jitter, then added to the output in its normalised frame. The
offsets move joints independently, so the corrected bones would change length from frame to
frame; the corrected output is therefore retargeted to settled lengths
(:class:`fpg_gym.reconstruct.bones.OutputLengths`: its own lengths' running mean, bounded as
the reconstructor's are after the first second), keeping each bone's corrected direction.
:func:`corrected_outputs` does the same for whole streams.

This module defines the features, the targets a model learns and how a correction is applied;
the model (:class:`OutputCorrection`, e.g. the ridge model of :mod:`policies.output_correction`)
comes with the optimiser: the reconstructor applies one when the optimiser that searched the
frame has an ``output_correction`` (``learned:`` with a linear sampler trained with one).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.reconstruct.bones import BoneSettlingConfig, OutputLengths, settled_output_lengths

__all__ = [
    "CORRECTION_FEATURES",
    "CorrectionState",
    "OutputCorrection",
    "apply_correction",
    "corrected_outputs",
    "correction_features",
    "correction_frames",
    "correction_targets",
    "output_correction_of",
    "settle_lengths",
    "smooth_corrections",
]

#: Length of a frame's feature row: output pose, sensor pose, reliability, one-hot states.
CORRECTION_FEATURES = 3 * skeleton.NUM_JOINTS * 2 + skeleton.NUM_JOINTS + 3 * skeleton.NUM_JOINTS


@runtime_checkable
class OutputCorrection(Protocol):
    """What the reconstructor needs of a correction model.

    Attributes
    ----------
    smoothing : float
        ``alpha`` in (0, 1] of the causal smoothing (1: none).
    """

    smoothing: float

    def predict(self, features: np.ndarray) -> np.ndarray:
        """Offsets ``(n, 60)`` of the output's joints (metres, in its normalised frame) for
        feature rows ``(n, CORRECTION_FEATURES)``."""
        ...


def output_correction_of(optimizer: object) -> OutputCorrection | None:
    """The correction an optimiser brings (its ``output_correction`` attribute), or None."""
    correction = getattr(optimizer, "output_correction", None)
    if correction is None:  # most optimisers (and a Protocol's isinstance costs ~20 µs)
        return None
    return correction if isinstance(correction, OutputCorrection) else None


def correction_features(
    outputs: np.ndarray, sensor: np.ndarray, states: np.ndarray, reliability: np.ndarray
) -> tuple[np.ndarray, np.ndarray, pose_utils.Placement]:
    """Feature rows of frames (module docstring), with the outputs' normalised poses.

    Parameters
    ----------
    outputs : array_like, shape (n, 20, 3)
        The reconstructor's output poses, camera space.
    sensor : array_like, shape (n, 20, 3)
        The raw sensor frames (before any sensor map), camera space.
    states : array_like, shape (n, 20)
        Tracking states: 0 not tracked, 1 inferred, 2 tracked.
    reliability : array_like, shape (n, 20)
        Each joint's reliability.

    Returns
    -------
    features : ndarray, shape (n, CORRECTION_FEATURES), float64
    local : ndarray, shape (n, 20, 3), float64
        The outputs normalised (root at the origin, facing +Z).
    placement : Placement
        Each output's root and heading (:func:`fpg_gym.core.poses.normalise`).
    """
    local32, placement = pose_utils.normalise(np.asarray(outputs, dtype=np.float64))
    local = local32.astype(np.float64)
    states = np.clip(np.asarray(states).astype(np.int64), 0, 2)
    seen = pose_utils.into_placement(sensor, placement)
    seen = np.where((states > 0)[..., None], seen, 0.0)
    n = len(local)
    features = np.concatenate(
        [
            local.reshape(n, -1),
            seen.reshape(n, -1),
            np.asarray(reliability, dtype=np.float64).reshape(n, -1),
            np.eye(3)[states].reshape(n, -1),
        ],
        axis=1,
    )
    return features, local, placement


def correction_targets(
    local: np.ndarray, placement: pose_utils.Placement, truth: np.ndarray
) -> np.ndarray:
    """What a model learns ``(n, 60)``: the truth seen from each output's frame minus the
    output's normalised pose ``local`` (:func:`correction_features`), every joint the root
    included."""
    return (pose_utils.into_placement(truth, placement) - local).reshape(len(local), -1)


def correction_frames(
    outputs: np.ndarray,
    recording: Any,
    reliability: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, pose_utils.Placement]:
    """A reconstructed recording's frames for a correction: features, targets, and the
    outputs' normalised poses and placements (:func:`correction_features`,
    :func:`correction_targets`), for the first ``len(outputs)`` frames of ``recording`` (its
    ``positions``, ``states`` and ``ground_truth``) and the reliabilities ``(n, 20)``."""
    count = len(outputs)
    features, local, placement = correction_features(
        np.asarray(outputs, dtype=np.float64),
        np.asarray(recording.positions, dtype=np.float64)[:count],
        np.asarray(recording.states)[:count],
        np.asarray(reliability).reshape(count, -1),
    )
    truth = np.asarray(recording.ground_truth, dtype=np.float64)[:count]
    return features, correction_targets(local, placement, truth), local, placement


def smooth_corrections(
    predictions: np.ndarray, episodes: np.ndarray, smoothing: float
) -> np.ndarray:
    """Causal smoothing of per-frame offsets ``(n, K)`` within each run of equal ``episodes``
    labels (consecutive frames of a stream), as :class:`CorrectionState` applies it."""
    from scipy.signal import lfilter

    predictions = np.asarray(predictions, dtype=np.float64)
    if smoothing >= 1.0:
        return predictions
    out = np.empty_like(predictions)
    labels = np.asarray(episodes)
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    for start, stop in zip(starts, np.r_[starts[1:], len(labels)], strict=True):
        part = predictions[start:stop]
        # c_t = a p_t + (1 - a) c_{t-1}, c_0 = p_0: the filter's state starts at (1 - a) p_0.
        out[start:stop], _ = lfilter(
            [smoothing], [1.0, smoothing - 1.0], part, axis=0, zi=(1.0 - smoothing) * part[:1]
        )
    return out


def apply_correction(
    local: np.ndarray, placement: pose_utils.Placement, offsets: np.ndarray
) -> np.ndarray:
    """The outputs moved ``(n, 20, 3)``, float32: normalised poses ``local`` plus ``offsets``
    ``(n, 60)``, put back with ``placement`` (before their lengths settle)."""
    moved = np.asarray(local, dtype=np.float64) + np.asarray(offsets).reshape(np.shape(local))
    return pose_utils.denormalise(moved, placement)


def settle_lengths(
    poses: np.ndarray,
    streams: np.ndarray,
    timestamps: np.ndarray,
    bones: BoneSettlingConfig | None = None,
) -> np.ndarray:
    """Moved poses ``(n, 20, 3)`` of whole streams with settled lengths, as
    :class:`CorrectionState` settles them frame by frame
    (:func:`fpg_gym.reconstruct.bones.settled_output_lengths`: frames with the same
    ``streams`` label in a row are one stream, ``timestamps`` in seconds)."""
    out = np.array(poses, dtype=np.float64)
    lengths = settled_output_lengths(pose_utils.bone_lengths(out), streams, timestamps, bones)
    settled = ~np.isnan(lengths[:, 0])  # frames still settling keep their own lengths
    out[settled] = pose_utils.retarget(out[settled], lengths[settled])
    return out


def corrected_outputs(
    local: np.ndarray,
    placement: pose_utils.Placement,
    offsets: np.ndarray,
    streams: np.ndarray,
    timestamps: np.ndarray,
    bones: BoneSettlingConfig | None = None,
) -> np.ndarray:
    """Whole streams corrected as :class:`CorrectionState` corrects them frame by frame
    ``(n, 20, 3)``: :func:`apply_correction` with the (already smoothed) ``offsets``, then
    :func:`settle_lengths`."""
    return settle_lengths(apply_correction(local, placement, offsets), streams, timestamps, bones)


class CorrectionState:
    """One stream's causal smoothing of a correction's offsets and the settling of the
    corrected output's lengths (module docstring).

    Parameters
    ----------
    bones : BoneSettlingConfig, optional
        The settling rule (the reconstructor's).
    """

    def __init__(self, bones: BoneSettlingConfig | None = None) -> None:
        self.offset: np.ndarray | None = None
        self.lengths = OutputLengths(bones)

    def reset(self) -> None:
        """A new stream: the next offset starts the smoothing afresh, and the lengths settle
        anew."""
        self.offset = None
        self.lengths.reset()

    def correct(
        self,
        model: OutputCorrection,
        output: np.ndarray,
        sensor: np.ndarray,
        states: np.ndarray,
        reliability: np.ndarray,
        timestamp: float,
    ) -> np.ndarray:
        """One frame's output ``(20, 3)`` corrected by ``model`` (camera space, float32), at
        ``timestamp`` seconds."""
        features, local, placement = correction_features(
            output[None], sensor[None], states[None], reliability[None]
        )
        predicted = np.asarray(model.predict(features), dtype=np.float64)[0]
        if self.offset is None:
            self.offset = predicted
        else:
            alpha = float(model.smoothing)
            self.offset = alpha * predicted + (1.0 - alpha) * self.offset
        moved = apply_correction(local, placement, self.offset[None])[0]
        return self.lengths.settle(moved, timestamp).astype(np.float32)
