"""The drivers of a :class:`~fpg_gym.reconstruct.reconstructor.Reconstructor`: one frame, a
warm-up, a recording frame by frame and a whole recording, each a loop of the reconstructor's
``prepare`` / ``search`` / ``finish``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from tqdm import tqdm

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.poses import RecordingLike
from fpg_gym.core.seeding import as_generator
from fpg_gym.reconstruct.bones import BoneSettler
from fpg_gym.reconstruct.config import ReconstructorConfig
from fpg_gym.reconstruct.kernels import compile_kernels
from fpg_gym.reconstruct.problem import SearchProblem
from fpg_gym.reconstruct.records import FrameRecord, ReconstructionResult
from optimizers import Optimizer, SearchResult, make

__all__ = ["FrameDrivers"]


class FrameDrivers:
    """The drivers :class:`~fpg_gym.reconstruct.reconstructor.Reconstructor` inherits: they run
    its per-frame pipeline (``prepare``, ``search``, ``finish``, ``reset``)."""

    config: ReconstructorConfig
    graph: Any
    bones: BoneSettler
    _pending: Any

    def prepare(
        self, positions: np.ndarray, states: np.ndarray, timestamp: float | None = None
    ) -> SearchProblem:
        raise NotImplementedError

    def search(
        self,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> SearchResult:
        raise NotImplementedError

    def finish(self, z: np.ndarray | None = None) -> tuple[np.ndarray, FrameRecord]:
        raise NotImplementedError

    def reset(self) -> None:
        raise NotImplementedError

    def reconstruct_frame(
        self,
        positions: np.ndarray,
        states: np.ndarray,
        timestamp: float | None = None,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> tuple[np.ndarray, FrameRecord]:
        """``prepare``, :meth:`search` with ``optimizer`` (a registered name or an object),
        ``finish``."""
        opt = make(optimizer)
        generator = as_generator(rng)
        self.prepare(positions, states, timestamp)
        try:
            found = self.search(opt, generator)
        except BaseException:
            self._pending = None
            raise
        return self.finish(found.x)

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

    def iter_frames(
        self,
        recording: RecordingLike,
        optimizer: Optimizer | str = "local-search",
        rng: np.random.Generator | int | None = None,
    ) -> Iterator[tuple[np.ndarray, FrameRecord]]:
        """Reconstruct a recording frame by frame (a generator; starts with :meth:`reset`).

        ``recording`` needs ``positions`` (T,20,3), ``states`` (T,20) and optionally
        ``timestamps`` (T,).
        """
        positions = pose_utils.as_poses(recording.positions, "recording.positions", ndim=3)
        states = np.asarray(recording.states)
        if states.shape != positions.shape[:2]:
            raise ValueError(
                f"recording.states: expected shape {positions.shape[:2]}, got {states.shape}"
            )
        stamps = getattr(recording, "timestamps", None)
        timestamps = (
            np.arange(len(positions)) * self.config.frame_dt
            if stamps is None
            else np.asarray(stamps, dtype=np.float64)
        )
        opt = make(optimizer)
        generator = as_generator(rng)
        self.reset()
        for i in range(len(positions)):
            yield self.reconstruct_frame(positions[i], states[i], timestamps[i], opt, generator)

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
        """Reconstruct a whole recording.

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
        total = len(recording.positions)
        last_checkpoint = time.monotonic()
        poses = np.zeros((total, skeleton.NUM_JOINTS, 3), dtype=np.float32)
        records: list[FrameRecord] = []
        bar = None
        if progress:
            bar = tqdm(total=total, unit="frame", desc="reconstruct", leave=False)
        interrupted = False
        try:
            for i, (pose, record) in enumerate(self.iter_frames(recording, optimizer, rng)):
                poses[i] = pose
                records.append(record)
                if bar is not None:
                    bar.update(1)
                now = time.monotonic()
                if checkpoint is not None and 0 < checkpoint_s <= now - last_checkpoint:
                    done = len(records)
                    checkpoint(
                        ReconstructionResult(
                            poses[:done].copy(), list(records), True, bones=self.bones.report()
                        )
                    )
                    last_checkpoint = time.monotonic()
        except KeyboardInterrupt:
            if not stop_on_interrupt:
                raise
            interrupted = True
        finally:
            if bar is not None:
                bar.close()
        return ReconstructionResult(
            poses[: len(records)], records, interrupted, bones=self.bones.report()
        )
