"""Writing output files safely: never over an input, never half-written.

Every command that writes a file checks its output first (:func:`check_output`), before any
work: an output that resolves to one of the command's inputs, an existing folder, or a place
that cannot be written is refused with an :class:`~fpg_gym.core.errors.OutputError` naming the
argument. The file is then written to a temporary file in the same folder and renamed into place
(:func:`atomic_path`, :func:`save_npz`, :func:`write_text`), so a crash or a kill leaves either
the old file or the new one, never a torn one.
"""

from __future__ import annotations

import os
import signal
import tempfile
import threading
import uuid
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.errors import OutputError

__all__ = [
    "atomic_path",
    "check_output",
    "interrupts_deferred",
    "npz_name",
    "same_file",
    "save_npz",
    "write_text",
]


def npz_name(path: str | os.PathLike[str]) -> Path:
    """The name numpy writes for ``path``: ``.npz`` appended unless the name ends with it."""
    target = Path(path)
    return target if target.suffix == ".npz" else target.with_name(target.name + ".npz")


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name the same file (the same inode when both exist, else the same
    resolved path; links and ``..`` are followed)."""
    first, second = Path(a), Path(b)
    try:
        if first.exists() and second.exists():
            return os.path.samefile(first, second)
    except OSError:
        pass
    try:
        return first.resolve() == second.resolve()
    except (OSError, RuntimeError):  # a loop of symbolic links: compare the paths as given
        return os.path.abspath(first) == os.path.abspath(second)


def _expand_inputs(inputs: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Files named by ``inputs``: files themselves and the files under folders."""
    files: list[Path] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            files.extend(p for p in path.rglob("*") if p.is_file())
        else:
            files.append(path)
    return files


def check_output(
    out: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str]] = (),
    *,
    argument: str = "--out",
    npz: bool = False,
) -> Path:
    """Check an output file before any work; return the path that will be written.

    Parameters
    ----------
    out : str or Path
        The output as the user gave it.
    inputs : iterable of str or Path
        The command's inputs (files or folders; words such as ``default`` that name no file
        are ignored). The output must not be any of them, nor a file under an input folder.
    argument : str
        The argument's name, for the message.
    npz : bool
        The writer appends ``.npz`` to a name without it (numpy's rule): check that name.

    Raises
    ------
    OutputError
        If the output is an input, an existing folder, or its folder cannot be created or
        written.
    """
    given = Path(out)
    if str(out) == "" or given.name in ("", ".", ".."):
        raise OutputError(f"{argument} {str(out)!r}: expected a file name")
    target = npz_name(given) if npz else given
    candidates = {given, target}
    for source in _expand_inputs(inputs):
        for candidate in candidates:
            if same_file(candidate, source):
                raise OutputError(
                    f"{argument} {candidate}: is the input {source}; refusing to overwrite an "
                    "input (choose another output name)"
                )
    for candidate in (given, target):
        if candidate.is_dir():
            raise OutputError(f"{argument} {candidate}: is a folder; expected a file name")
    folder = target.parent if str(target.parent) else Path(".")
    existing = folder
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{argument} {target}: {existing} is not a folder")
    try:  # a real probe: permissions, read-only file systems and quotas all show here
        with tempfile.TemporaryFile(dir=existing, prefix=".fpg-gym-probe-"):
            pass
    except OSError as error:
        raise OutputError(
            f"{argument} {target}: cannot write in folder {existing} ({error.strerror})"
        ) from None
    return target


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) and SIGTERM back within the block, then raise ``KeyboardInterrupt``.

    For the final write of results already computed: an interrupt that arrives while they are
    being summarised and written no longer throws them away; it is raised once they are on
    disk. Outside the main thread (where Python cannot install handlers) the block runs as is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def hold(signum: int, frame: object) -> None:
        received.append(signum)

    previous = {number: signal.signal(number, hold) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    if received:
        raise KeyboardInterrupt(f"signal {received[0]} (held until the results were written)")


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path beside ``path``; renamed onto ``path`` when the block succeeds, removed
    when it fails. Folders are created.

    Raises
    ------
    OutputError
        Writing failed with an ``OSError`` (a full disk, say): the message names ``path``.
    """
    target = Path(path)
    temporary = target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        yield temporary
        os.replace(temporary, target)
    except OSError as error:  # a full disk, a quota, a read-only file system: name the file
        temporary.unlink(missing_ok=True)
        raise OutputError(
            f"{target}: cannot write ({error.strerror or error}); the previous file, if any, "
            "is left as it was"
        ) from error
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def save_npz(
    path: str | os.PathLike[str], arrays: Mapping[str, Any], *, compressed: bool = True
) -> Path:
    """Write ``arrays`` as an ``.npz`` archive atomically (temporary file, then rename).

    The name is taken as given except that ``.npz`` is appended when it lacks it (numpy's
    rule, kept for compatibility). Returns the path written.
    """
    target = npz_name(path)
    with atomic_path(target) as temporary, open(temporary, "xb") as stream:
        if compressed:
            np.savez_compressed(stream, **arrays)
        else:
            np.savez(stream, **arrays)
    return target


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) atomically; returns the path."""
    target = Path(path)
    with atomic_path(target) as temporary:
        temporary.write_text(text, encoding="utf-8")
    return target
