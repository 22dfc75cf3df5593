"""The errors an env step reports and rewards: FPG Eq. 13 of the output and of the sensor
against an episode's ground truth, and the output's acceleration over its last three frames."""

from __future__ import annotations

import math

import numpy as np

from fpg_gym.core.metrics import (
    acceleration,
    bone_vector_errors,
    frame_error,
    second_difference_norms,
)
from fpg_gym.core.poses import bone_vectors
from fpg_gym.io.recording import Recording
from fpg_gym.reconstruct.streams import Stream

__all__ = ["StepErrors"]


def _bone_mean(terms: np.ndarray) -> np.ndarray:
    """FPG Eq. 13 per frame from its bone terms ``(T, 19)``: their mean, the bones added one
    after the other, as numpy's mean in :func:`~fpg_gym.core.metrics.frame_error` of two stacked
    frames adds them (the rewards and errors are those it gives, to the bit)."""
    return np.add.accumulate(terms, axis=-1)[..., -1] / terms.shape[-1]


class StepErrors:
    """One episode's step errors; :meth:`reset` at each episode, :meth:`output` at each step.

    The outputs and their timestamps are the episode's stream's
    (:class:`~fpg_gym.reconstruct.streams.Stream`), read where it keeps them.
    """

    def __init__(self) -> None:
        self._truth: np.ndarray | None = None
        self._truth_bones: np.ndarray | None = None  # (T, 19, 3) of the ground truth
        self._raw_errors: np.ndarray | None = None  # (T,) FPG Eq. 13 of the sensor stream

    def reset(self, recording: Recording) -> None:
        """Start an episode: the truth's bone vectors and the sensor stream's errors, once."""
        self._truth = recording.ground_truth
        self._truth_bones = self._raw_errors = None
        if self._truth is not None:
            self._truth_bones = bone_vectors(self._truth.astype(np.float64))
            sensor = bone_vectors(recording.positions.astype(np.float64))
            self._raw_errors = _bone_mean(bone_vector_errors(self._truth_bones, sensor))

    def output(self, stream: Stream) -> dict[str, float]:
        """The errors of the stream's last finished frame ``t``: ``frame_error`` and
        ``raw_frame_error`` (with ground truth) and ``acceleration`` (m/s², the mean over joints
        of the outputs of frames ``t - 2 ... t``; 0 before).

        Raises
        ------
        ValueError
            On a non-finite output, naming the bad value.
        """
        t = stream.next - 1
        errors: dict[str, float] = {}
        if self._truth is not None:
            assert self._truth_bones is not None and self._raw_errors is not None
            output = bone_vectors(stream.poses[t : t + 1].astype(np.float64))
            terms = bone_vector_errors(self._truth_bones[t : t + 1], output)
            error = float(_bone_mean(terms)[0])
            if not math.isfinite(error):
                frame_error(self._truth[t], stream.poses[t])  # raises, naming the bad value
            errors["frame_error"] = error
            errors["raw_frame_error"] = float(self._raw_errors[t])
        errors["acceleration"] = 0.0
        if t >= 2:
            outputs = stream.poses[t - 2 : t + 1].astype(np.float64)
            s0, s1, s2 = (float(record.timestamp) for record in stream.records[-3:])
            jerk = float("nan")
            if s0 < s1 < s2:
                jerk = float(second_difference_norms(outputs, np.array([s0, s1, s2])).mean())
            if not math.isfinite(jerk):
                acceleration(outputs, timestamps=[s0, s1, s2])  # raises, naming the bad value
            errors["acceleration"] = jerk
        return errors
