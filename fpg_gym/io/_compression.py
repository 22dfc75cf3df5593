"""Transparent gzip: readers accept compressed files whatever their name."""

from __future__ import annotations

import os
import zlib
from pathlib import Path

from fpg_gym.errors import DataFormatError

#: First two bytes of every gzip stream (RFC 1952).
GZIP_MAGIC = b"\x1f\x8b"
#: Most bytes a compressed file may expand to (a "gzip bomb" must not exhaust memory).
MAX_DECOMPRESSED_BYTES = 1 << 30


def maybe_gunzip(raw: bytes, path: str | os.PathLike[str] = "") -> bytes:
    """``raw`` decompressed when it starts with the gzip magic bytes, else ``raw`` itself.

    Concatenated gzip members are joined; zero padding after the last one is ignored.

    Raises
    ------
    DataFormatError
        Naming ``path``: corrupt or truncated gzip data, or data expanding beyond
        :data:`MAX_DECOMPRESSED_BYTES`.
    """
    if raw[:2] != GZIP_MAGIC:
        return raw
    pieces: list[bytes] = []
    total = 0
    data = raw
    while data:
        stream = zlib.decompressobj(wbits=31)  # gzip header and trailer
        try:
            piece = stream.decompress(data, MAX_DECOMPRESSED_BYTES + 1 - total)
        except zlib.error as error:
            raise DataFormatError(path, f"corrupt gzip data ({error})") from None
        total += len(piece)
        if total > MAX_DECOMPRESSED_BYTES or stream.unconsumed_tail:
            raise DataFormatError(
                path,
                f"gzip data expands beyond {MAX_DECOMPRESSED_BYTES >> 20} MiB; not a mocap file",
            )
        if not stream.eof:
            raise DataFormatError(path, "corrupt gzip data, or truncated (the stream ends early)")
        pieces.append(piece)
        data = stream.unused_data
        if not data.strip(b"\0"):
            break
        if data[:2] != GZIP_MAGIC:
            raise DataFormatError(path, "corrupt gzip data (unexpected bytes after the stream)")
    return b"".join(pieces)


def read_input_bytes(path: Path) -> bytes:
    """The bytes of an input file, decompressed when gzip (:func:`maybe_gunzip`).

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist (the message names it).
    DataFormatError
        Naming ``path``: it cannot be read, or its gzip data is corrupt.
    """
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot read the file ({error.strerror})") from None
    return maybe_gunzip(raw, path)
