"""Live reconstruction: frames in as JSON lines, each reconstructed frame out at once.

The wire format (one JSON object per line, UTF-8; over UDP one or more lines per datagram):

``{"timestamp": 12.033, "joints": [[x, y, z], ... 20 ...], "states": [2, 2, 1, ...]}``

- ``timestamp``: seconds (any origin, non-decreasing; jumps are survived, below); optional, 30 Hz
  after the previous frame.
- ``joints``: the 20 Kinect-20 joints in :data:`fpg_gym.core.skeleton.JOINT_NAMES` order, metres in
  camera space (Y up, Z away from the sensor); or an object ``{"HipCenter": [x, y, z], ...}``
  naming all 20.
- ``states``: 2 tracked, 1 inferred, 0 not tracked, as a list of 20 or an object by joint name;
  optional (every joint tracked).
- ``{"end": true}`` ends the stream (a sender's last line; stdin ends at end of file too).

Each emitted frame is one JSON line: ``frame`` (the input's sequence number, counting from 0
over well-formed frames), ``timestamp``, ``joints`` (20 × [x, y, z]), ``latency_ms`` (receipt of
the line to emission: queueing plus reconstruction), ``ms`` (reconstruction only) and the
running counts ``dropped`` and ``malformed``.

Start-up: lines are read from the moment :class:`LiveReader` is made, before the pipeline is
ready (graph loaded, compiled kernels warm). Every frame that arrives before it is ready, and
every frame arriving while those are worked through, is reconstructed: nothing is dropped until
the output has caught up with the input (the queue empties once), unless the waiting frames grow
to twice the start-up backlog (a pipeline slower than the stream).

Falling behind, after that: received frames wait in a bounded queue; when it is full the oldest
frame is dropped, and a frame older than ``max_age_s`` is skipped when a newer one waits — the
output stays current instead of lagging (both counted in ``dropped``). A malformed line (bad
JSON, a missing or wrong-shaped field, a non-finite or implausible value, a state outside
0/1/2) is counted by reason in ``malformed`` and skipped; it never stops the stream.

Timestamps (:class:`StreamClock`): a frame up to :data:`LATE_S` older than the last one
reconstructed arrived out of order and is skipped (``malformed``: "timestamp goes back"); one
further back means the sender's clock jumped or restarted: the frame is reconstructed 1/30 s
after the last one and the stream goes on from there (``clock_jumps``, and a notice). A jump
forward is a gap: longer than the reconstructor's ``max_gap_s`` (0.5 s), the stream restarts.

Every frame goes through the one run path (:func:`fpg_gym.reconstruct.streams.step_streams` on
a :class:`~fpg_gym.reconstruct.streams.Stream`), the same one
:meth:`~fpg_gym.reconstruct.Reconstructor.reconstruct` runs offline: with no frame dropped and
the same seed, the live output equals the offline one.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fpg_gym.core.errors import FpgGymError
from fpg_gym.core.validation import check_integer, check_number
from fpg_gym.definitions import sensor_to_output_map
from fpg_gym.filters import make_filter
from fpg_gym.io.live_frames import FrameError, LiveFrame, is_end, parse_frame
from fpg_gym.methods.names import Method
from fpg_gym.reconstruct import Reconstructor
from fpg_gym.reconstruct.streams import Stream, step_streams
from optimizers import make

__all__ = [
    "MAX_JUMP_NOTICES",
    "FrameQueue",
    "LiveReader",
    "LiveStats",
    "ReconstructorStep",
    "StreamClock",
    "emit_frame",
    "run_live",
]

#: Frame step assumed when a frame carries no timestamp (seconds).
DEFAULT_DT = 1.0 / 30.0
#: A frame at most this much older than the last one (seconds) arrived out of order: skipped.
#: Further back, the sender's clock jumped or restarted (:class:`StreamClock`).
LATE_S = 0.1
#: Frames held at most while the pipeline starts (before it first asks for a frame).
MAX_STARTUP_FRAMES = 10_000


# --------------------------------------------------------------------------- queue and counts


@dataclass
class LiveStats:
    """Counts and latencies of a live run (the summary printed at the end)."""

    received: int = 0
    emitted: int = 0
    dropped: int = 0
    malformed: Counter[str] = field(default_factory=Counter)
    latency_ms: list[float] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)
    interrupted: bool = False
    clock_jumps: int = 0
    backlog: int = 0

    def summary(self) -> dict[str, Any]:
        """JSON-ready counts and latency percentiles."""

        def pct(values: list[float], q: float) -> float | None:
            return float(np.percentile(values, q)) if values else None

        return {
            "received": self.received,
            "emitted": self.emitted,
            "dropped": self.dropped,
            "malformed": sum(self.malformed.values()),
            "malformed_by_reason": dict(self.malformed),
            "clock_jumps": self.clock_jumps,
            "waiting_at_start": self.backlog,
            "latency_ms_median": pct(self.latency_ms, 50),
            "latency_ms_p95": pct(self.latency_ms, 95),
            "latency_ms_max": max(self.latency_ms) if self.latency_ms else None,
            "reconstruct_ms_median": pct(self.ms, 50),
            "interrupted": self.interrupted,
        }


class FrameQueue:
    """A bounded, thread-safe queue that drops its oldest frame when full, after start-up.

    Start-up: until the consumer first finds the queue empty (it has caught up), no frame is
    dropped, for size or age; the queue then holds at most twice the frames that waited at the
    consumer's first :meth:`get` (the start-up backlog; before it, :data:`MAX_STARTUP_FRAMES`).
    Past that bound the pipeline is slower than the stream: the start-up ends there.

    Parameters
    ----------
    size : int
        Frames held at most once started (>= 1).
    startup : bool
        Keep every frame until the consumer has caught up (True); False: the bounded queue
        from the first frame.
    """

    def __init__(self, size: int, startup: bool = True) -> None:
        self._frames: deque[LiveFrame] = deque()
        self._size = check_integer(size, "size", low=1)
        self._ready = threading.Condition()
        self._closed = False
        self._starting = bool(startup)
        self._startup_limit = MAX_STARTUP_FRAMES
        self.dropped = 0
        self.backlog: int | None = None  # frames waiting at the first get (None: not yet)

    def _limit(self) -> int:
        return self._startup_limit if self._starting else self._size

    def _trim(self) -> None:
        while len(self._frames) > self._limit():
            self._frames.popleft()
            self.dropped += 1

    def put(self, frame: LiveFrame) -> None:
        """Add a frame; the oldest waiting one is dropped (and counted) when full."""
        with self._ready:
            self._frames.append(frame)
            if self._starting and len(self._frames) > self._startup_limit:
                self._starting = self.backlog is None  # behind the stream: start-up is over
            self._trim()
            self._ready.notify()

    def close(self) -> None:
        """No more frames: :meth:`get` returns None once the queue is empty."""
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def get(self, max_age_s: float | None = None) -> LiveFrame | None:
        """The next frame (blocking), skipping frames older than ``max_age_s`` while a newer
        one waits (after start-up); None when closed and empty."""
        with self._ready:
            if self.backlog is None:
                self.backlog = len(self._frames)
                self._startup_limit = max(2 * self.backlog, self._size)
                self._trim()
            if not self._frames:
                self._starting = False  # caught up with the stream
            while not self._frames and not self._closed:
                self._ready.wait(0.1)
            if not self._frames:
                return None
            if max_age_s is not None and not self._starting:
                now = time.perf_counter()
                while len(self._frames) > 1 and now - self._frames[0].received > max_age_s:
                    self._frames.popleft()
                    self.dropped += 1
            return self._frames.popleft()


class StreamClock:
    """The stream's time from the sender's timestamps, through jumps and restarts.

    While the sender's clock runs forward, a frame's time is its timestamp (so that the live
    output equals the offline one). A timestamp up to ``late_s`` before the last frame's is a
    frame that arrived out of order: :meth:`place` says to skip it. Further back, the sender's
    clock jumped or restarted: the frame is placed ``frame_dt`` after the last one, and the
    frames after it follow their timestamps from there (one frame stamped far ahead, then the
    stream again, is a gap and a jump). A frame without a timestamp is ``frame_dt`` after the
    last one. Times never go back.

    Parameters
    ----------
    late_s : float
        Largest step back taken for a frame out of order (:data:`LATE_S`).
    frame_dt : float
        Step given to a frame after a jump or without a timestamp (:data:`DEFAULT_DT`).
    """

    def __init__(self, late_s: float = LATE_S, frame_dt: float = DEFAULT_DT) -> None:
        self.late_s = check_number(late_s, "late_s", low=0.0)
        self.frame_dt = check_number(frame_dt, "frame_dt", low=0.0, low_open=True)
        self._last_stamp: float | None = None  # the last reconstructed frame's timestamp
        self._last_time: float | None = None  # the last reconstructed frame's time
        self._anchor: tuple[float, float] | None = None  # (stamp, time) since the last jump

    @property
    def last_stamp(self) -> float | None:
        """The last reconstructed frame's timestamp (None: none yet)."""
        return self._last_stamp

    def _mapped(self, stamp: float) -> float:
        if self._anchor is None:
            return stamp
        anchor_stamp, anchor_time = self._anchor
        return anchor_time + (stamp - anchor_stamp)

    def place(self, stamp: float | None) -> tuple[float, str]:
        """The stream time of a frame stamped ``stamp`` (None: not stamped) and what it is:
        ``"next"``, ``"late"`` (skip it; the time is then meaningless) or ``"jump"`` (the
        sender's clock went back further than ``late_s``). Nothing changes until
        :meth:`advance`."""
        last = self._last_time
        if last is None:
            return (0.0 if stamp is None else stamp), "next"
        if stamp is None:
            return last + self.frame_dt, "next"
        if self._last_stamp is not None and stamp < self._last_stamp:
            if self._last_stamp - stamp <= self.late_s:
                return last, "late"
            return last + self.frame_dt, "jump"
        mapped = self._mapped(stamp)
        return (mapped if mapped >= last else last + self.frame_dt), "next"

    def advance(self, stamp: float | None, time_s: float) -> None:
        """Record a frame as reconstructed at ``time_s`` (from :meth:`place`)."""
        if stamp is not None:
            if self._mapped(stamp) != time_s:
                self._anchor = (stamp, time_s)
            self._last_stamp = stamp
        self._last_time = time_s


def emit_frame(frame: LiveFrame, pose: np.ndarray, ms: float, stats: LiveStats) -> dict[str, Any]:
    """The output object of one reconstructed frame (module docstring)."""
    return {
        "frame": frame.index,
        "timestamp": frame.timestamp,
        "joints": np.asarray(pose, dtype=np.float64).tolist(),
        "latency_ms": round(1000.0 * (time.perf_counter() - frame.received), 3),
        "ms": round(ms, 3),
        "dropped": stats.dropped,
        "malformed": sum(stats.malformed.values()),
    }


# --------------------------------------------------------------------------- the loop


class ReconstructorStep:
    """The per-frame step of a live run: a :class:`~fpg_gym.reconstruct.streams.Stream` with
    one optimiser object and one generator, given each frame as it arrives, as
    :meth:`Reconstructor.reconstruct` runs a recording's.

    Parameters
    ----------
    reconstructor : Reconstructor
    optimizer : str or Optimizer
    seed : int
        Seed of the optimiser's generator (same seed as offline, same output).
    """

    def __init__(self, reconstructor: Reconstructor, optimizer: Any, seed: int) -> None:
        self.reconstructor = reconstructor
        self.optimizer = make(optimizer)
        self.rng = np.random.default_rng(seed)
        self.reconstructor.reset()
        # The compiled kernels load (numba: import and disk cache, about 1 s) now, before the
        # stream, not on its first frames, where they would stall it and drop frames.
        self.reconstructor.warm_up(self.optimizer)
        self.stream = Stream(reconstructor, optimizer=self.optimizer, rng=self.rng)

    def __call__(self, frame: LiveFrame) -> np.ndarray:
        (output,) = step_streams(
            [self.stream], frames=[(frame.positions, frame.states, frame.timestamp)]
        )
        return output.pose


class FilterStep:
    """The per-frame step of a reference filter (``raw``, ``holt``, ``kalman``, ``one-euro``,
    optionally ``+map``: the sensor through the map into the reconstruction's output
    definitions, :func:`fpg_gym.definitions.sensor_to_output_map` of ``options``).

    Raises
    ------
    ValueError
        For ``+ragdoll`` (the filters' ragdoll stage runs on whole streams) or ``+map`` without
        a map in ``options``.
    """

    def __init__(self, method: Method, options: dict[str, Any]) -> None:
        if method.ragdoll:
            raise ValueError(f"--method {method.name}: live runs the filters without the ragdoll")
        assert method.filter_name is not None
        self.filter = make_filter(method.filter_name)
        self.mapping = sensor_to_output_map(options) if method.mapped else None
        if method.mapped and self.mapping is None:
            raise ValueError(
                f"--method {method.name}: no definition map to apply; give --sensor kinect-v2 "
                "or a map (--sensor-map, --calibration-map)"
            )

    def __call__(self, frame: LiveFrame) -> np.ndarray:
        positions = np.asarray(frame.positions, dtype=np.float64)
        if self.mapping is not None:
            positions = self.mapping.apply(positions)
        return np.asarray(self.filter.update(positions, frame.states, frame.timestamp))


def _read_into(
    lines: Iterable[bytes | str],
    queue: FrameQueue,
    stats: LiveStats,
    lock: threading.Lock,
) -> None:
    """Reader thread: parse each line, count malformed ones, queue the others."""
    index = 0
    try:
        for line in lines:
            received = time.perf_counter()
            if not line.strip():
                continue
            if is_end(line):
                break
            try:
                frame = parse_frame(line, index, received)
            except FrameError as error:
                with lock:
                    stats.malformed[error.reason] += 1
                continue
            except Exception as error:  # a line no rule foresaw: counted, never fatal
                with lock:
                    stats.malformed[f"unreadable ({type(error).__name__})"] += 1
                continue
            index += 1
            with lock:
                stats.received += 1
            queue.put(frame)
    finally:
        queue.close()


class LiveReader:
    """Reads, parses and queues ``lines`` in a background thread from the moment it is made.

    Make it before the pipeline starts (loading the graph, warming the compiled kernels): the
    frames that arrive meanwhile wait in its queue and are all reconstructed (:class:`FrameQueue`).

    Parameters
    ----------
    lines : iterable of bytes or str
        JSON lines as they arrive.
    queue_size : int
        Frames waiting at most once the stream has caught up (the oldest is dropped when full).
    """

    def __init__(self, lines: Iterable[bytes | str], queue_size: int = 2) -> None:
        self.stats = LiveStats()
        self.lock = threading.Lock()
        self.queue = FrameQueue(check_integer(queue_size, "queue_size", low=1))
        self.thread = threading.Thread(
            target=_read_into,
            args=(lines, self.queue, self.stats, self.lock),
            name="fpg-gym-live-reader",
            daemon=True,
        )
        self.thread.start()


#: Clock jumps reported one by one through ``notify``; later ones are only counted.
MAX_JUMP_NOTICES = 5


def _jump_notice(index: int, stamp: float, previous: float, count: int) -> str:
    """The one-line notice of a frame whose timestamp jumped back (the ``count``-th)."""
    later = " (later jumps are only counted)" if count == MAX_JUMP_NOTICES else ""
    return (
        f"frame {index}: timestamp {stamp:.3f} s is {previous - stamp:.3f} s before the "
        f"previous frame's ({previous:.3f} s): the sender's clock jumped or restarted; the "
        f"stream goes on from this frame{later}"
    )


def run_live(
    lines: Iterable[bytes | str] | LiveReader,
    step: Callable[[LiveFrame], np.ndarray],
    emit: Callable[[dict[str, Any]], None],
    *,
    queue_size: int = 2,
    max_age_s: float | None = 0.1,
    max_frames: int | None = None,
    notify: Callable[[str], None] | None = None,
) -> LiveStats:
    """Reconstruct frames as they arrive and emit each at once.

    Parameters
    ----------
    lines : iterable of bytes or str, or LiveReader
        JSON lines as they arrive (read in a background thread), or a :class:`LiveReader`
        already reading them (made before the pipeline started).
    step : callable
        ``frame -> pose (20, 3)``, e.g. a :class:`ReconstructorStep`; the frame it gets carries
        the stream's time (:class:`StreamClock`) as its ``timestamp``.
    emit : callable
        Called with each output object (:func:`emit_frame`; its ``timestamp`` as received).
    queue_size : int
        Frames waiting at most (for ``lines``; a :class:`LiveReader` has its own queue).
    max_age_s : float or None
        A waiting frame older than this is skipped when a newer one waits (None: never); not
        while the stream starts (:class:`FrameQueue`).
    max_frames : int, optional
        Stop after emitting this many frames.
    notify : callable, optional
        Called with a one-line notice when the sender's clock jumps back (the first
        :data:`MAX_JUMP_NOTICES`; all are counted in ``clock_jumps``).

    Returns
    -------
    LiveStats
        The counts; ``interrupted`` when Ctrl-C (or SIGTERM through the command line) ended the
        stream.
    """
    if max_age_s is not None:
        max_age_s = check_number(max_age_s, "max_age_s", low=0.0)
    if max_frames is not None:
        max_frames = check_integer(max_frames, "max_frames", low=1)
    reader = lines if isinstance(lines, LiveReader) else LiveReader(lines, queue_size)
    stats, lock, queue = reader.stats, reader.lock, reader.queue
    clock = StreamClock()
    try:
        while max_frames is None or stats.emitted < max_frames:
            frame = queue.get(max_age_s)
            with lock:
                stats.dropped = queue.dropped
                stats.backlog = queue.backlog or 0
            if frame is None:
                break
            stamp = frame.timestamp
            previous = clock.last_stamp
            time_s, kind = clock.place(stamp)
            if kind == "late":
                with lock:
                    stats.malformed["timestamp goes back"] += 1
                continue
            start = time.perf_counter()
            try:
                pose = step(replace(frame, timestamp=time_s))
            except (FpgGymError, ValueError, ArithmeticError) as error:  # refused: skip it
                with lock:
                    stats.malformed[f"refused ({type(error).__name__})"] += 1
                continue
            ms = 1000.0 * (time.perf_counter() - start)
            clock.advance(stamp, time_s)
            with lock:
                if kind == "jump":
                    stats.clock_jumps += 1
                output = emit_frame(frame, pose, ms, stats)
                stats.emitted += 1
                stats.latency_ms.append(output["latency_ms"])
                stats.ms.append(ms)
            if kind == "jump" and notify is not None and stats.clock_jumps <= MAX_JUMP_NOTICES:
                assert stamp is not None and previous is not None
                notify(_jump_notice(frame.index, stamp, previous, stats.clock_jumps))
            emit(output)
    except KeyboardInterrupt:
        stats.interrupted = True
    with lock:
        stats.dropped = queue.dropped
        stats.backlog = queue.backlog or 0
    return stats
