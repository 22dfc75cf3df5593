"""Checking ``.npz`` archives before numpy reads them.

``numpy.load`` allocates what an array's header announces before reading any data, so a forged
header (a shape of 10^12 elements in a file of a few bytes) ends in ``MemoryError``; a corrupt
member ends in ``zlib.error``. :func:`check_npz` reads every member's header first and refuses,
with a :class:`~fpg_gym.errors.DataFormatError` naming the file and the array, an archive that is
not a zip, a member that is not an ``.npy`` array, a pickled (object) array, or an array larger
than its member can hold. :func:`load_npz` checks, then reads every array (no pickle).
"""

from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np
import numpy.lib.format as npy_format

from fpg_gym.errors import DataFormatError

__all__ = ["check_npz", "load_npz"]

#: Deflate cannot expand data by more than about 1032 times: a bound on a member's real size.
_MAX_DEFLATE_RATIO = 1100
#: Header bytes allowed on top of the data.
_HEADER_ALLOWANCE = 1 << 16


def check_npz(path: str | os.PathLike[str], only: Collection[str] | None = None) -> list[str]:
    """Check every array header of an ``.npz`` archive; return the array names.

    Parameters
    ----------
    path : str or Path
    only : collection of str, optional
        Check only these arrays (the ones a reader will load); all by default.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    DataFormatError
        If the file is not a zip archive, a member is not an ``.npy`` array, holds Python
        objects (pickle), or announces more data than it holds.
    """
    source = Path(path)
    if not source.is_file():
        raise FileNotFoundError(f"{source}: no such file")
    names: list[str] = []
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
                names.append(name)
    except DataFormatError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError) as error:
        raise DataFormatError(source, f"not a readable .npz archive ({error})") from None
    except (ValueError, OSError, NotImplementedError, OverflowError) as error:
        raise DataFormatError(source, f"corrupt .npz archive ({error})") from None
    return names


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
