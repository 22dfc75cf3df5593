"""Checking ``.npz`` archives before numpy reads them.

``numpy.load`` allocates what an array's header announces before reading any data, so a forged
header (a shape of 10^12 elements in a file of a few bytes) ends in ``MemoryError``; a corrupt
member ends in ``zlib.error``. :func:`check_npz` reads every member's header first and refuses,
with a :class:`~fpg_gym.core.errors.DataFormatError` naming the file and the array, an archive that
is not a zip, a member that is not an ``.npy`` array, a pickled (object) array, or an array larger
than its member can hold. It also refuses, before anything is inflated, arrays that together
declare more than the memory ceiling (:func:`fpg_gym.io.files.max_input_bytes`) and, given the
shapes a reader expects (``shapes``), arrays whose declared shapes do not fit them (a
recording's ``states`` must have as many frames as its ``positions``). :func:`load_npz` checks,
then reads every array (no pickle).
"""

from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.lib.format as npy_format

from fpg_gym.core.errors import DataFormatError
from fpg_gym.io.files import MAX_INPUT_MB_ENV, check_input_file, max_input_bytes

__all__ = ["Shape", "check_npz", "check_zip", "load_npz"]

#: An expected array shape: each dimension an exact size, or a name that must take the same
#: size in every array of the archive (``("T", 20, 3)``).
Shape = tuple[int | str, ...]

#: Deflate cannot expand data by more than about 1032 times: a bound on a member's real size.
_MAX_DEFLATE_RATIO = 1100
#: Header bytes allowed on top of the data.
_HEADER_ALLOWANCE = 1 << 16


def check_npz(
    path: str | os.PathLike[str],
    only: Collection[str] | None = None,
    *,
    shapes: Mapping[str, Shape] | None = None,
) -> list[str]:
    """Check every array header of an ``.npz`` archive; return the array names.

    Nothing is inflated: only the members' ``.npy`` headers are read.

    Parameters
    ----------
    path : str or Path
    only : collection of str, optional
        Check only these arrays (the ones a reader will load); all by default.
    shapes : mapping of str to Shape, optional
        The shape each named array must have (arrays absent from the archive are not checked
        here); a named dimension takes one size across the arrays.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    DataFormatError
        If the path is not a readable file, not a zip archive, a member is not an ``.npy``
        array, holds Python objects (pickle), announces more data than it holds or a shape
        other than ``shapes`` says, or the arrays together announce more than the memory
        ceiling.
    """
    source = check_input_file(path)
    names: list[str] = []
    declared: dict[str, tuple[tuple[int, ...], np.dtype[Any]]] = {}
    try:
        with zipfile.ZipFile(source) as archive:
            for info in archive.infolist():
                name = info.filename.removesuffix(".npy")
                if only is not None and name not in only:
                    names.append(name)
                    continue
                if not info.filename.endswith(".npy"):
                    raise DataFormatError(
                        source, "not an .npy array (an .npz archive holds only arrays)", field=name
                    )
                limit = info.file_size
                if info.compress_type != zipfile.ZIP_STORED:
                    limit = min(limit, info.compress_size * _MAX_DEFLATE_RATIO + _HEADER_ALLOWANCE)
                shape, dtype = _read_header(source, archive, info, name)
                if dtype.hasobject:
                    raise DataFormatError(
                        source,
                        "holds Python objects (pickle), which fpg-gym never loads; expected "
                        "numbers or strings",
                        field=name,
                    )
                size = math.prod(int(n) for n in shape) * int(dtype.itemsize)
                if size > limit:
                    raise DataFormatError(
                        source,
                        f"the array header announces shape {tuple(shape)} of {dtype} "
                        f"({size} bytes), more than the archive member holds ({limit} bytes): "
                        "a corrupt or forged file",
                        field=name,
                    )
                declared[name] = (shape, dtype)
                names.append(name)
    except DataFormatError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError) as error:
        raise DataFormatError(source, f"not a readable .npz archive ({error})") from None
    except (ValueError, OSError, NotImplementedError, OverflowError) as error:
        raise DataFormatError(source, f"corrupt .npz archive ({error})") from None
    _check_total(source, declared)
    if shapes:
        _check_shapes(source, declared, shapes)
    return names


def check_zip(path: str | os.PathLike[str]) -> Path:
    """Check a file a reader will inflate (a torch ``.pt`` file, say) before it does: a zip
    archive's members each declare a size their compressed bytes can hold, and together at
    most the memory ceiling (:func:`fpg_gym.io.files.max_input_bytes`); any other file is
    itself at most the ceiling (its reader refuses what it is not).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    DataFormatError
        Not a readable file, or sizes that do not fit (naming the member).
    """
    source = check_input_file(path)
    if not zipfile.is_zipfile(source):
        ceiling = max_input_bytes()
        if source.stat().st_size > ceiling:
            raise DataFormatError(
                source,
                f"more than the {ceiling >> 20} MiB an input may hold (set {MAX_INPUT_MB_ENV} "
                "to read it)",
            )
        return source
    total = 0
    try:
        with zipfile.ZipFile(source) as archive:
            for info in archive.infolist():
                if info.compress_type != zipfile.ZIP_STORED and info.file_size > (
                    info.compress_size * _MAX_DEFLATE_RATIO + _HEADER_ALLOWANCE
                ):
                    raise DataFormatError(
                        source,
                        f"declares {info.file_size} bytes from {info.compress_size} compressed: "
                        "a corrupt or forged archive",
                        field=info.filename,
                    )
                total += info.file_size
    except DataFormatError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError) as error:
        raise DataFormatError(source, f"not a readable zip archive ({error})") from None
    ceiling = max_input_bytes()
    if total > ceiling:
        raise DataFormatError(
            source,
            f"the archive declares {total >> 20} MiB, more than the {ceiling >> 20} MiB an input "
            f"may hold; refused before inflating (set {MAX_INPUT_MB_ENV} to read it)",
        )
    return source


def _check_total(source: Path, declared: Mapping[str, tuple[tuple[int, ...], Any]]) -> None:
    """Refuse arrays that together declare more bytes than the memory ceiling."""
    total = sum(math.prod(shape) * int(dtype.itemsize) for shape, dtype in declared.values())
    ceiling = max_input_bytes()
    if total > ceiling:
        largest = max(declared, key=lambda n: math.prod(declared[n][0]) * declared[n][1].itemsize)
        raise DataFormatError(
            source,
            f"the arrays declare {total >> 20} MiB (largest: {largest!r}, shape "
            f"{declared[largest][0]}), more than the {ceiling >> 20} MiB an input may hold; "
            f"refused before inflating (set {MAX_INPUT_MB_ENV} to read it)",
        )


def _check_shapes(
    source: Path,
    declared: Mapping[str, tuple[tuple[int, ...], Any]],
    shapes: Mapping[str, Shape],
) -> None:
    """Refuse declared shapes that do not fit ``shapes`` (see :func:`check_npz`)."""
    sizes: dict[str, tuple[int, str]] = {}  # dimension name -> (size, array that set it)
    for name, expected in shapes.items():
        if name not in declared:
            continue
        shape = declared[name][0]
        spelled = "(" + ", ".join(str(d) for d in expected) + ("," if len(expected) == 1 else "")
        spelled += ")"
        fits = len(shape) == len(expected)
        for actual, wanted in zip(shape, expected, strict=False):
            if not fits:
                break
            if isinstance(wanted, int):
                fits = actual == wanted
            elif wanted in sizes:
                fits = actual == sizes[wanted][0]
            else:
                sizes[wanted] = (actual, name)
        if not fits:
            known = "".join(
                f"; {dim} = {size} (from {origin!r})"
                for dim, (size, origin) in sizes.items()
                if origin != name
            )
            raise DataFormatError(
                source,
                f"expected shape {spelled}, got {tuple(shape)} (its header's){known}",
                field=name,
            )


def _read_header(
    source: Path, archive: zipfile.ZipFile, info: zipfile.ZipInfo, name: str
) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """Shape and dtype from a member's ``.npy`` header (nothing else is read)."""
    try:
        with archive.open(info) as member:
            version = npy_format.read_magic(member)
            if version == (1, 0):
                shape, _, dtype = npy_format.read_array_header_1_0(member)
            elif version == (2, 0):
                shape, _, dtype = npy_format.read_array_header_2_0(member)
            else:
                raise DataFormatError(
                    source, f"unsupported .npy format version {version}", field=name
                )
    except DataFormatError:
        raise
    except Exception as error:  # numpy parses the header with ast: its errors vary
        text = " ".join(str(error).split())[:200] or type(error).__name__
        raise DataFormatError(source, f"corrupt array header ({text})", field=name) from None
    return tuple(int(n) for n in shape), dtype


def load_npz(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive, after :func:`check_npz` (no pickle).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    DataFormatError
        As :func:`check_npz`, or when an array's data is corrupt or truncated.
    """
    source = Path(path)
    check_npz(source)
    try:
        with np.load(source, allow_pickle=False) as archive:
            return {key: np.asarray(archive[key]) for key in archive.files}
    except (zipfile.BadZipFile, zlib.error, EOFError) as error:
        raise DataFormatError(source, f"not a readable .npz archive ({error})") from None
    except (ValueError, OSError) as error:
        raise DataFormatError(source, f"corrupt .npz archive ({error})") from None
