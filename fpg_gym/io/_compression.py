"""Transparent gzip: readers accept compressed files whatever their name."""

from __future__ import annotations

import gzip

#: First two bytes of every gzip stream (RFC 1952).
GZIP_MAGIC = b"\x1f\x8b"


def maybe_gunzip(raw: bytes) -> bytes:
    """``raw`` decompressed when it starts with the gzip magic bytes, else ``raw`` itself.

    Raises
    ------
    OSError or EOFError
        On corrupt or truncated gzip data (``gzip.BadGzipFile`` is an ``OSError``).
    """
    return gzip.decompress(raw) if raw[:2] == GZIP_MAGIC else raw
