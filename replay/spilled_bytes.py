"""Bytes appended during a recording and read once at its end, kept on disk meanwhile.

The writer's chunk index records (:class:`replay.mcap_output.McapOutput`) are only read
when the summary is written: as objects they held 1.4 KB a chunk (10 MB per hour of
0.5 s chunks), as bytes in memory 0.2 KB (1.4 MB an hour, grown by reallocation);
:class:`SpilledBytes` keeps them in an unnamed temporary file instead, so a recording's
memory does not grow with its length, and falls back to memory when the temporary
directory cannot take them.
"""

from __future__ import annotations

import tempfile
from typing import IO


class SpilledBytes:
    """Bytes appended during a recording and read once at its end, held in an unnamed
    temporary file (``tempfile.TemporaryFile``: not linked, gone when closed), so that a
    recording's memory does not grow with its length. If the temporary directory
    cannot take them (full, read-only) they move to memory instead: nothing is lost."""

    def __init__(self) -> None:
        self._memory: bytearray | None = None
        self._file: IO[bytes] | None = None
        self._size = 0  # bytes appended to the file in full
        try:
            # unbuffered: an append that fails leaves nothing pending in a buffer
            self._file = tempfile.TemporaryFile(prefix="ptinertia-index-", buffering=0)
        except OSError:
            self._memory = bytearray()

    def append(self, data: bytes) -> None:
        if self._file is not None:
            try:
                view = memoryview(data)
                while view:
                    view = view[self._file.write(view) or 0 :]
                self._size += len(data)
                return
            except OSError:
                self._to_memory()  # what was written in full; this append follows
        assert self._memory is not None
        self._memory += data

    def getvalue(self) -> bytes:
        """Everything appended so far."""
        self._to_memory()
        assert self._memory is not None
        return bytes(self._memory)

    def _to_memory(self) -> None:
        if self._file is None:
            return
        f, self._file = self._file, None
        try:
            # the appends made in full (a failed one may have left part of itself after them)
            f.seek(0)
            self._memory = bytearray()
            while len(self._memory) < self._size:
                got = f.read(self._size - len(self._memory))  # raw reads may return less
                if not got:
                    raise OSError(
                        f"temporary index file: {len(self._memory)} of {self._size} bytes read back"
                    )
                self._memory += got
        finally:
            f.close()

    def close(self) -> None:
        """Let go of the bytes (the temporary file, or the memory)."""
        if self._file is not None:
            self._file.close()
        self._file, self._memory, self._size = None, bytearray(), 0
