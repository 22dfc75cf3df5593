"""Shared pybullet plumbing: DIRECT clients with the C-level console chatter silenced."""

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


def connect_direct() -> int:
    """Open a new pybullet client in DIRECT mode (no display) and return its id."""
    with quiet_stdout():
        client = pybullet.connect(pybullet.DIRECT)
    if client < 0:
        raise RuntimeError("pybullet could not open a DIRECT client")
    return int(client)
