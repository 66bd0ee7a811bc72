"""The chunk index records of a recording wait in a temporary file until the summary
(replay.spilled_bytes.SpilledBytes): the same bytes come back, and a temporary directory
that fills up mid-recording loses none of them."""

from __future__ import annotations

import errno
import io

import pytest

from replay import spilled_bytes
from replay.spilled_bytes import SpilledBytes


def _records(n: int) -> list[bytes]:
    return [bytes([i % 251]) * (37 + i % 13) for i in range(n)]


def test_appended_bytes_come_back_in_order() -> None:
    spill = SpilledBytes()
    records = _records(500)
    for r in records:
        spill.append(r)
    assert spill.getvalue() == b"".join(records)
    spill.append(b"after")  # still usable once read back
    assert spill.getvalue() == b"".join(records) + b"after"
    spill.close()


class _FillingFile(io.FileIO):
    """A real unbuffered temporary file on a disk that is full after ``budget`` bytes:
    the write that crosses it takes what fits, the next raises ENOSPC."""

    def __init__(self, path: str, budget: int) -> None:
        super().__init__(path, "w+b")
        self.budget = budget

    def write(self, data) -> int:  # type: ignore[override]
        if self.budget <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = super().write(bytes(data)[: self.budget]) or 0
        self.budget -= n
        return n


@pytest.mark.parametrize("budget", [0, 1, 100, 1000])
def test_a_full_temporary_directory_loses_nothing(tmp_path, monkeypatch, budget: int) -> None:
    made: list[_FillingFile] = []

    def temporary_file(**_kw) -> _FillingFile:
        made.append(_FillingFile(str(tmp_path / f"spill{len(made)}"), budget))
        return made[-1]

    monkeypatch.setattr(spilled_bytes.tempfile, "TemporaryFile", temporary_file)
    spill = SpilledBytes()
    records = _records(60)
    for r in records:
        spill.append(r)
    assert spill.getvalue() == b"".join(records)
    assert made and made[0].closed  # the file let go once its bytes moved to memory


def test_no_temporary_directory_at_all(monkeypatch) -> None:
    def refuse(**_kw):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(spilled_bytes.tempfile, "TemporaryFile", refuse)
    spill = SpilledBytes()
    for r in _records(20):
        spill.append(r)
    assert spill.getvalue() == b"".join(_records(20))


def test_the_temporary_file_is_not_linked_anywhere() -> None:
    spill = SpilledBytes()
    spill.append(b"x")
    assert spill._file is not None
    name = spill._file.name
    # tempfile.TemporaryFile is unnamed (O_TMPFILE or unlinked at once): its name is the fd
    assert isinstance(name, int), name
    spill.close()


def test_a_writer_stopped_without_its_summary_lets_the_temporary_file_go() -> None:
    """After a failed chunk write (or a failed start) the summary never comes: stop()
    closes the temporary file (it stayed open, a deleted file and its descriptor)."""
    from replay.mcapwriter import ThreadedWriter

    writer = ThreadedWriter(io.BytesIO())
    spill = writer._out.chunk_index_records
    assert spill._file is not None
    writer.stop()
    assert spill._file is None
