"""Shared pybullet plumbing: DIRECT clients with the C-level console chatter silenced, and the
clients their closed owners hand back for the next owner of the same kind."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pybullet_data


def data_path() -> Path:
    """Folder of the ``pybullet_data`` package (the embedded default data)."""
    return Path(pybullet_data.getDataPath())


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """Silence what C code prints on file descriptors 1 and 2 (pybullet's URDF warnings)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 1)
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


with quiet_stdout():  # pybullet prints its build time on import
    import pybullet


def connect_direct(*, renderer: bool = True) -> int:
    """Open a new pybullet client in DIRECT mode (no display) and return its id.

    Parameters
    ----------
    renderer : bool
        Keep pybullet's software renderer (``getCameraImage``). Without it (``False``) the
        client cannot take pictures, but creating a body costs about half as much: the renderer
        converts every new body's shapes into meshes. The physics are the same.
    """
    with quiet_stdout():
        client = pybullet.connect(pybullet.DIRECT)
    if client < 0:
        raise RuntimeError("pybullet could not open a DIRECT client")
    if not renderer:
        # Loading a plugin that is already loaded returns its id (the renderer is built in).
        plugin = pybullet.loadPlugin("tinyRendererPlugin", physicsClientId=client)
        if plugin >= 0:
            pybullet.unloadPlugin(plugin, physicsClientId=client)
    return int(client)


#: Clients handed back, kept for the next owner of the same kind (at most this many a kind).
KEPT_CLIENTS = 4
_handed_back: dict[str, list[int]] = {}
_owner_process = os.getpid()


def reuse_direct(kind: str) -> int:
    """A DIRECT client without the renderer for an owner of ``kind`` (``"ragdoll"``, ``"rays"``):
    one that a closed owner of the same kind handed back (:func:`hand_back`; its world is empty,
    as :func:`pybullet.resetSimulation` leaves it), else a new one (:func:`connect_direct`, about
    12 CPU ms). An owner sets every engine parameter it relies on after
    ``resetSimulation``; a kind's owners all set the same ones."""
    global _owner_process
    if os.getpid() != _owner_process:  # a forked process does not share its parent's clients
        _handed_back.clear()
        _owner_process = os.getpid()
    idle = _handed_back.get(kind)
    while idle:
        client = idle.pop()
        if pybullet.isConnected(physicsClientId=client):
            return client
    return connect_direct(renderer=False)


def hand_back(kind: str, client: int) -> None:
    """Release ``client`` (from :func:`reuse_direct`): its world is reset and the client kept
    for the next owner of ``kind``, or disconnected when :data:`KEPT_CLIENTS` are kept."""
    try:
        idle = _handed_back.setdefault(kind, [])
        if os.getpid() == _owner_process and len(idle) < KEPT_CLIENTS:
            pybullet.resetSimulation(physicsClientId=client)
            idle.append(client)
        else:
            pybullet.disconnect(physicsClientId=client)
    except pybullet.error:  # pragma: no cover - already gone
        pass
