"""Opening input files: what a path is, how much of it may be read, JSON without surprises.

Every reader goes through these, so that a bad path gets the same message everywhere: a
missing file, a folder, a symbolic-link loop, a device or pipe, a file that cannot be read or
one larger than the memory ceiling (:func:`max_input_bytes`) is named with what was expected.
:func:`read_json` refuses cleanly what ``json.loads`` does not: a byte-order mark (skipped),
nesting deep enough to exhaust Python's stack, non-UTF-8 bytes.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import stat
from pathlib import Path
from typing import Any

from fpg_gym.core.errors import DataFormatError

__all__ = [
    "MAX_INPUT_MB_ENV",
    "check_input_file",
    "decode_text",
    "file_digest",
    "max_input_bytes",
    "read_input_file",
    "read_json",
]

#: Environment variable that raises (or lowers) the memory ceiling of one input, in MiB.
MAX_INPUT_MB_ENV = "FPG_GYM_MAX_INPUT_MB"
#: The default ceiling: the most bytes one input file may hold once decompressed (a text file,
#: a gzip stream's content, the arrays an ``.npz`` archive declares). The largest real inputs
#: here (Bandai Namco BVH takes, MSRC-12 and UI-PRMD streams) are under 3 MB.
DEFAULT_MAX_INPUT_MB = 256
_BOM = b"\xef\xbb\xbf"


def max_input_bytes() -> int:
    """The memory ceiling of one input, in bytes: ``$FPG_GYM_MAX_INPUT_MB`` MiB, else
    :data:`DEFAULT_MAX_INPUT_MB` MiB.

    Raises
    ------
    ValueError
        ``FPG_GYM_MAX_INPUT_MB`` is not a positive number.
    """
    text = os.environ.get(MAX_INPUT_MB_ENV, "").strip()
    if not text:
        return DEFAULT_MAX_INPUT_MB << 20
    try:
        megabytes = float(text)
    except ValueError:
        megabytes = float("nan")
    if not 0 < megabytes < 1 << 40:
        raise ValueError(f"{MAX_INPUT_MB_ENV}: expected a positive number of MiB, got {text!r}")
    return int(megabytes * (1 << 20))


def check_input_file(path: str | os.PathLike[str]) -> Path:
    """``path`` if it is a regular file this process can open, else a clear error.

    Raises
    ------
    FileNotFoundError
        Nothing there (a dangling link included); the message names the path.
    DataFormatError
        A folder, a symbolic-link loop, a device or pipe, or a file that cannot be opened
        (permissions), naming the path and what was expected.
    """
    source = Path(path)
    try:
        info = source.stat()
    except FileNotFoundError:
        raise FileNotFoundError(f"{source}: no such file") from None
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise DataFormatError(source, "a loop of symbolic links; expected a file") from None
        raise DataFormatError(source, f"cannot read the file ({error.strerror})") from None
    if stat.S_ISDIR(info.st_mode):
        raise DataFormatError(source, "is a folder; expected a file")
    if not stat.S_ISREG(info.st_mode):
        raise DataFormatError(source, "not a regular file (a device, pipe or socket)")
    try:
        with open(source, "rb"):
            pass
    except OSError as error:
        raise DataFormatError(source, f"cannot read the file ({error.strerror})") from None
    return source


def read_input_file(path: str | os.PathLike[str], limit: int | None = None) -> bytes:
    """The bytes of an input file, after :func:`check_input_file` and a size check.

    Parameters
    ----------
    limit : int, optional
        Most bytes accepted (:func:`max_input_bytes` by default).

    Raises
    ------
    FileNotFoundError, DataFormatError
        As :func:`check_input_file`, or the file is larger than ``limit``.
    """
    source = check_input_file(path)
    ceiling = max_input_bytes() if limit is None else limit
    size = source.stat().st_size
    if size > ceiling:
        raise DataFormatError(
            source,
            f"{size >> 20} MiB, more than the {ceiling >> 20} MiB an input may hold "
            f"(set {MAX_INPUT_MB_ENV} to read it)",
        )
    try:
        with open(source, "rb") as handle:
            return handle.read(ceiling + 1)
    except OSError as error:
        raise DataFormatError(source, f"cannot read the file ({error.strerror})") from None


def decode_text(raw: bytes, path: str | os.PathLike[str], *, latin1: bool = False) -> str:
    """``raw`` as text: UTF-8 without its byte-order mark (Windows editors write one).

    Parameters
    ----------
    latin1 : bool
        Fall back to Latin-1 for bytes that are not UTF-8 (every byte decodes), instead of
        refusing the file.

    Raises
    ------
    DataFormatError
        Not UTF-8 (and ``latin1`` is False), naming ``path``.
    """
    if raw.startswith(_BOM):
        raw = raw[len(_BOM) :]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as error:
        if latin1:
            return raw.decode("latin-1")
        raise DataFormatError(
            path, f"not a UTF-8 text file (byte {error.start} is {raw[error.start]:#04x})"
        ) from None


def read_json(
    path: str | os.PathLike[str],
    *,
    text: str | None = None,
    limit: int | None = None,
) -> Any:
    """The JSON document of a file (or ``text`` read from it), refused cleanly when it is not.

    Parameters
    ----------
    path : str or Path
        The file (named in errors; read unless ``text`` is given).
    text : str, optional
        The file's content, already read.
    limit : int, optional
        Most bytes accepted (:func:`max_input_bytes` by default).

    Raises
    ------
    FileNotFoundError, DataFormatError
        As :func:`read_input_file`; not UTF-8; not JSON (with the line); nested too deeply
        for Python's parser.
    """
    if text is None:
        text = decode_text(read_input_file(path, limit), path)
    elif text.startswith("\ufeff"):
        text = text[1:]
    try:
        return json.loads(text)
    except json.JSONDecodeError as error:
        raise DataFormatError(path, f"not JSON ({error.msg})", line=error.lineno) from None
    except RecursionError:
        raise DataFormatError(
            path, "JSON nested too deeply for Python's parser; not a file fpg-gym reads"
        ) from None
    except ValueError as error:
        raise DataFormatError(path, f"not JSON ({error})") from None


def file_digest(path: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of a file's bytes, read in blocks: how resume keys name an input by its
    content rather than its path.

    Raises
    ------
    FileNotFoundError, DataFormatError
        As :func:`check_input_file`.
    """
    source = check_input_file(path)
    digest = hashlib.sha256()
    try:
        with open(source, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError as error:
        raise DataFormatError(source, f"cannot read the file ({error.strerror})") from None
    return digest.hexdigest()
