"""Cut-short and bad recordings: what is recovered, and the one-line errors.

The SIGKILL test kills a real recording process (a paced synthetic source)
and checks that the file's readable part reaches within 1 s of the kill and
equals an un-killed recording of the same stream over the same span.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from mcap.writer import Writer
from support.mcap_logs import (
    BENCH_TEXT,
    assert_same_items,
    record,
    synthetic_items,
    synthetic_layout,
)

from acquisition.stream import SampleBlock, SourceError, StreamItem
from ptinertia.errors import user_error_types
from replay import stream_codec
from replay.errors import LogError
from replay.raw_writer import record_source
from replay.reader import find_logs, open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo
from replay.schemas import FORMAT, META_RUN, SCHEMA_VERSION, full_name, schema_data, wire_class

ROOT = Path(__file__).resolve().parents[2]

PACED_RECORDER = textwrap.dedent(
    '''
    """Record a paced synthetic stream (0.1 s blocks) on a fake clock, then wait to be killed."""
    import sys

    import numpy as np

    from acquisition.stream import ChannelSpec, EdgeBlock, SampleBlock, SampleGroup, StreamLayout

    RATE, N_CH, BLOCK = 5120.0, 10, 512  # 0.1 s blocks
    ORIGIN_NS = 1_700_000_000_000_000_000


    def layout():
        acc = SampleGroup("acc", RATE, tuple(ChannelSpec(f"s{i}", "m/s^2") for i in range(N_CH)))
        return StreamLayout((acc,), ("tacho",))


    def items(n_blocks):
        for k in range(n_blocks):
            yield SampleBlock("acc", k * BLOCK, np.random.default_rng(k).standard_normal((N_CH, BLOCK)))
            yield EdgeBlock("tacho", k * 0.1 + np.arange(5) * 0.02)


    if __name__ == "__main__":
        from replay.recorder import McapRecorder
        from replay.recording_head import RecordingInfo

        now = [0.0]  # the recorder's monotonic clock: a paced source's, without sleeping
        rec = McapRecorder(sys.argv[1], time_origin_ns=ORIGIN_NS, monotonic=lambda: now[0])
        rec.start(RecordingInfo(layout=layout(), bench_text="[paced]\\n"))
        for k, item in enumerate(items(int(sys.argv[2]))):
            now[0] = (k // 2 + 1) * 0.1  # block k // 2 is released at its end time
            rec.on_item(item)
        # what a few ms of wall time do after a chunk is closed: the writer thread has
        # written it (the open chunk stays open, as at any moment of a live run)
        rec._writer.sync()
        print("recording", flush=True)
        sys.stdin.readline()  # until killed
        rec.close(None)
    '''
)


def load_script(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location("paced_recorder", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_sigkill_mid_run_loses_at_most_the_last_second(tmp_path: Path) -> None:
    script = tmp_path / "paced_recorder.py"
    script.write_text(PACED_RECORDER)
    out = tmp_path / "killed.mcap"
    n_blocks = 25  # killed at 2.5 s of stream, late in a 0.5 s chunk: near the worst case
    proc = subprocess.Popen(
        [sys.executable, str(script), str(out), str(n_blocks)],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "recording"
        # a file still being written opens too
        origin = open_log(out).time_origin_ns if out.stat().st_size else None
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=10)
        for pipe in (proc.stdin, proc.stdout):
            if pipe is not None:
                pipe.close()
    assert proc.returncode == -signal.SIGKILL

    log = open_log(out)
    assert not log.finished
    assert origin == log.time_origin_ns
    assert any("unfinished recording" in line for line in log.report.lines())
    got = list(log.items())
    blocks = [i for i in got if isinstance(i, SampleBlock)]
    recovered_until = (blocks[-1].first_index + blocks[-1].n_samples) / 5120.0
    killed_at = n_blocks * 0.1  # the stream time the paced source had reached
    assert killed_at > 2.0
    assert killed_at - recovered_until <= 1.0, (killed_at, recovered_until)

    # the same stream recorded without a kill, over the same span
    paced = load_script(script)
    full = tmp_path / "unkilled.mcap"
    record_source(paced.items(len(blocks) + 5), full, layout=paced.layout())
    reference = list(open_log(full).items())[: len(got)]
    assert_same_items(got, reference)
    assert_same_items(got, list(paced.items(len(blocks)))[: len(got)])


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, list[StreamItem]]:
    layout = synthetic_layout(n_ch=3, rate_hz=1024.0)
    items = synthetic_items(layout, 4.0, seed=7)
    path = tmp_path_factory.mktemp("small") / "small.mcap"
    record(path, items, layout, chunk_s=0.3)
    return path.read_bytes(), items


def test_every_cut_gives_a_prefix_or_one_line(
    tmp_path: Path, small_log: tuple[bytes, list[StreamItem]]
) -> None:
    data, items = small_log
    cuts = sorted(
        {*np.linspace(0, len(data), 60).astype(int).tolist(), len(data) - 1, len(data) - 30}
    )
    recovered = []
    for cut in cuts:
        path = tmp_path / f"cut{cut}.mcap"
        path.write_bytes(data[:cut])
        try:
            log = open_log(path)
        except LogError as err:
            assert "\n" not in str(err) and str(path) in str(err)
            recovered.append(0)
            continue
        got = list(log.items())
        assert_same_items(got, items[: len(got)])
        recovered.append(len(got))
        # the fast walk and the mcap library's own readers see the same messages
        topics = list(log.topics)
        assert list(log.messages(topics)) == list(log.messages(topics, reference=True))
    assert recovered == sorted(recovered)  # more file, never less data
    assert recovered[0] == 0 and recovered[-2] == len(items)  # cut in the summary: nothing lost
    assert 0 < recovered[len(cuts) // 2] < len(items)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"", "empty file"),
        (b"time,a,b\n0,1,2\n", "not an MCAP file"),
        (b"\x89MCAP0\r\n", "truncated before any data"),
        (b"\x89MCA", "truncated before any data"),
    ],
)
def test_bad_files_give_one_line(tmp_path: Path, content: bytes, expected: str) -> None:
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(LogError, match=expected) as info:
        open_log(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_killed_before_the_first_chunk(tmp_path: Path) -> None:
    path = tmp_path / "early.mcap"
    rec = McapRecorder(path)
    rec.start(RecordingInfo(layout=synthetic_layout(), bench_text=BENCH_TEXT))
    rec.on_item(SampleBlock("acc", 0, np.zeros((4, 10))))  # still in the open chunk
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(path.read_bytes())  # what a SIGKILL now would leave
    rec.close(None)
    with pytest.raises(LogError, match="truncated before any data"):
        open_log(copy)
    assert len(list(open_log(path).items())) == 1


def test_missing_file_and_directories(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="no such file"):
        open_log(tmp_path / "nope.mcap")
    with pytest.raises(LogError, match="is a directory"):
        open_log(tmp_path)
    with pytest.raises(LogError, match=r"no \.mcap files"):
        find_logs(tmp_path)
    layout = synthetic_layout()
    for name in ("b.mcap", "a.mcap"):
        record_source(synthetic_items(layout, 0.2), tmp_path / name, layout=layout)
    (tmp_path / "notes.txt").write_text("x")
    assert find_logs(tmp_path) == [tmp_path / "a.mcap", tmp_path / "b.mcap"]


class Handmade:
    """An MCAP written with the mcap library alone; ``topics`` maps topic -> our message type or ``json``."""

    def __init__(self, path: Path, topics: dict[str, str], metadata: dict[str, str] | None) -> None:
        self.fh = open(path, "wb")  # closed in finish()
        self.writer = Writer(self.fh)
        self.writer.start()
        if metadata is not None:
            self.writer.add_metadata(META_RUN, metadata)
        self.ids: dict[str, int] = {}
        for topic, kind in topics.items():
            if kind == "json":
                sid = self.writer.register_schema("foo", "jsonschema", b"{}")
                self.ids[topic] = self.writer.register_channel(topic, "json", sid)
            else:
                sid = self.writer.register_schema(full_name(kind), "protobuf", schema_data())
                self.ids[topic] = self.writer.register_channel(topic, "protobuf", sid)

    def add(self, topic: str, t: int, data: bytes) -> None:
        self.writer.add_message(self.ids[topic], t, data, t)

    def finish(self) -> None:
        self.writer.finish()
        self.fh.close()


def _run_metadata(layout_json: str) -> dict[str, str]:
    return {
        "format": FORMAT,
        "schema_version": str(SCHEMA_VERSION),
        "layout": layout_json,
        "truth": "null",
        "settings": "{}",
        "time_origin_ns": "0",
    }


def test_foreign_mcap_is_not_a_recording(tmp_path: Path) -> None:
    path = tmp_path / "foreign.mcap"
    mcap = Handmade(path, {"/camera": "json"}, None)
    mcap.add("/camera", 1, b"{}")
    mcap.finish()
    with pytest.raises(LogError, match="not a ptinertia recording") as info:
        open_log(path)
    assert "\n" not in str(info.value)


def test_missing_raw_topic_is_an_error(tmp_path: Path) -> None:
    layout = synthetic_layout()
    path = tmp_path / "missing.mcap"
    mcap = Handmade(
        path,
        {"/raw/acc": "SampleBlock", "/raw/edges/tacho": "EdgeBlock", "/events": "SourceEvent"},
        _run_metadata(stream_codec.layout_to_json(layout)),
    )
    block = SampleBlock("acc", 0, np.zeros((4, 3)))
    mcap.add("/raw/acc", 1, stream_codec.encode_samples(block, layout.groups[0]))
    mcap.finish()
    with pytest.raises(LogError, match=r"missing /raw/slow") as info:
        open_log(path)
    assert "\n" not in str(info.value)


def test_unknown_topics_and_bad_messages_are_skipped_and_reported(tmp_path: Path) -> None:
    layout = synthetic_layout(n_ch=2)
    acc = layout.groups[0]
    path = tmp_path / "mixed.mcap"
    topics = {
        "/raw/acc": "SampleBlock",
        "/raw/slow": "SampleBlock",
        "/raw/edges/tacho": "EdgeBlock",
        "/events": "SourceEvent",
        "/camera": "json",
        "/estimate": "OrderFrame",  # right topic, wrong schema
    }
    mcap = Handmade(path, topics, _run_metadata(stream_codec.layout_to_json(layout)))
    good = [SampleBlock("acc", 0, np.ones((2, 5))), SampleBlock("acc", 5, 2 * np.ones((2, 5)))]
    bad = wire_class("SampleBlock")(group="acc", channels=["s0", "s1"], n_samples=9, data=b"\0" * 8)
    mcap.add("/raw/acc", 1, stream_codec.encode_samples(good[0], acc))
    mcap.add("/camera", 2, b"{}")
    mcap.add("/raw/acc", 3, bad.SerializeToString())
    mcap.add("/estimate", 3, b"")
    mcap.add("/raw/acc", 4, stream_codec.encode_samples(good[1], acc))
    mcap.finish()
    log = open_log(path)
    assert_same_items(list(log.items()), good)
    assert list(log.estimates()) == []
    lines = log.report.lines()
    assert any("unknown topic /camera" in line for line in lines)
    assert any("/estimate has schema" in line for line in lines)
    assert any("skipped 1 message(s) on /raw/acc" in line for line in lines)
    assert any("8 data bytes, expected 72" in line for line in lines)
    assert all("\n" not in line for line in lines)


def test_bench_that_no_longer_matches_the_channels(tmp_path: Path) -> None:
    from ptinertia.config import load_bench
    from ptinertia.to_acquisition import channel_needs
    from replay.source import open_replay

    layout = synthetic_layout()
    path = tmp_path / "synthetic.mcap"
    record_source(synthetic_items(layout, 0.2), path, layout=layout)
    bench = load_bench(ROOT / "examples" / "i3-bench.toml")
    with pytest.raises(SourceError, match="not found") as info:
        open_replay(path, channel_needs(bench))
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_log_errors_are_user_errors() -> None:
    """The CLI turns them into one line and exit code 2."""
    assert issubclass(LogError, user_error_types())
    assert issubclass(LogError, ValueError)
