"""CAN log files written from the simulated DAQ replay to the simulated stream (same body as the bus)."""

from __future__ import annotations

import can
import numpy as np
import pytest
from support.can_streams import (
    DBC,
    assemble,
    can_bench_file,
    check_same_stream,
    sim_frames,
    simulated,
)

from acquisition.can.bus import frame_to_message
from acquisition.can.decoder import decode_frames
from acquisition.can.logs import FrameLogWriter, is_can_log, read_frames, write_can_log
from acquisition.stream import EdgeBlock, SampleBlock, SourceError, SourceEvent
from ptinertia.config import load_bench
from ptinertia.sources import open_source

FORMATS = ["blf", "asc", "trc", "log", "mf4"]


@pytest.fixture(scope="module")
def reference_2s(i3):
    """The simulated stream of the frames' 2 s (conftest.py's ``reference`` is longer)."""
    return simulated(i3, duration_s=2.0)


@pytest.fixture(scope="module")
def frames(i3, plan):
    return sim_frames(i3, plan, duration_s=2.0)[0]


@pytest.mark.parametrize("fmt", FORMATS)
def test_log_replays_the_simulated_stream(tmp_path, plan, reference_2s, frames, fmt):
    path = tmp_path / f"run.{fmt}"
    assert write_can_log(path, frames) == len(frames)
    back = [f for batch in read_frames(path, batch_frames=777) for f in batch]
    # the payloads, ids and FD flags survive every format; times only to the format's resolution
    assert [(f.arbitration_id, f.is_fd, f.data) for f in back] == [
        (f.arbitration_id, f.is_fd, f.data) for f in frames
    ]
    bench = load_bench(can_bench_file(tmp_path))
    with open_source(f"file:{path}", bench) as src:
        items = list(src)
    check_same_stream(plan, *reference_2s, items)
    assert items[-1].kind == "can_stats" and "0 lost" in items[-1].message


def test_a_log_decodes_again_with_a_corrected_dbc(tmp_path, i3, frames):
    # a DBC with the wrong factor for sensor B gives wrong values; the corrected one the right ones
    wrong = DBC.read_text().replace("B_x_s0 : 48|16@1- (0.01,0)", "B_x_s0 : 48|16@1- (0.02,0)")
    wrong = "\n".join(
        line.replace("(0.01,0)", "(0.02,0)") if " SG_ B_x_s" in line else line
        for line in wrong.splitlines()
    )
    (tmp_path / "wrong.dbc").write_text(wrong)
    path = tmp_path / "run.blf"
    write_can_log(path, frames)
    wrong_bench = load_bench(can_bench_file(tmp_path, dbc=tmp_path / "wrong.dbc"))
    with open_source(f"file:{path}", wrong_bench) as src:
        bad = assemble(list(src), src.layout)[0]["accel"]
    with open_source(f"file:{path}", wrong_bench, dbc=str(DBC)) as src:
        good = assemble(list(src), src.layout)[0]["accel"]
    assert np.allclose(bad[3], 2 * good[3]) and np.array_equal(bad[4:], good[4:])


def test_error_frames_in_a_log_are_counted(tmp_path, plan, frames):
    path = tmp_path / "err.blf"
    with can.Logger(str(path)) as log:
        for i, f in enumerate(frames[:500]):
            if i == 250:
                log.on_message_received(
                    can.Message(
                        timestamp=f.timestamp_ns * 1e-9, is_error_frame=True, arbitration_id=0x40
                    )
                )
            log.on_message_received(frame_to_message(f))
    from acquisition.can.logs import CanLogSource

    with CanLogSource(path, plan) as src:
        items = list(src)
    assert src.stats.bus_errors == 1 and src.stats.frames_in == 500
    assert isinstance(items[-1], SourceEvent) and "1 bus errors" in items[-1].message


def test_mf4_bus_logging_is_told_from_measurement_files(tmp_path, frames):
    path = tmp_path / "bus.mf4"
    write_can_log(path, frames[:50])
    assert is_can_log(path) and is_can_log(tmp_path / "x.blf")
    from asammdf import MDF, Signal

    meas = tmp_path / "meas.mf4"
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.arange(5.0), np.arange(5) / 10.0, name="A_x", unit="m/s^2")])
    mdf.save(meas, overwrite=True)
    assert not is_can_log(meas) and not is_can_log(tmp_path / "x.csv")


def test_unreadable_and_missing_logs(tmp_path, i3, frames):
    bench = load_bench(can_bench_file(tmp_path))
    with pytest.raises(SourceError, match="not found"):
        open_source(f"file:{tmp_path / 'missing.blf'}", bench)
    junk = tmp_path / "junk.blf"
    junk.write_bytes(b"this is not a BLF file" * 10)
    with pytest.raises(SourceError, match=r"junk\.blf"):
        with open_source(f"file:{junk}", bench) as src:
            list(src)
    write_can_log(tmp_path / "ok.blf", frames[:10])
    with pytest.raises(SourceError, match="no DBC"):
        open_source(
            f"file:{tmp_path / 'ok.blf'}",
            i3.model_copy(update={"can": i3.can.model_copy(update={"dbc": None})}),
        )
    with pytest.raises(SourceError, match=r"expected \.blf"):
        FrameLogWriter(tmp_path / "x.txt")


def test_same_frames_same_items_whatever_the_format(tmp_path, plan, frames):
    # decode(log(frames)) == decode(frames), item for item: the log's times never move a sample
    direct, _ = decode_frames(plan, frames)
    for fmt in ("asc", "trc"):
        path = tmp_path / f"r.{fmt}"
        write_can_log(path, frames)
        replayed, _ = decode_frames(plan, [f for b in read_frames(path) for f in b])
        a, b = assemble(direct, plan.layout), assemble(replayed, plan.layout)
        for g in a[0]:
            assert np.array_equal(a[0][g], b[0][g], equal_nan=True)
        assert np.array_equal(a[1]["tacho"], b[1]["tacho"])


@pytest.mark.parametrize("fmt", ["asc.gz", "log.gz"])
def test_compressed_logs_written_by_python_can_replay_the_stream(
    tmp_path, plan, reference_2s, frames, fmt
):
    path = tmp_path / f"run.{fmt}"
    with can.Logger(str(path)) as log:  # python-can's own compressed writer
        for f in frames:
            log.on_message_received(frame_to_message(f, channel=0))
    assert is_can_log(path)
    bench = load_bench(can_bench_file(tmp_path))
    with open_source(f"file:{path}", bench) as src:
        items = list(src)
    check_same_stream(plan, *reference_2s, items)


def test_a_gzipped_blf_replays_the_stream(tmp_path, plan, reference_2s, frames):
    # python-can writes no .blf.gz (its writer refuses) but reads one: gzip of a BLF it wrote
    import gzip

    blf = tmp_path / "run.blf"
    write_can_log(blf, frames)
    path = tmp_path / "run.blf.gz"
    path.write_bytes(gzip.compress(blf.read_bytes()))
    bench = load_bench(can_bench_file(tmp_path))
    with open_source(f"file:{path}", bench) as src:
        items = list(src)
    check_same_stream(plan, *reference_2s, items)


def test_a_log_of_another_bench_names_the_expected_messages_and_the_ids_it_holds(tmp_path, i3):
    path = tmp_path / "vendor.blf"
    with can.Logger(str(path)) as log:
        for i in range(30):
            for ident in (0x64, 0x3E8, 0x1F334455):
                log.on_message_received(
                    can.Message(
                        timestamp=1.0 + i * 0.01,
                        arbitration_id=ident,
                        is_extended_id=ident > 0x7FF,
                        data=bytes(8),
                    )
                )
    bench = load_bench(can_bench_file(tmp_path))
    with pytest.raises(SourceError) as err:
        with open_source(f"file:{path}", bench) as src:
            list(src)
    msg = str(err.value)
    assert "\n" not in msg and "vendor.blf" in msg and "none of its 90 frames" in msg
    assert "0x100 DAQ_AccA" in msg and "0x7F0 DAQ_Status" in msg
    assert "0x64 (30), 0x3E8 (30), 0x1F334455 extended (30)" in msg


def test_big_batches_interleave_samples_and_edges_in_data_time(plan, frames):
    # a log is read thousands of frames at a time: the items must still come in data time,
    # never samples seconds ahead of the edges that give them their crank angle
    items, _ = decode_frames(plan, frames)
    last_edge = -1.0
    for it in items:
        if isinstance(it, EdgeBlock):
            last_edge = float(it.times_s[-1])
        elif isinstance(it, SampleBlock):
            g = next(g for g in plan.layout.groups if g.name == it.group)
            t_end = (it.first_index + it.n_samples) / g.rate_hz
            assert t_end - max(last_edge, 0.0) <= 0.25, (it.group, t_end, last_edge)


def test_a_log_without_data_frames_says_so(tmp_path, i3):
    path = tmp_path / "remote.blf"
    with can.Logger(str(path)) as log:
        for i in range(2):
            log.on_message_received(
                can.Message(timestamp=1.0 + i, arbitration_id=0x100, is_remote_frame=True, dlc=8)
            )
    bench = load_bench(can_bench_file(tmp_path))
    with pytest.raises(SourceError, match=r"remote\.blf' holds no CAN data frames \(2 remote"):
        with open_source(f"file:{path}", bench) as src:
            list(src)
