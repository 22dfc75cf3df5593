"""Live reconstruction: frames in as JSON lines, each reconstructed frame out at once.

The wire format (one JSON object per line, UTF-8; over UDP one or more lines per datagram):

``{"timestamp": 12.033, "joints": [[x, y, z], ... 20 ...], "states": [2, 2, 1, ...]}``

- ``timestamp``: seconds (any origin, non-decreasing); optional, 30 Hz after the previous frame.
- ``joints``: the 20 Kinect-20 joints in :data:`fpg_gym.skeleton.JOINT_NAMES` order, metres in
  camera space (Y up, Z away from the sensor); or an object ``{"HipCenter": [x, y, z], ...}``
  naming all 20.
- ``states``: 2 tracked, 1 inferred, 0 not tracked, as a list of 20 or an object by joint name;
  optional (every joint tracked).
- ``{"end": true}`` ends the stream (a sender's last line; stdin ends at end of file too).

Each emitted frame is one JSON line: ``frame`` (the input's sequence number, counting from 0
over well-formed frames), ``timestamp``, ``joints`` (20 × [x, y, z]), ``latency_ms`` (receipt of
the line to emission: queueing plus reconstruction), ``ms`` (reconstruction only) and the
running counts ``dropped`` and ``malformed``.

Falling behind: received frames wait in a bounded queue; when it is full the oldest frame is
dropped, and a frame older than ``max_age_s`` is skipped when a newer one waits — the output
stays current instead of lagging (both counted in ``dropped``). A malformed line (bad JSON, a
missing or wrong-shaped field, a non-finite or implausible value, a state outside 0/1/2, a
timestamp going back) is counted by reason in ``malformed`` and skipped; it never stops the
stream.

Every frame goes through one per-frame call, :meth:`fpg_gym.reconstruct.Reconstructor.\
reconstruct_frame`, the same one :meth:`~fpg_gym.reconstruct.Reconstructor.reconstruct` makes
offline: with no frame dropped and the same seed, the live output equals the offline one.
"""

from __future__ import annotations

import json
import math
import socket
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any, BinaryIO

import numpy as np

from fpg_gym import skeleton
from fpg_gym.errors import FpgGymError
from fpg_gym.reconstruct import Reconstructor
from fpg_gym.validation import check_integer, check_number
from optimizers import make

__all__ = [
    "FrameError",
    "FrameQueue",
    "LiveFrame",
    "LiveStats",
    "ReconstructorStep",
    "emit_frame",
    "frame_line",
    "is_end",
    "parse_address",
    "parse_frame",
    "run_live",
    "stdin_lines",
    "udp_lines",
    "udp_sender",
]

#: Largest plausible coordinate (metres); a larger one is a corrupt frame.
MAX_COORDINATE_M = 1000.0
#: Frame step assumed when a frame carries no timestamp (seconds).
DEFAULT_DT = 1.0 / 30.0
#: Largest UDP datagram read.
MAX_DATAGRAM = 65507


class FrameError(FpgGymError, ValueError):
    """A malformed live frame; ``reason`` is a short category for the counts."""

    def __init__(self, reason: str, detail: str = "") -> None:
        self.reason = reason
        super().__init__(f"{reason}: {detail}" if detail else reason)


@dataclass(frozen=True)
class LiveFrame:
    """One received frame.

    Attributes
    ----------
    index : int
        Sequence number among well-formed frames (0, 1, ...).
    timestamp : float or None
        Seconds, as sent (None: not sent).
    positions : ndarray, shape (20, 3), float32
    states : ndarray, shape (20,), int8
    received : float
        ``time.perf_counter()`` when the line arrived.
    """

    index: int
    timestamp: float | None
    positions: np.ndarray
    states: np.ndarray
    received: float


def _joint_values(value: Any, name: str, width: int) -> np.ndarray:
    """A list of 20 (or an object naming all 20 joints) as an array ``(20, width)``."""
    if isinstance(value, dict):
        missing = [j for j in skeleton.JOINT_NAMES if j not in value]
        if missing:
            raise FrameError(f"{name} lacks joints", f"e.g. {missing[:3]}")
        value = [value[j] for j in skeleton.JOINT_NAMES]
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise FrameError(f"{name} not numbers") from None
    shape = (skeleton.NUM_JOINTS, width) if width > 1 else (skeleton.NUM_JOINTS,)
    if array.shape != shape:
        raise FrameError(f"{name} wrong shape", f"expected {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise FrameError(f"{name} not finite")
    return array


def parse_frame(line: str | bytes, index: int = 0, received: float | None = None) -> LiveFrame:
    """Parse one JSON line of the wire format (module docstring).

    Raises
    ------
    FrameError
        On anything that does not fit the format (``reason`` names the category).
    """
    try:
        data = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        raise FrameError("not JSON") from None
    if not isinstance(data, dict):
        raise FrameError("not a JSON object")
    if "joints" not in data:
        raise FrameError("no joints")
    positions = _joint_values(data["joints"], "joints", 3)
    if np.abs(positions).max() > MAX_COORDINATE_M:
        raise FrameError("joints implausible", f"a coordinate beyond ±{MAX_COORDINATE_M:g} m")
    states: np.ndarray
    if data.get("states") is None:
        states = np.full(skeleton.NUM_JOINTS, skeleton.TRACKED, dtype=np.int8)
    else:
        values = _joint_values(data["states"], "states", 1)
        if not np.all(np.isin(values, skeleton.TRACKING_STATES)):
            raise FrameError("states not 0, 1 or 2")
        states = values.astype(np.int8)
    stamp = data.get("timestamp")
    if stamp is not None:
        if isinstance(stamp, bool) or not isinstance(stamp, int | float):
            raise FrameError("timestamp not a number")
        try:
            stamp = float(stamp)
        except OverflowError:
            raise FrameError("timestamp not finite") from None
        if not math.isfinite(stamp):
            raise FrameError("timestamp not finite")
    return LiveFrame(
        index=index,
        timestamp=stamp,
        positions=positions.astype(np.float32),
        states=states,
        received=time.perf_counter() if received is None else received,
    )


def frame_line(
    positions: np.ndarray, states: np.ndarray | None = None, timestamp: float | None = None
) -> str:
    """One frame in the wire format (what a sender writes; values kept exactly)."""
    data: dict[str, Any] = {}
    if timestamp is not None:
        data["timestamp"] = float(timestamp)
    data["joints"] = np.asarray(positions, dtype=np.float64).tolist()
    if states is not None:
        data["states"] = np.asarray(states, dtype=int).tolist()
    return json.dumps(data, separators=(",", ":"))


def is_end(line: str | bytes) -> bool:
    """Whether a line is the end-of-stream marker ``{"end": true}``."""
    text = line.decode("utf-8", errors="replace") if isinstance(line, bytes) else line
    text = text.strip()
    if not text.startswith("{") or "end" not in text:
        return False
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError):
        return False
    return isinstance(data, dict) and data.get("end") is True


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
            "latency_ms_median": pct(self.latency_ms, 50),
            "latency_ms_p95": pct(self.latency_ms, 95),
            "latency_ms_max": max(self.latency_ms) if self.latency_ms else None,
            "reconstruct_ms_median": pct(self.ms, 50),
            "interrupted": self.interrupted,
        }


class FrameQueue:
    """A bounded, thread-safe queue that drops its oldest frame when full.

    Parameters
    ----------
    size : int
        Frames held at most (>= 1).
    """

    def __init__(self, size: int) -> None:
        self._frames: deque[LiveFrame] = deque()
        self._size = check_integer(size, "size", low=1)
        self._ready = threading.Condition()
        self._closed = False
        self.dropped = 0

    def put(self, frame: LiveFrame) -> None:
        """Add a frame; the oldest waiting one is dropped (and counted) when full."""
        with self._ready:
            if len(self._frames) >= self._size:
                self._frames.popleft()
                self.dropped += 1
            self._frames.append(frame)
            self._ready.notify()

    def close(self) -> None:
        """No more frames: :meth:`get` returns None once the queue is empty."""
        with self._ready:
            self._closed = True
            self._ready.notify_all()

    def get(self, max_age_s: float | None = None) -> LiveFrame | None:
        """The next frame (blocking), skipping frames older than ``max_age_s`` while a newer
        one waits; None when closed and empty."""
        with self._ready:
            while not self._frames and not self._closed:
                self._ready.wait(0.1)
            if not self._frames:
                return None
            if max_age_s is not None:
                now = time.perf_counter()
                while len(self._frames) > 1 and now - self._frames[0].received > max_age_s:
                    self._frames.popleft()
                    self.dropped += 1
            return self._frames.popleft()


# --------------------------------------------------------------------------- sources and sinks


def parse_address(text: str, argument: str) -> tuple[str, int]:
    """``udp://HOST:PORT`` -> ``(host, port)``.

    Raises
    ------
    ValueError
        Naming ``argument`` when the text is not of that form.
    """
    prefix = "udp://"
    host, sep, port = (
        text[len(prefix) :].rpartition(":") if text.startswith(prefix) else ("", "", "")
    )
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"{argument}: expected '-' or udp://HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


def stdin_lines(stream: BinaryIO | None = None) -> Iterator[bytes]:
    """Lines of standard input (or ``stream``) as they arrive."""
    source = sys.stdin.buffer if stream is None else stream
    yield from iter(source.readline, b"")


def udp_lines(
    sock: socket.socket, stop: threading.Event, idle_timeout_s: float | None = None
) -> Iterator[bytes]:
    """Lines of the datagrams arriving on a bound UDP socket, until ``stop`` is set or no
    datagram came for ``idle_timeout_s`` seconds (None: wait for ever)."""
    sock.settimeout(0.1)
    last = time.monotonic()
    while not stop.is_set():
        try:
            data = sock.recv(MAX_DATAGRAM)
        except TimeoutError:
            if idle_timeout_s is not None and time.monotonic() - last > idle_timeout_s:
                return
            continue
        except OSError:  # e.g. an ICMP error reported on the socket: not a frame, go on
            continue
        last = time.monotonic()
        yield from (line for line in data.splitlines() if line.strip())


def udp_sender(host: str, port: int) -> Callable[[str], None]:
    """A function sending one line as one UDP datagram to ``host:port``."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
    address = (host, port)

    def send(line: str) -> None:
        sock.sendto(line.encode("utf-8"), address)

    return send


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
    """The per-frame step of a live run: :meth:`Reconstructor.reconstruct_frame` with one
    optimiser object and one generator, as :meth:`Reconstructor.iter_frames` uses them.

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

    def __call__(self, frame: LiveFrame) -> np.ndarray:
        pose, _ = self.reconstructor.reconstruct_frame(
            frame.positions, frame.states, frame.timestamp, self.optimizer, self.rng
        )
        return pose


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


def run_live(
    lines: Iterable[bytes | str],
    step: Callable[[LiveFrame], np.ndarray],
    emit: Callable[[dict[str, Any]], None],
    *,
    queue_size: int = 2,
    max_age_s: float | None = 0.1,
    max_frames: int | None = None,
) -> LiveStats:
    """Reconstruct frames as they arrive and emit each at once.

    Parameters
    ----------
    lines : iterable of bytes or str
        JSON lines as they arrive (read in a background thread).
    step : callable
        ``frame -> pose (20, 3)``, e.g. a :class:`ReconstructorStep`.
    emit : callable
        Called with each output object (:func:`emit_frame`).
    queue_size : int
        Frames waiting at most; the oldest is dropped when full.
    max_age_s : float or None
        A waiting frame older than this is skipped when a newer one waits (None: never).
    max_frames : int, optional
        Stop after emitting this many frames.

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
    stats = LiveStats()
    lock = threading.Lock()
    queue = FrameQueue(check_integer(queue_size, "queue_size", low=1))
    reader = threading.Thread(
        target=_read_into, args=(lines, queue, stats, lock), name="fpg-gym-live-reader", daemon=True
    )
    reader.start()
    last_stamp: float | None = None
    try:
        while max_frames is None or stats.emitted < max_frames:
            frame = queue.get(max_age_s)
            with lock:
                stats.dropped = queue.dropped
            if frame is None:
                break
            stamp = frame.timestamp
            if stamp is not None and last_stamp is not None and stamp < last_stamp:
                with lock:
                    stats.malformed["timestamp goes back"] += 1
                continue
            start = time.perf_counter()
            try:
                pose = step(frame)
            except (FpgGymError, ValueError, ArithmeticError) as error:  # refused: skip it
                with lock:
                    stats.malformed[f"refused ({type(error).__name__})"] += 1
                continue
            ms = 1000.0 * (time.perf_counter() - start)
            if stamp is not None:
                last_stamp = stamp
            with lock:
                output = emit_frame(frame, pose, ms, stats)
                stats.emitted += 1
                stats.latency_ms.append(output["latency_ms"])
                stats.ms.append(ms)
            emit(output)
    except KeyboardInterrupt:
        stats.interrupted = True
    with lock:
        stats.dropped = queue.dropped
    return stats
