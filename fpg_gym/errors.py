"""Exceptions raised by fpg-gym."""

from __future__ import annotations

from pathlib import Path


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
        path: str | Path,
        message: str,
        *,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = str(path)
        self.line = line
        self.field = field
        where = self.path
        if line is not None:
            where += f", line {line}"
        if field is not None:
            where += f", field {field!r}"
        super().__init__(f"{where}: {message}")
