"""Transparent gzip: readers accept compressed files whatever their name."""

from __future__ import annotations

import os
import zlib
from pathlib import Path

from fpg_gym.core.errors import DataFormatError
from fpg_gym.io.files import MAX_INPUT_MB_ENV, max_input_bytes, read_input_file

#: First two bytes of every gzip stream (RFC 1952).
GZIP_MAGIC = b"\x1f\x8b"
#: Bytes inflated at a time.
_PIECE_BYTES = 16 << 20


def maybe_gunzip(raw: bytes, path: str | os.PathLike[str] = "") -> bytes:
    """``raw`` decompressed when it starts with the gzip magic bytes, else ``raw`` itself.

    Concatenated gzip members are joined; zero padding after the last one is ignored. The
    stream is inflated piece by piece and refused as soon as it passes the memory ceiling
    (:func:`fpg_gym.io.files.max_input_bytes`): a "gzip bomb" never expands beyond it.

    Raises
    ------
    DataFormatError
        Naming ``path``: corrupt or truncated gzip data, or data expanding beyond the ceiling.
    """
    if raw[:2] != GZIP_MAGIC:
        return raw
    ceiling = max_input_bytes()
    pieces: list[bytes] = []
    total = 0
    data = raw
    while data:
        stream = zlib.decompressobj(wbits=31)  # gzip header and trailer
        pending = data
        while pending and not stream.eof:  # in pieces: memory grows with what is kept only
            try:
                piece = stream.decompress(pending, _PIECE_BYTES)
            except zlib.error as error:
                raise DataFormatError(path, f"corrupt gzip data ({error})") from None
            total += len(piece)
            if total > ceiling:
                raise DataFormatError(
                    path,
                    f"gzip data expands beyond {ceiling >> 20} MiB, the most an "
                    f"input may hold (set {MAX_INPUT_MB_ENV} to read it)",
                )
            pieces.append(piece)
            pending = stream.unconsumed_tail
        if not stream.eof:
            raise DataFormatError(path, "corrupt gzip data, or truncated (the stream ends early)")
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
        Naming ``path``: not a readable file (:func:`fpg_gym.io.files.read_input_file`),
        larger than the memory ceiling, or corrupt gzip data.
    """
    return maybe_gunzip(read_input_file(path), path)
