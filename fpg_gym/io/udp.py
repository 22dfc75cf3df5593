"""Where live lines come from and go to: standard input, UDP datagrams (``udp://HOST:PORT``)
in and out, with errors that name the argument and the address.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, BinaryIO

from fpg_gym.core.errors import FpgGymError

__all__ = [
    "MAX_DATAGRAM",
    "LiveAddressError",
    "open_udp_input",
    "parse_address",
    "stdin_lines",
    "udp_lines",
    "udp_sender",
]

#: Largest UDP datagram read.
MAX_DATAGRAM = 65507


class LiveAddressError(FpgGymError, ValueError):
    """A ``udp://HOST:PORT`` that cannot be listened on or sent to (names the argument)."""


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


def _resolve(text: str, argument: str, passive: bool) -> tuple[Any, ...]:
    """``(family, address)`` of a ``udp://HOST:PORT`` (the first of ``getaddrinfo``)."""
    host, port = parse_address(text, argument)
    try:
        found = socket.getaddrinfo(
            host, port, type=socket.SOCK_DGRAM, flags=socket.AI_PASSIVE if passive else 0
        )
    except (OSError, UnicodeError) as error:
        reason = getattr(error, "strerror", None) or str(error)
        raise LiveAddressError(
            f"{argument} {text}: host {host!r} not found ({reason}); expected an IP address "
            "or a host name this machine resolves"
        ) from None
    family, _, _, _, address = found[0]
    return family, address


def open_udp_input(text: str, argument: str = "--input") -> socket.socket:
    """A UDP socket bound to ``udp://HOST:PORT`` (port 0: any free port).

    Raises
    ------
    LiveAddressError
        Naming ``argument`` and the address when it cannot be resolved or bound (in use, not an
        address of this machine, a privileged port).
    """
    family, address = _resolve(text, argument, passive=True)
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind(address)
    except OSError as error:
        sock.close()
        raise LiveAddressError(
            f"{argument} {text}: cannot listen there ({error.strerror or error}); expected an "
            "address of this machine (e.g. 0.0.0.0 or 127.0.0.1) and a free port (1024-65535, "
            "or 0 for any)"
        ) from None
    return sock


def stdin_lines(stream: BinaryIO | None = None) -> Iterator[bytes]:
    """Lines of standard input (or ``stream``) as they arrive."""
    source = sys.stdin.buffer if stream is None else stream
    yield from iter(source.readline, b"")


def udp_lines(
    sock: socket.socket, stop: threading.Event, idle_timeout_s: float | None = None
) -> Iterator[bytes]:
    """Lines of the datagrams arriving on a bound UDP socket, until ``stop`` is set or, after
    the first datagram, none came for ``idle_timeout_s`` seconds (None: wait for ever)."""
    sock.settimeout(0.1)
    last: float | None = None  # the idle time counts from the first datagram
    while not stop.is_set():
        try:
            data = sock.recv(MAX_DATAGRAM)
        except TimeoutError:
            if (
                idle_timeout_s is not None
                and last is not None
                and time.monotonic() - last > idle_timeout_s
            ):
                return
            continue
        except OSError:  # e.g. an ICMP error reported on the socket: not a frame, go on
            continue
        last = time.monotonic()
        yield from (line for line in data.splitlines() if line.strip())


def udp_sender(text: str, argument: str = "--output") -> Callable[[str], None]:
    """A function sending one line as one UDP datagram to ``udp://HOST:PORT`` (resolved once).

    Raises
    ------
    LiveAddressError
        Naming ``argument`` and the address: now when it cannot be resolved or its port is 0,
        and from the function when a datagram cannot be sent.
    """
    family, address = _resolve(text, argument, passive=False)
    if address[1] == 0:
        raise LiveAddressError(f"{argument} {text}: expected a port from 1 to 65535, got 0")
    sock = socket.socket(family, socket.SOCK_DGRAM)

    def send(line: str) -> None:
        try:
            sock.sendto(line.encode("utf-8"), address)
        except OSError as error:
            raise LiveAddressError(
                f"{argument} {text}: cannot send ({error.strerror or error}); expected a "
                "reachable address"
            ) from None

    return send
