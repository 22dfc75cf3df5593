"""Transparent gzip: readers accept compressed files whatever their name."""

from __future__ import annotations

import gzip
import io
import os
import zlib

from fpg_gym.errors import DataFormatError

#: First two bytes of every gzip stream (RFC 1952).
GZIP_MAGIC = b"\x1f\x8b"
#: Most bytes a compressed file may expand to (a "gzip bomb" must not exhaust memory).
MAX_DECOMPRESSED_BYTES = 1 << 30


def maybe_gunzip(raw: bytes, path: str | os.PathLike[str] = "") -> bytes:
    """``raw`` decompressed when it starts with the gzip magic bytes, else ``raw`` itself.

    Raises
    ------
    DataFormatError
        Naming ``path``: corrupt or truncated gzip data, or data expanding beyond
        :data:`MAX_DECOMPRESSED_BYTES`.
    """
    if raw[:2] != GZIP_MAGIC:
        return raw
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(raw)) as stream:
            data = stream.read(MAX_DECOMPRESSED_BYTES + 1)
    except (OSError, EOFError, zlib.error) as error:
        raise DataFormatError(path, f"corrupt gzip data, or truncated ({error})") from None
    if len(data) > MAX_DECOMPRESSED_BYTES:
        raise DataFormatError(
            path, f"gzip data expands beyond {MAX_DECOMPRESSED_BYTES >> 20} MiB; not a mocap file"
        )
    return data
