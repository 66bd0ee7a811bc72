"""The text entries of a PNG file, read by hand (no image library needed)."""

from __future__ import annotations

import struct
import zlib


def png_text(data: bytes) -> dict[str, str]:
    """The ``tEXt`` entries of a PNG (read here, not with the writer's library)."""
    out: dict[str, str] = {}
    pos = 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        assert (
            zlib.crc32(kind + body)
            == struct.unpack(">I", data[pos + 8 + length : pos + 12 + length])[0]
        )
        if kind == b"tEXt":
            key, _, value = body.partition(b"\0")
            out[key.decode("latin-1")] = value.decode("latin-1")
        pos += 12 + length
    return out
