"""Fuzz the MCAP reader and ``ptinertia replay``: truncation, bit flips, crafted records.

The property, for every mutated recording: the reader gives back the clean
stream, or a part of it with what was skipped reported (``recording_skipped``
in the result document), or refuses the file with one line (``LogError``,
exit 2; exit 1 "no estimate"); never a traceback, never an item or an estimate
silently different from the clean one. Sizes read from the file are bounded
(``replay.mcap_records.MAX_CHUNK_BYTES``, the file size), which is what keeps a
crafted record from hanging the reader; ``benchmarks/bench_bitflips.py``
measures the replay times.

Bounded for the suite: a few dozen reader examples and a handful of full
replays, a few seconds. A longer run by hand scales every test's examples::

    PTINERTIA_FUZZ_EXAMPLES=2000 .venv/bin/python -m pytest tests/replay/test_mcap_fuzz.py

(the figure is the reader tests' count; the replay tests run a tenth of it).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.opcode import Opcode
from support.clean_run import CleanRun
from support.mcap_logs import record, synthetic_items, synthetic_layout

from acquisition.stream import EdgeBlock, SampleBlock, SourceEvent, StreamItem
from ptinertia.cli import main
from replay.errors import LogError
from replay.mcap_records import chunk_payload, records
from replay.reader import open_log

EXAMPLES = int(os.environ.get("PTINERTIA_FUZZ_EXAMPLES", "40"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
REPLAYS = settings(FUZZ, max_examples=max(4, EXAMPLES // 10))


def item_key(item: StreamItem) -> tuple[Any, ...]:
    """Hashable identity of an item, down to the bits of its data."""
    if isinstance(item, SampleBlock):
        return ("s", item.group, item.first_index, item.data.astype(np.float64).tobytes())
    if isinstance(item, EdgeBlock):
        return ("e", item.channel, item.times_s.tobytes())
    return ("v", item.kind, item.message, item.time_s, item.count)


@dataclass(frozen=True)
class Clean:
    """A recording's bytes and the keys of its items as read back (short repr: hypothesis
    prints the arguments of a failing example)."""

    data: bytes = field(repr=False)
    keys: list[tuple[Any, ...]] = field(repr=False)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Clean:
    """A small recording (2 s in 0.25 s chunks) and its items."""
    path = tmp_path_factory.mktemp("fuzz") / "clean.mcap"
    layout = synthetic_layout(n_ch=2, rate_hz=1024.0)
    record(path, synthetic_items(layout, 2.0, seed=3), layout, chunk_s=0.25)
    return Clean(path.read_bytes(), [item_key(i) for i in open_log(path).items()])


def check_reader(path: Path, clean: list[tuple[Any, ...]]) -> None:
    """The reader's side of the property on one mutated file."""
    try:
        log = open_log(path)
        got = [item_key(i) for i in log.items()]
    except LogError as err:
        assert "\n" not in str(err) and str(err)
        return
    if got == clean:
        return
    # nothing misread: what came back is the clean stream with parts left out ...
    rest = iter(clean)
    assert all(any(key == c for c in rest) for key in got), "an item not in the clean stream"
    # ... and what was left out is said
    assert log.report.skipped_document(), "items lost without a word"


def mutate(data: bytes, flips: list[int], cut: int | None) -> bytes:
    out = bytearray(data)
    for bit in flips:
        out[(bit // 8) % len(out)] ^= 1 << (bit % 8)
    return bytes(out[:cut] if cut is not None else out)


@FUZZ
@given(
    flips=st.lists(st.integers(min_value=0), min_size=1, max_size=3),
    cut=st.none() | st.integers(min_value=0),
)
def test_bit_flips_and_cuts_never_misread(
    synthetic: Clean,
    tmp_path: Path,
    flips: list[int],
    cut: int | None,
) -> None:
    data, clean = synthetic.data, synthetic.keys
    path = tmp_path / "mutated.mcap"
    path.write_bytes(mutate(data, flips, None if cut is None else cut % len(data)))
    check_reader(path, clean)


@FUZZ
@given(
    which=st.integers(min_value=0),
    edits=st.lists(
        st.tuples(st.integers(0), st.binary(min_size=1, max_size=12)), min_size=1, max_size=4
    ),
)
def test_crafted_records_with_valid_crcs_are_refused_or_skipped(
    synthetic: Clean,
    tmp_path: Path,
    which: int,
    edits: list[tuple[int, bytes]],
) -> None:
    """Bytes overwritten inside a chunk's records, the chunk stored with a correct CRC, the
    file cut before its data end (so no other CRC sees it): only the reader's own checks on
    what the records say stand in the way."""
    data = synthetic.data
    clean_path = tmp_path / "clean.mcap"
    clean_path.write_bytes(data)
    spans = []
    with open(clean_path, "rb") as fh:
        for opcode, offset, length in records(fh):
            if opcode == Opcode.DATA_END:
                data_end = offset - 9
                break
            if opcode == Opcode.CHUNK:
                spans.append((offset, length))
    offset, length = spans[which % len(spans)]
    payload = bytearray(chunk_payload(data[offset : offset + length]))
    for at, junk in edits:
        at %= len(payload)
        payload[at : at + len(junk)] = junk[: len(payload) - at]
    start, end = struct.unpack_from("<QQ", data, offset)
    content = (
        struct.pack("<QQQI", start, end, len(payload), zlib.crc32(payload))
        + struct.pack("<I", 0)
        + struct.pack("<Q", len(payload))
        + bytes(payload)
    )
    out = bytearray(data[: offset - 8]) + struct.pack("<Q", len(content)) + content
    out += data[offset + length : data_end]
    path = tmp_path / "crafted.mcap"
    path.write_bytes(bytes(out))
    try:
        log = open_log(path)
        items = list(log.items())
        list(log.frames())
        list(log.estimates())
    except LogError as err:
        assert "\n" not in str(err)
        return
    assert all(isinstance(i, (SampleBlock, EdgeBlock, SourceEvent)) for i in items)


def replay_outcome(log: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> Any:
    out.unlink(missing_ok=True)
    capsys.readouterr()
    code = main(["replay", str(log), "--quiet", "--json", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, json.loads(out.read_text()) if out.exists() else None, err


@REPLAYS
@given(bit=st.integers(min_value=0), cut=st.none() | st.floats(0.0, 1.0))
def test_replay_of_a_damaged_recording_is_clean_or_says_what_it_skipped(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    bit: int,
    cut: float | None,
) -> None:
    data = clean_run.data
    cut_at = None if cut is None else int(cut * len(data))
    log = tmp_path / "damaged.mcap"
    log.write_bytes(mutate(data, [bit % (8 * len(data))], cut_at))
    code, doc, err = replay_outcome(log, tmp_path / "r.json", capsys)
    if code == 0:
        assert doc == clean_run.result or doc.get("recording_skipped"), "silently changed"
    elif code == 2:
        assert doc is None and len(err) == 1 and err[0].startswith("ptinertia replay: error: ")
    else:
        assert code == 1 and doc is None and "no estimate" in err[-1]
