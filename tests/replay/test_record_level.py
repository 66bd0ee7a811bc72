"""The recorder's zstd level is a setting: any level reads back the same messages."""

from __future__ import annotations

import io

import pytest
import zstandard
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from support.mcap_writer_calls import drive

from replay.errors import LogError
from replay.mcapwriter import ThreadedWriter
from replay.recorder import McapRecorder


def _written(level: int) -> bytes:
    out = io.BytesIO()
    drive(ThreadedWriter(out, chunk_size=50_000, level=level), seed=2)
    return out.getvalue()


def _messages(data: bytes) -> list[tuple[int, int, bytes]]:
    reader = make_reader(io.BytesIO(data))
    return [(c.id, m.log_time, m.data) for _, c, m in reader.iter_messages(log_time_order=False)]


def _chunk_levels_differ(fast: bytes, strong: bytes) -> bool:
    """The chunks hold the same payload, compressed differently."""
    chunks = [
        [r for r in StreamReader(io.BytesIO(d), emit_chunks=True).records if isinstance(r, Chunk)]
        for d in (fast, strong)
    ]
    plain = [[zstandard.ZstdDecompressor().decompress(c.data) for c in cs] for cs in chunks]
    return plain[0] == plain[1] and [c.data for c in chunks[0]] != [c.data for c in chunks[1]]


def test_levels_give_the_same_messages_in_chunks_compressed_their_own_way():
    fast, strong = _written(-1), _written(3)
    assert _messages(fast) == _messages(strong)
    assert len(_messages(fast)) == 2000
    assert _chunk_levels_differ(fast, strong)
    assert _written(3) == strong  # a level is deterministic


@pytest.mark.parametrize("level", [23, -51, 1.5, True])
def test_a_level_zstd_does_not_have_is_refused_by_name(tmp_path, level):
    with pytest.raises(LogError, match="zstd level"):
        McapRecorder(tmp_path / "x.mcap", level=level)
    with pytest.raises(ValueError, match="zstd level"):
        ThreadedWriter(io.BytesIO(), level=level)
