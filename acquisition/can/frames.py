"""One CAN frame as received (:class:`RawFrame`) and the binary record raw-frame logs store.

The bottom of the CAN modules: the DBC plan, the codecs, the sources and the recorder all
pass frames around as ``RawFrame``. It needs neither cantools nor python-can, so replay
can read raw-frame records without either.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from acquisition.stream import SourceError

# the payload lengths a CAN (FD) frame can have; the index is the DLC code
DLC_SIZES = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


class RawFrame(NamedTuple):
    """One CAN frame as received (or logged); the record raw-frame logs store.

    ``timestamp_ns`` is the receive time (host clock or log time, integer ns); it
    only helps to unwrap short counters: samples are placed by their counters.
    """

    timestamp_ns: int
    arbitration_id: int
    is_extended_id: bool
    data: bytes
    is_fd: bool = True


# -- a raw frame log record (symmetric pack / unpack) --------------------------------------------

_HEADER = np.dtype([("t", "<i8"), ("id", "<u4"), ("flags", "u1"), ("len", "u1")])


def pack_frames(frames: Sequence[RawFrame]) -> bytes:
    """Frames as one binary record: per frame ``<i8 t_ns, <u4 id, u1 flags, u1 len, data``.

    ``flags`` bit 0: extended id, bit 1: CAN FD. :func:`unpack_frames` inverts it.
    """
    out = bytearray()
    for f in frames:
        flags = (1 if f.is_extended_id else 0) | (2 if f.is_fd else 0)
        out += np.array((f.timestamp_ns, f.arbitration_id, flags, len(f.data)), _HEADER).tobytes()
        out += f.data
    return bytes(out)


def unpack_frames(buf: bytes) -> list[RawFrame]:
    """The frames of a :func:`pack_frames` record."""
    frames = []
    pos = 0
    size = _HEADER.itemsize
    while pos < len(buf):
        if pos + size > len(buf):
            raise SourceError(f"raw CAN record: truncated frame header at byte {pos} of {len(buf)}")
        h = np.frombuffer(buf, _HEADER, count=1, offset=pos)[0]
        end = pos + size + int(h["len"])
        if end > len(buf):
            raise SourceError(
                f"raw CAN record: frame at byte {pos} needs {end - pos} bytes, has {len(buf) - pos}"
            )
        flags = int(h["flags"])
        frames.append(
            RawFrame(
                int(h["t"]),
                int(h["id"]),
                bool(flags & 1),
                bytes(buf[pos + size : end]),
                bool(flags & 2),
            )
        )
        pos = end
    return frames
