"""Ray (``fpg-gym[distributed]``) for the commands that send work past one machine.

What ``compare --backend ray`` and the sampler's training-data collection share: the import with
an error naming the extra, and a session that connects to a cluster (``address``, else
``RAY_ADDRESS``) or starts a local instance, and leaves the process as it found it (an instance
it started is shut down, the signal handlers Ray's driver installs are put back). Ray schedules
the work; nothing here is a scheduler.
"""

from __future__ import annotations

import os
import signal
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from fpg_gym.core.errors import FpgGymError, import_optional

__all__ = [
    "RayUnavailable",
    "check_address",
    "ray_session",
    "require_ray",
    "restore_signals",
    "signal_handlers",
    "task_result",
]


class RayUnavailable(FpgGymError, ImportError):
    """``--backend ray`` without Ray installed (the message says what to install)."""


def require_ray() -> Any:
    """The ``ray`` module, or :class:`RayUnavailable` naming the extra to install."""
    return import_optional(  # optional extra fpg-gym[distributed]
        "ray", RayUnavailable("backend 'ray' needs Ray: pip install 'fpg-gym[distributed]'")
    )


#: Seconds a Ray address has to accept a connection before it counts as dead.
CONNECT_TIMEOUT_S = 5.0


class RayAddressError(FpgGymError, ValueError):
    """``--address`` names no Ray cluster that answers (the message names the address)."""


def check_address(
    address: str | None, timeout: float = CONNECT_TIMEOUT_S, *, argument: str = "--address"
) -> None:
    """Refuse, within ``timeout`` seconds, a ``HOST:PORT`` address nothing listens on (Ray's
    own connection attempt retries for minutes and floods the log).

    ``None``, ``"auto"`` and ``"local"`` (Ray's words) are left to Ray; so is a ``ray://``
    client address's scheme (its host and port are checked).

    Parameters
    ----------
    address : str or None
    timeout : float
        Seconds to wait for the connection.
    argument : str
        Where the address came from, for the message (``--address``, ``RAY_ADDRESS``).

    Raises
    ------
    RayAddressError
        The address is not ``HOST:PORT``, its host is unknown, or no connection is accepted.
    """
    if address is None or address in ("auto", "local"):
        return
    target = address.removeprefix("ray://")
    host, colon, port_text = target.rpartition(":")
    host = host.strip("[]")
    if not colon or not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise RayAddressError(
            f"{argument} {address!r}: expected HOST:PORT of a Ray cluster's head (e.g. "
            "10.0.0.5:6379), 'auto' or 'local'"
        )
    try:
        with socket.create_connection((host, int(port_text)), timeout=timeout):
            pass
    except socket.gaierror as error:
        raise RayAddressError(f"{argument} {address}: unknown host ({error.strerror})") from None
    except OSError as error:
        reason = "no answer" if isinstance(error, TimeoutError) else error.strerror or error
        raise RayAddressError(
            f"{argument} {address}: no Ray cluster answers there ({reason} within "
            f"{timeout:g} s); start one (`ray start --head`) or check the address"
        ) from None


def signal_handlers() -> dict[int, Any]:
    """This process's SIGINT and SIGTERM handlers (empty outside the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}


def restore_signals(handlers: dict[int, Any]) -> None:
    """Put back handlers saved by :func:`signal_handlers`."""
    for number, handler in handlers.items():
        if handler is not None:
            signal.signal(number, handler)


@contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None) -> Iterator[Any]:
    """The ``ray`` module, connected for the ``with`` block.

    An instance the caller already started (``ray.init``) is used as it is. Otherwise this
    connects to ``address`` (or ``RAY_ADDRESS``), or starts a local instance with ``num_cpus``
    CPUs (None: all), and shuts it down on leaving.

    Raises
    ------
    RayUnavailable
        Without Ray installed.
    RayAddressError
        ``address`` names nothing that answers (:func:`check_address`).
    """
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    if address is not None:
        check_address(address)
    else:
        check_address(os.environ.get("RAY_ADDRESS"), argument="RAY_ADDRESS")
    handlers = signal_handlers()
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
    if address is None and not os.environ.get("RAY_ADDRESS"):
        kwargs["num_cpus"] = num_cpus
    ray.init(address=address, **kwargs)
    try:
        yield ray
    finally:
        ray.shutdown()
        restore_signals(handlers)  # Ray's driver installs its own SIGTERM handler


def task_result(ray: Any, ref: Any) -> Any:
    """``ray.get(ref)``, a failed task raising its own exception here (not Ray's wrapper)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as error:
        cause = getattr(error, "cause", None)
        raise (cause if isinstance(cause, Exception) else error) from None
