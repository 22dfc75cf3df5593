"""The one run path: streams of frames through their reconstructors, one stream or many.

Every driver of a :class:`~fpg_gym.reconstruct.Reconstructor`'s per-frame pipeline
(``prepare`` -> a latent point -> ``finish``) goes through a :class:`Stream`, which calls them:

* :func:`step_streams` runs one frame of each stream in lockstep: every stream prepares its
  frame, a *chooser* gives each prepared problem its latent point (:func:`search_streams`, the
  default: each stream's optimiser, the searches side by side,
  :func:`~fpg_gym.reconstruct.search.search_together`; or the caller's, e.g. the imitation
  data's searches and targets), every stream finishes its frame;
* :func:`reconstruct_streams` runs whole recordings that way (progress, Ctrl-C, checkpoints);
  :func:`run_streams` makes the streams' optimisers and generators first, and
  :meth:`Reconstructor.reconstruct <fpg_gym.reconstruct.Reconstructor.reconstruct>` is it for
  one stream;
* a caller whose point comes later (the env: its agent acts between the observation and the
  step) calls :meth:`Stream.prepare` and :meth:`Stream.finish` itself; a live stream
  (:mod:`fpg_gym.methods.live`) gives :func:`step_streams` each frame as it arrives.

Each stream has its own reconstructor (its history, bone lengths, selector state), optimiser
and generator, so a stream's output is the same alone or beside others, with the same seed (to
the last bit with the compiled kernel, to floating-point rounding with numpy's; the tests check
it). What streams share is the search's arithmetic
(:func:`~fpg_gym.reconstruct.search.search_together`).

Per-frame timings
-----------------
The ``search`` stage time of a frame's record (:attr:`FrameRecord.ms`) is the stream's own
share: the time spent in its optimiser's calls plus its share (by rows) of each stacked
evaluation it took part in; ``total`` is corrected with it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from fpg_gym.core import poses as pose_utils
from fpg_gym.core import skeleton
from fpg_gym.core.errors import interrupt_in
from fpg_gym.reconstruct.output_correction import OutputCorrection, output_correction_of
from fpg_gym.reconstruct.problem import SearchProblem
from fpg_gym.reconstruct.records import FrameOutput, FrameRecord, ReconstructionResult
from fpg_gym.reconstruct.search import (
    OptimizerSpec,
    budgeted_run,
    make_generators,
    make_optimizers,
    search_together,
)
from optimizers import Optimizer

if TYPE_CHECKING:
    from fpg_gym.reconstruct.reconstructor import Reconstructor

__all__ = [
    "Choice",
    "Chooser",
    "Stream",
    "reconstruct_stream",
    "reconstruct_streams",
    "run_streams",
    "search_streams",
    "step_streams",
]


def _stream_arrays(recording: Any, index: int, frame_dt: float) -> tuple[np.ndarray, ...]:
    """``positions`` (T,20,3), ``states`` (T,20), ``timestamps`` (T,) of one recording."""
    name = f"recordings[{index}]"
    positions = pose_utils.as_poses(recording.positions, f"{name}.positions", ndim=3)
    states = np.asarray(recording.states)
    if states.shape != positions.shape[:2]:
        raise ValueError(f"{name}.states: expected shape {positions.shape[:2]}, got {states.shape}")
    stamps = getattr(recording, "timestamps", None)
    timestamps = (
        np.arange(len(positions)) * frame_dt
        if stamps is None
        else np.asarray(stamps, dtype=np.float64).reshape(-1)
    )
    if timestamps.shape != (len(positions),):
        raise ValueError(
            f"{name}.timestamps: expected shape ({len(positions)},), got {timestamps.shape}"
        )
    return positions, states, timestamps


def _own_search_time(record: FrameRecord, search_ms: float) -> FrameRecord:
    """The record with the stream's own search time (not the batch's): its ``ms``, a dict new
    with the frame (``Reconstructor.finish``), set in place."""
    ms = record.ms
    ms["total"] += search_ms - ms["search"]
    ms["search"] = search_ms
    return record


@dataclass(frozen=True)
class Choice:
    """The latent point a stream's frame is finished with (what a :data:`Chooser` gives).

    Attributes
    ----------
    z : ndarray, shape (d,)
    correction : OutputCorrection, optional
        The output correction to apply (the optimiser's, :func:`output_correction_of`).
    search_s : float, optional
        Seconds the stream's own search took (its record's ``search`` time); None: the time
        between ``prepare`` and ``finish``.
    """

    z: np.ndarray
    correction: OutputCorrection | None = None
    search_s: float | None = None


class Stream:
    """One reconstructor's stream of frames: where they come from, the optimiser and generator
    that search them, and what the stream output.

    Parameters
    ----------
    reconstructor : Reconstructor
    recording : Recording-like, optional
        ``positions`` (T,20,3), ``states`` (T,20), optional ``timestamps`` (T,): the frames, in
        order (:meth:`prepare` takes the next one); None: each frame is given to
        :meth:`prepare` (a live stream; no output is kept).
    optimizer : Optimizer, optional
        The stream's optimiser (:func:`search_streams`), used as is.
    rng : numpy.random.Generator, optional
        The optimiser's generator; None: unseeded.
    frames : int, optional
        At most this many frames of ``recording``.
    index : int
        The stream's number among many (in error messages).

    Attributes
    ----------
    no_body : list of bool
        Per frame of ``recording``, whether no joint is tracked or inferred (empty for a live
        stream).
    """

    def __init__(
        self,
        reconstructor: Reconstructor,
        recording: Any = None,
        optimizer: Optimizer | None = None,
        rng: np.random.Generator | None = None,
        *,
        frames: int | None = None,
        index: int = 0,
    ) -> None:
        self.reconstructor = reconstructor
        self.optimizer = optimizer
        self.rng = rng
        self.index = index
        self.next = 0
        self.records: list[FrameRecord] = []
        self._frames: tuple[np.ndarray, ...] | None = None
        # Per frame, found once for the recording: its positions in float64, its timestamp (a
        # float) and whether no joint is tracked or inferred (what prepare would find frame by
        # frame).
        self._positions64: np.ndarray | None = None
        self._stamps: list[float] = []
        self.no_body: list[bool] = []
        length = 0
        if recording is not None:
            self._frames = _stream_arrays(recording, index, reconstructor.config.frame_dt)
            self._positions64 = self._frames[0].astype(np.float64)
            self._stamps = self._frames[2].tolist()
            self.no_body = np.logical_not(skeleton.body_present(self._frames[1])).tolist()
            length = len(self._frames[0]) if frames is None else min(frames, len(self._frames[0]))
        self.length = length
        self.poses = np.zeros((length, skeleton.NUM_JOINTS, 3), dtype=np.float32)

    @property
    def done(self) -> bool:
        """Whether the recording's frames are all finished (never for a live stream)."""
        return self._frames is not None and self.next >= self.length

    def prepare(
        self,
        positions: np.ndarray | None = None,
        states: np.ndarray | None = None,
        timestamp: float | None = None,
    ) -> SearchProblem:
        """Prepare the recording's next frame, or the frame given (a live stream); its
        problem (:meth:`Reconstructor.prepare`)."""
        if positions is None:
            if self._frames is None or self.done:
                raise RuntimeError(f"stream {self.index}: no frame left to prepare")
            t = self.next
            positions, states, _ = self._frames
            assert self._positions64 is not None
            # checked with the recording (_stream_arrays)
            return self.reconstructor._prepare_checked(
                positions[t],
                states[t],
                self._stamps[t],
                no_body=self.no_body[t],
                positions64=self._positions64[t],
            )
        assert states is not None
        return self.reconstructor.prepare(positions, states, timestamp)

    def finish(
        self,
        z: np.ndarray,
        *,
        correction: OutputCorrection | None = None,
        search_s: float | None = None,
    ) -> FrameOutput:
        """Finish the prepared frame from ``z`` (:meth:`Reconstructor.finish`), keep its output
        (a recording's stream) and move to the next frame."""
        pose, record = self.reconstructor.finish(z, correction=correction)
        if search_s is not None:
            _own_search_time(record, 1e3 * search_s)
        if self._frames is not None:
            self.poses[self.next] = pose
            self.records.append(record)
        self.next += 1
        return FrameOutput(pose, record)

    def drop(self) -> None:
        """Forget the prepared frame, if any (the reconstructor stays usable)."""
        self.reconstructor.drop_frame()

    def result(self, interrupted: bool = False, *, copy: bool = False) -> ReconstructionResult:
        """The frames finished so far (copies with ``copy``, e.g. for a checkpoint)."""
        done = len(self.records)
        poses = self.poses[:done]
        return ReconstructionResult(
            poses.copy() if copy else poses,
            list(self.records) if copy else self.records,
            interrupted,
            bones=self.reconstructor.bones.report(),
        )


#: ``chooser(problems, streams) -> choices``: one :class:`Choice` per prepared problem.
Chooser = Callable[[Sequence[SearchProblem], Sequence[Stream]], Sequence[Choice]]


def search_streams(problems: Sequence[SearchProblem], streams: Sequence[Stream]) -> list[Choice]:
    """The default :data:`Chooser`: each stream's optimiser and generator on its problem within
    its reconstructor's budget (``max_evaluations``, ``time_budget_s``), the searches side by
    side (:func:`~fpg_gym.reconstruct.search.search_together`); each its best point, the
    optimiser's output correction and the search's own time."""
    runs = []
    for problem, stream in zip(problems, streams, strict=True):
        if stream.optimizer is None:
            raise ValueError(f"stream {stream.index}: no optimiser to search with")
        runs.append(
            budgeted_run(problem, stream.optimizer, stream.rng, stream.reconstructor.config)
        )
    seconds = search_together(problems, runs)
    return [
        Choice(run.result().x, output_correction_of(stream.optimizer), float(own))
        for run, stream, own in zip(runs, streams, seconds, strict=True)
    ]


def step_streams(
    streams: Sequence[Stream],
    choose: Chooser = search_streams,
    frames: Sequence[tuple[np.ndarray, np.ndarray, float | None]] | None = None,
) -> list[FrameOutput]:
    """One frame of every stream not done, in lockstep: prepare, choose, finish.

    Parameters
    ----------
    streams : sequence of Stream
    choose : callable
        ``choose(problems, streams)`` -> one :class:`Choice` per stream not done (default
        :func:`search_streams`).
    frames : sequence of (positions, states, timestamp), optional
        The frame of each stream, for streams without a recording (live).

    Returns
    -------
    list of FrameOutput
        One per stream not done, in order (empty when all are done).

    Raises
    ------
    Exception
        What ``prepare``, the chooser or ``finish`` raised; the streams' prepared frames are
        dropped first (each reconstructor stays usable, at the frame before). An interrupt
        that a compiled call turned into a ``SystemError`` is raised as the
        ``KeyboardInterrupt`` it was (:func:`fpg_gym.core.errors.interrupt_in`).
    """
    active = [s for s in streams if not s.done]
    if frames is not None and len(frames) != len(active):
        raise ValueError(f"frames: expected {len(active)} (one per stream), got {len(frames)}")
    try:
        problems = [
            stream.prepare() if frames is None else stream.prepare(*frames[k])
            for k, stream in enumerate(active)
        ]
        chosen = choose(problems, active) if active else []
        if len(chosen) != len(active):
            raise ValueError(f"choose: expected {len(active)} choices, got {len(chosen)}")
        return [
            stream.finish(c.z, correction=c.correction, search_s=c.search_s)
            for stream, c in zip(active, chosen, strict=True)
        ]
    except BaseException as error:
        for stream in active:
            stream.drop()
        interrupt = interrupt_in(error)
        if interrupt is not None and interrupt is not error:  # swallowed by a compiled call
            raise interrupt from None
        raise


def reconstruct_streams(
    streams: Sequence[Stream],
    choose: Chooser = search_streams,
    *,
    progress: bool = False,
    on_step: Callable[[int], object] | None = None,
    stop_on_interrupt: bool = False,
    checkpoint: Callable[[list[ReconstructionResult]], None] | None = None,
    checkpoint_s: float = 30.0,
) -> list[ReconstructionResult]:
    """Reset the streams' reconstructors and run their recordings to the end in lockstep
    (:func:`step_streams`; a finished stream leaves the batch).

    Parameters
    ----------
    streams : sequence of Stream
        Streams of recordings, with distinct reconstructors.
    choose : callable
        The :data:`Chooser` (default :func:`search_streams`).
    progress : bool
        A tqdm bar over all frames, on stderr.
    on_step : callable, optional
        Called with the frames each step finished (e.g. a shared bar's ``update``).
    stop_on_interrupt : bool
        On Ctrl-C return the frames done (``interrupted=True``) instead of raising.
    checkpoint : callable, optional
        Called every ``checkpoint_s`` seconds (0: never) with the frames done so far (copies,
        ``interrupted=True``), e.g. to write them so that a killed run keeps them.
    checkpoint_s : float
        Seconds between checkpoints (30).

    Returns
    -------
    list of ReconstructionResult
        In the order of ``streams``.
    """
    if len({id(s.reconstructor) for s in streams}) != len(streams):
        raise ValueError("reconstructors: expected distinct objects (one per stream)")
    for stream in streams:
        stream.reconstructor.reset()
    total = sum(s.length - s.next for s in streams)
    # no bar at all without progress (making a disabled one costs more than a short stream)
    bar = tqdm(total=total, unit="frame", desc="reconstruct", leave=False) if progress else None
    checkpoints = checkpoint is not None and checkpoint_s > 0
    last_checkpoint = time.monotonic()
    interrupted = False
    try:
        while outputs := step_streams(streams, choose):
            if bar is not None:
                bar.update(len(outputs))
            if on_step is not None:
                on_step(len(outputs))
            if checkpoints and checkpoint_s <= time.monotonic() - last_checkpoint:
                assert checkpoint is not None
                checkpoint([s.result(True, copy=True) for s in streams])
                last_checkpoint = time.monotonic()
    except KeyboardInterrupt:
        if not stop_on_interrupt:
            for stream in streams:
                stream.reconstructor.reset()
            raise
        interrupted = True
    except BaseException:
        for stream in streams:  # drop the half-done stream: the objects stay usable
            stream.reconstructor.reset()
        raise
    finally:
        if bar is not None:
            bar.close()
    return [s.result(interrupted) for s in streams]


def reconstruct_stream(
    stream: Stream,
    choose: Chooser = search_streams,
    *,
    progress: bool = False,
    stop_on_interrupt: bool = False,
    checkpoint: Callable[[ReconstructionResult], None] | None = None,
    checkpoint_s: float = 30.0,
) -> ReconstructionResult:
    """:func:`reconstruct_streams` of one stream (``checkpoint`` gets its one result)."""
    (result,) = reconstruct_streams(
        [stream],
        choose,
        progress=progress,
        stop_on_interrupt=stop_on_interrupt,
        checkpoint=None if checkpoint is None else lambda results: checkpoint(results[0]),
        checkpoint_s=checkpoint_s,
    )
    return result


def run_streams(
    reconstructors: Sequence[Reconstructor],
    recordings: Sequence[Any],
    optimizer: OptimizerSpec = "local-search",
    rngs: Sequence[np.random.Generator | int] | None = None,
    *,
    progress: bool = False,
) -> list[ReconstructionResult]:
    """Reconstruct ``recordings[i]`` with ``reconstructors[i]``, all streams in lockstep.

    Parameters
    ----------
    reconstructors : sequence of Reconstructor
        One per recording, distinct objects (each keeps its stream's state; each is reset).
    recordings : sequence of Recording-like
        ``positions`` (T,20,3), ``states`` (T,20), optional ``timestamps`` (T,); lengths may
        differ (a finished stream leaves the batch).
    optimizer : str, Optimizer or callable
        A registered name (made once per stream), an optimiser object (copied per stream) or a
        factory called once per stream.
    rngs : sequence of numpy.random.Generator or int, optional
        One seed or generator per stream; None: unseeded.
    progress : bool
        A tqdm bar over all frames, on stderr.

    Returns
    -------
    list of ReconstructionResult
        In the order of ``recordings``; stream i equals
        ``reconstructors[i].reconstruct(recordings[i], optimizer, rngs[i])``.
    """
    count = len(recordings)
    if len(reconstructors) != count:
        raise ValueError(
            f"reconstructors: expected {count} (one per recording), got {len(reconstructors)}"
        )
    if len({id(r) for r in reconstructors}) != count:
        raise ValueError("reconstructors: expected distinct objects (one per stream)")
    streams = [
        Stream(reconstructor, recording, index=i)
        for i, (reconstructor, recording) in enumerate(zip(reconstructors, recordings, strict=True))
    ]
    optimizers = make_optimizers(optimizer, count)
    for stream, opt, rng in zip(streams, optimizers, make_generators(rngs, count), strict=True):
        stream.optimizer, stream.rng = opt, rng
    return reconstruct_streams(streams, progress=progress)
