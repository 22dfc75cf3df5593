"""The drivers of a :class:`~fpg_gym.reconstruct.reconstructor.Reconstructor`: one frame, a
warm-up and a whole recording, each a :class:`~fpg_gym.reconstruct.streams.Stream` of one
(the one run path, :mod:`fpg_gym.reconstruct.streams`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.poses import RecordingLike
from fpg_gym.core.seeding import as_generator
from fpg_gym.reconstruct.bones import BoneSettler
from fpg_gym.reconstruct.config import ReconstructorConfig
from fpg_gym.reconstruct.kernels import compile_kernels
from fpg_gym.reconstruct.records import FrameOutput, ReconstructionResult
from fpg_gym.reconstruct.streams import Stream, reconstruct_stream, step_streams
from optimizers import Optimizer, make

__all__ = ["FrameDrivers"]


class FrameDrivers:
    """The drivers :class:`~fpg_gym.reconstruct.reconstructor.Reconstructor` inherits: they run
    its per-frame pipeline (``prepare``, a search, ``finish``) through a
    :class:`~fpg_gym.reconstruct.streams.Stream`."""

    config: ReconstructorConfig
    graph: Any
    bones: BoneSettler
    _pending: Any

    def reset(self) -> None:
        raise NotImplementedError

    def drop_frame(self) -> None:
        """Forget the prepared frame, if any (after a failed search: the next ``prepare``
        continues the stream from the frame before)."""
        self._pending = None

    def reconstruct_frame(
        self,
        positions: np.ndarray,
        states: np.ndarray,
        timestamp: float | None = None,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> FrameOutput:
        """``prepare``, a search with ``optimizer`` (a registered name or an object),
        ``finish``: the frame's pose and record."""
        stream = Stream(self, optimizer=make(optimizer), rng=as_generator(rng))  # type: ignore[arg-type]
        return step_streams([stream], frames=[(positions, states, timestamp)])[0]

    def warm_up(self, optimizer: Optimizer | str = "local-search") -> None:
        """Load what a stream's first frames would otherwise load, then start a new stream.

        Compiles (or loads from numba's disk cache) the energy and selection kernels and runs
        two frames of a still database pose standing 2.5 m in front of the sensor, a full search
        then a graph walk, with ``optimizer`` (which loads the compiled local search when it is
        local search) and the ragdoll, when configured; then
        :meth:`reset`, after which the output does not depend on these frames. For a live
        stream, whose first frames would stall for tens of milliseconds otherwise.
        """
        compile_kernels()
        pose = np.asarray(self.graph.poses[0], dtype=np.float64) + np.array([0.0, 1.0, 2.5])
        states = np.full(skeleton.NUM_JOINTS, skeleton.TRACKED)
        try:
            for timestamp in (0.0, self.config.frame_dt):
                self.reconstruct_frame(pose, states, timestamp, optimizer, 0)
        finally:
            self.reset()

    def reconstruct(
        self,
        recording: RecordingLike,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
        *,
        progress: bool = False,
        stop_on_interrupt: bool = False,
        checkpoint: Callable[[ReconstructionResult], None] | None = None,
        checkpoint_s: float = 30.0,
    ) -> ReconstructionResult:
        """Reconstruct a whole recording
        (:func:`~fpg_gym.reconstruct.streams.reconstruct_stream`).

        Parameters
        ----------
        recording : Recording-like
            ``positions`` (T,20,3), ``states`` (T,20), optional ``timestamps`` (T,).
        optimizer : str or Optimizer
            A registered name (``optimizers.available()``) or an optimiser object.
        rng : numpy.random.Generator or int, optional
            Seed or generator for the optimiser (same seed, same output); None: unseeded.
        progress : bool
            Show a tqdm progress bar on stderr.
        stop_on_interrupt : bool
            On Ctrl-C return the frames done (``interrupted=True``) instead of raising.
        checkpoint : callable, optional
            Called every ``checkpoint_s`` seconds (0: never) with the frames done so far (a
            :class:`ReconstructionResult` with ``interrupted=True``), e.g. to write them so that
            a killed run keeps them.
        checkpoint_s : float
            Seconds between checkpoints (30).
        """
        stream = Stream(self, recording, make(optimizer), as_generator(rng))  # type: ignore[arg-type]
        return reconstruct_stream(
            stream,
            progress=progress,
            stop_on_interrupt=stop_on_interrupt,
            checkpoint=checkpoint,
            checkpoint_s=checkpoint_s,
        )
