"""A finished recording's summary read from its bytes (``replay.summary``) as the mcap reader reads it."""

from __future__ import annotations

import io

import pytest
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.writer import CompressionType, Writer
from support.clean_run import CleanRun
from support.mcap_writer_calls import drive

from replay.integrity import check_summary_crc
from replay.summary import read_metadata, read_summary


def mcap_writers_file(seed: int) -> bytes:
    out = io.BytesIO()
    drive(Writer(out, chunk_size=20_000, compression=CompressionType.ZSTD), seed)
    return out.getvalue()


@pytest.mark.parametrize("source", ["ours", "mcap writer 0", "mcap writer 1"])
def test_the_summary_reads_as_the_mcap_reader_reads_it(clean_run: CleanRun, source: str) -> None:
    data = clean_run.data if source == "ours" else mcap_writers_file(int(source[-1]))
    fh = io.BytesIO(data)
    start, section, _ = check_summary_crc(fh)
    ours = read_summary(section)
    theirs = SeekingReader(io.BytesIO(data)).get_summary()
    assert theirs is not None and start > 0
    assert ours.schemas == theirs.schemas and ours.channels == theirs.channels
    assert ours.statistics == theirs.statistics and ours.statistics is not None
    assert ours.metadata_indexes == theirs.metadata_indexes
    assert ours.attachment_indexes == theirs.attachment_indexes
    assert len(ours.chunk_indexes) == len(theirs.chunk_indexes) > 1
    for span, index in zip(ours.chunk_indexes, theirs.chunk_indexes, strict=True):
        assert (
            span.message_start_time,
            span.message_end_time,
            span.chunk_start_offset,
            span.chunk_length,
            span.message_index_length,
        ) == (
            index.message_start_time,
            index.message_end_time,
            index.chunk_start_offset,
            index.chunk_length,
            index.message_index_length,
        )
    metadata = [read_metadata(fh, index) for index in ours.metadata_indexes]
    assert metadata == list(SeekingReader(io.BytesIO(data)).iter_metadata()) != []


def test_a_summary_record_cut_by_the_footer_or_a_wrong_metadata_index_is_refused(
    clean_run: CleanRun,
) -> None:
    fh = io.BytesIO(clean_run.data)
    _, section, _ = check_summary_crc(fh)
    with pytest.raises(McapError, match="runs past the footer"):
        read_summary(section[:-3])
    with pytest.raises(McapError, match="inside a record header"):
        read_summary(section + b"\x08\x00")
    index = read_summary(section).metadata_indexes[0]
    wrong = type(index)(offset=index.offset + 1, length=index.length, name=index.name)
    with pytest.raises(McapError, match="expected a metadata record"):
        read_metadata(fh, wrong)
    # a damaged length in the record's header (outside the summary's CRC) is not read
    data = bytearray(clean_run.data)
    data[index.offset + 5] ^= 0x08  # its length + 2**35 bytes
    with pytest.raises(McapError, match="its index says"):
        read_metadata(io.BytesIO(bytes(data)), index)
