"""Exceptions raised by fpg-gym.

Every error fpg-gym raises on purpose derives from :class:`FpgGymError`. They survive pickling
with their message and fields (an error raised in a worker process reaches the parent intact,
naming the file), and the command line prints them on one line with exit status 2.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType
from typing import Any


class FpgGymError(Exception):
    """Base class of every error fpg-gym raises on purpose."""


class DataFormatError(FpgGymError, ValueError):
    """A file's content does not match its format.

    The message names the file and, where known, the line (1-based) or field.

    Parameters
    ----------
    path : str or Path
        The offending file.
    message : str
        What was wrong and what was expected.
    line : int, optional
        1-based line number.
    field : str, optional
        Name of the offending field (for archives such as ``.npz``).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        message: str,
        *,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = str(path)
        self.line = line
        self.field = field
        self.reason = message
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field {field!r}"
        super().__init__(f"{where}: {message}")

    def __reduce__(self) -> tuple[Any, ...]:
        # Exception pickles ``args`` (the formatted message) by default, which does not fit
        # this constructor: rebuild from the parts instead.
        return (_rebuild_data_format_error, (self.path, self.reason, self.line, self.field))


def _rebuild_data_format_error(
    path: str, message: str, line: int | None, field: str | None
) -> DataFormatError:
    return DataFormatError(path, message, line=line, field=field)


class OutputError(FpgGymError, ValueError):
    """An output path that cannot or must not be written (an input, a folder, unwritable).

    The message names the argument and the path.
    """


class TaskError(FpgGymError):
    """A task of a parallel run failed; the message names the task (episode and method) and
    the original error."""


def import_optional(module: str, missing: ImportError) -> ModuleType:
    """Import ``module`` of an optional extra, or raise ``missing`` (which says what to install).

    Parameters
    ----------
    module : str
        The module's dotted name (``"ray"``, ``"rerun"``, ``"torch"``...).
    missing : ImportError
        The error raised, chained to the original, when ``module`` cannot be imported.
    """
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise missing from error


def interrupt_in(error: BaseException) -> KeyboardInterrupt | None:
    """The ``KeyboardInterrupt`` (Ctrl-C, or SIGTERM through the command line) that ``error``
    is: itself, or the cause of a ``SystemError``.

    A signal handler runs at the next Python instruction, which can be inside a compiled
    (numba) call that runs Python code on its way out (boxing the arrays it returns): the call
    then fails with ``SystemError: ... returned a result with an exception set``, its cause the
    interrupt. Code that keeps the work done on an interrupt asks this, so that such an
    interrupt is one too.
    """
    current: BaseException | None = error
    while isinstance(current, SystemError):
        current = current.__cause__
    return current if isinstance(current, KeyboardInterrupt) else None
