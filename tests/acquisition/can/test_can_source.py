"""CAN decoding: the stream of the simulated source comes back out of its frames.

One body (:func:`check_same_stream`) runs over every path the frames can take:
decoded directly, through python-can's in-process virtual bus, through raw-frame
records (``test_can_logs.py`` adds the log formats). The reference is the
simulated source itself: the same layout, every sample at its grid index within
half a DBC step, every tacho edge within half a tick.
"""

from __future__ import annotations

import can
import numpy as np
import pytest
from support.can_streams import (
    DBC,
    SIM,
    assemble,
    can_bench_file,
    check_same_stream,
    quantum,
    sim_frames,
    simulated,
)

from acquisition.can.bus import CanBusSource
from acquisition.can.decoder import FrameDecoder, decode_frames
from acquisition.can.faults import FaultInjector, FaultRates
from acquisition.can.fields import as_rows, read_fields
from acquisition.can.frames import RawFrame, pack_frames, unpack_frames
from acquisition.can.reorder import DecoderOptions
from acquisition.can.source import CanFrameSource, open_can
from acquisition.stream import SourceError
from ptinertia.commands.can_sim import simulate_to_bus
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source, simulated_bench
from ptinertia.to_acquisition import channel_needs
from ptinertia.to_can import can_plan, can_settings

# -- one body over every path --------------------------------------------------------------------


def test_decoded_frames_carry_the_simulated_stream(plan, reference, clean_frames):
    items, stats = decode_frames(plan, clean_frames)
    check_same_stream(plan, *reference, items)
    assert stats.total("lost") == 0 and stats.malformed == 0
    assert stats.frames_in == len(clean_frames)


def test_virtual_bus_carries_the_simulated_stream(i3, plan, reference):
    channel = "ptinertia-test-virtual"
    with CanBusSource(plan, interface="virtual", channel=channel, idle_timeout_s=5.0) as src:
        tx = can.Bus(interface="virtual", channel=channel)
        try:
            simulate_to_bus(i3, plan, bus=tx, pace=False, sim_overrides=SIM)
        finally:
            tx.shutdown()
        items = list(src)
    check_same_stream(plan, *reference, items)
    assert items[-1].kind == "can_stats" and src.stats.total("lost") == 0


def test_raw_frame_records_replay_the_stream(plan, reference, clean_frames):
    # what a recording stores: packed batches of raw frames, decoded again on replay
    records = [pack_frames(clean_frames[i : i + 700]) for i in range(0, len(clean_frames), 700)]
    with CanFrameSource(plan, (unpack_frames(r) for r in records)) as src:
        check_same_stream(plan, *reference, list(src))


@pytest.mark.parametrize("bench_file", ["i4-bench.toml"])
@pytest.mark.parametrize("reference_kind", ["pressure", "cam"])
def test_pressure_and_cam_channels(bench_file, reference_kind):
    bench = simulated_bench(
        load_bench(EXAMPLES_DIR / bench_file), tacho={"phase_reference": reference_kind}
    )
    plan = can_plan(bench, DBC)
    sim = simulated(bench, duration_s=1.0)
    frames, _ = sim_frames(bench, plan, duration_s=1.0)
    check_same_stream(plan, *sim, decode_frames(plan, frames)[0])


def test_frames_the_bench_does_not_need_are_ignored_not_unknown(i3):
    # a DAQ sending pressure too, a bench that uses no pressure: those frames are known, unused
    with_p = simulated_bench(i3, tacho={"phase_reference": "pressure"})
    frames, _ = sim_frames(with_p, can_plan(with_p, DBC), duration_s=1.0)
    plan = can_plan(i3, DBC)
    items, stats = decode_frames(plan, [*frames, RawFrame(0, 0x555, False, bytes(8), False)])
    n_pressure = sum(1 for f in frames if f.arbitration_id == 0x110)
    assert n_pressure > 100 and stats.ignored == n_pressure
    assert stats.unknown_ids == {0x555: 1}
    check_same_stream(plan, *simulated(i3, duration_s=1.0), items)


# -- batching never changes the result -----------------------------------------------------------


def test_any_split_into_batches_gives_the_same_items(plan, clean_frames):
    rng = np.random.default_rng(11)
    frames = clean_frames[:2500]
    # spoil a few frames so that losses, duplicates and reordering are part of the check
    frames = frames[:300] + frames[301:900] + frames[905:1500] + frames[1400:1410] + frames[1500:]
    frames[2000], frames[2003] = frames[2003], frames[2000]
    one, stats_one = decode_frames(plan, frames)
    for trial in range(3):
        dec = FrameDecoder(plan)
        items = []
        i = 0
        while i < len(frames):
            n = 1 if trial == 0 else int(rng.integers(1, 400))
            items += dec.feed(frames[i : i + n])
            i += n
        items += dec.finish()
        a, b = assemble(one, plan.layout), assemble(items, plan.layout)
        for name in a[0]:
            assert np.array_equal(a[0][name], b[0][name], equal_nan=True)
        for ch in a[1]:
            assert np.array_equal(a[1][ch], b[1][ch])
        assert dec.stats.as_dict() == stats_one.as_dict()
    assert stats_one.total("lost") > 0 and stats_one.total("duplicate") == 10


# -- faults: every loss counted, nothing misplaced -----------------------------------------------


def _frame_samples(plan, frames):
    """Per sample message: frame number -> data, for the unspoiled frames."""
    out = {}
    for m in plan.messages:
        mine = [f for f in frames if (f.arbitration_id, f.is_extended_id) == m.key]
        if mine and m.counter is not None:
            seq = read_fields(as_rows([f.data for f in mine], m.length), [m.counter])[:, 0]
            out[m.name] = dict(zip(seq.tolist(), mine, strict=True))
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_faults_are_counted_exactly_and_nothing_is_misplaced(
    i3, plan, reference, clean_frames, seed
):
    rates = FaultRates(drop=0.01, duplicate=0.005, reorder=0.005, corrupt=0.005)
    injector = FaultInjector(rates, plan, seed)
    frames, _ = sim_frames(i3, plan, faults=injector)
    log = injector.log
    items, stats = decode_frames(plan, frames)
    sim_layout, sim_items = reference
    ref_g, ref_e, _ = assemble(sim_items, sim_layout)
    got_g, got_e, events = assemble(items, plan.layout)
    assert (
        sum(log.dropped.values()) > 10 and sum(sum(c.values()) for c in log.corrupted.values()) > 5
    )
    clean = _frame_samples(plan, clean_frames)
    for m in plan.messages:
        st = stats.streams[m.name]
        spoiled = log.spoiled.get(m.name, set())
        corrupted = log.corrupted.get(m.name, {})
        if m.kind == "status":
            continue
        if m.kind == "samples":
            # the stop frame dates the end: even losses at the tail are counted
            assert st.lost == len(spoiled), m.name
            rows = list(m.rows)
            got = got_g[m.group][rows]
            ref = ref_g[m.group][rows]
            missing = np.zeros(ref.shape[1], dtype=bool)
            for n in spoiled:
                missing[n * m.samples_per_frame : (n + 1) * m.samples_per_frame] = True
            # samples of lost frames are NaN (or left out); every other sample is where it belongs
            assert np.all(np.isnan(got[:, missing[: got.shape[1]]]))
            kept = ~missing
            kept[got.shape[1] :] = False
            assert got.shape[1] >= np.flatnonzero(~missing).max() + 1
            assert np.abs(got[:, kept] - ref[:, kept]).max() <= quantum(plan, m.group) * (1 + 1e-9)
        else:
            # an edge frame lost after the last one received leaves no trace: only those go uncounted
            last = max(set(clean[m.name]) - spoiled)
            assert st.lost == len([n for n in spoiled if n < last]), m.name
            kept_frames = [clean[m.name][n] for n in sorted(clean[m.name]) if n not in spoiled]
            expected = assemble(decode_frames(plan, kept_frames)[0], plan.layout)[1][m.group]
            assert np.array_equal(got_e[m.group], expected)
            # ... and each of them is a true edge time (within half a tick)
            ref = ref_e[m.group]
            j = np.clip(np.searchsorted(ref, expected), 1, ref.size - 1)
            nearest = np.minimum(np.abs(ref[j] - expected), np.abs(ref[j - 1] - expected))
            assert nearest.max() <= m.tick_s / 2 + 1e-12
        assert st.duplicate == log.duplicated[m.name], m.name
        assert st.bad_length == corrupted.get("length", 0), m.name
        assert st.bad_crc == corrupted.get("crc", 0), m.name
        assert st.bad_counter == corrupted.get("counter", 0), m.name
        assert st.late == 0 and st.out_of_order <= log.reordered[m.name] + log.duplicated[m.name]
    assert sum(stats.unknown_ids.values()) == sum(c.get("id", 0) for c in log.corrupted.values())
    # and every lost frame is in a gap event
    gaps = [e for e in events if e.kind == "gap"]
    assert sum(e.count for e in gaps) == stats.total("lost")


# -- counters --------------------------------------------------------------------------------------


def test_short_counters_unwrap_with_the_receive_clock(tmp_path, i3):
    # an 8-bit ECU counter wraps every 2.56 s; drop 3 s of ECU frames: only the receive time
    # (the frames' DAQ-time stamps here) tells how many wraps went by
    text = DBC.read_text().replace(
        " SG_ AliveCounter : 0|16@1+ (1,0) [0|65535]", " SG_ AliveCounter : 0|8@1+ (1,0) [0|255]"
    )
    (tmp_path / "c8.dbc").write_text(text)
    plan = can_plan(i3, tmp_path / "c8.dbc")
    frames, _ = sim_frames(i3, plan, duration_s=8.0)
    ecu = plan.by_key()[(0xC0, False)]
    seq = iter(range(10**9))
    kept = [f for f in frames if f.arbitration_id != 0xC0 or not 300 <= next(seq) < 600]
    items, stats = decode_frames(plan, kept)
    got = assemble(items, plan.layout)[0]["rpm"][0]
    ref = assemble(simulated(i3, duration_s=8.0)[1], plan.layout)[0]["rpm"][0]
    assert stats.streams[ecu.name].lost == 300 and stats.streams[ecu.name].bad_counter == 0
    assert np.all(np.isnan(got[300:600]))
    keep = np.r_[0:300, 600:800]
    assert np.abs(got[keep] - ref[keep]).max() <= 0.125


def test_a_receiver_joining_late_places_samples_by_counter(plan, reference, clean_frames):
    # start listening 1.2 s into the run: the DAQ frames' 32-bit counters are absolute, the
    # ECU's 16-bit one is anchored by the DAQ clock
    t_join = clean_frames[0].timestamp_ns + 1_200_000_000
    items, stats = decode_frames(plan, [f for f in clean_frames if f.timestamp_ns >= t_join])
    ref_g, ref_e, _ = assemble(reference[1], reference[0])
    got_g, got_e, _ = assemble(items, plan.layout)
    for name, ref in ref_g.items():
        got = got_g[name]
        have = ~np.isnan(got[0])
        first = int(np.flatnonzero(have)[0])
        assert abs(first / 5120 - 1.2) < 0.01 if name == "accel" else abs(first / 100 - 1.2) < 0.02
        assert np.all(have[first:])
        assert np.abs(got[:, first:] - ref[:, first : got.shape[1]]).max() <= quantum(
            plan, name
        ) * (1 + 1e-9)
    assert stats.total("lost") == 0
    assert np.abs(got_e["tacho"] - ref_e["tacho"][-got_e["tacho"].size :]).max() < 1e-9


def test_bad_counter_at_the_start_does_not_anchor_the_stream(plan, clean_frames):
    frames = list(clean_frames)
    first_acc = next(i for i, f in enumerate(frames) if f.arbitration_id == 0x100)
    m = plan.by_key()[(0x100, False)]
    data = bytearray(frames[first_acc].data)
    data[0:4] = (2**31).to_bytes(4, "little")
    from acquisition.can.fields import frame_crc

    data[4:6] = frame_crc(bytes(data), m.crc).to_bytes(2, "little")
    frames[first_acc] = frames[first_acc]._replace(data=bytes(data))
    items, stats = decode_frames(plan, frames)
    assert stats.streams[m.name].bad_counter == 1 and stats.streams[m.name].lost == 1
    got = assemble(items, plan.layout)[0]["accel"]
    assert np.all(np.isnan(got[0:3, 0:9])) and not np.isnan(got[0:3, 9:]).any()


def _open_can(arg, bench, **overrides):
    return open_can(arg, can_settings(bench.can), channel_needs(bench), **overrides)


def test_open_can_bad_input(i3, tmp_path):
    bench = load_bench(can_bench_file(tmp_path))
    with pytest.raises(
        SourceError, match=r"unknown CAN interface 'nosuchbus'; python-can knows: .*virtual"
    ):
        _open_can("nosuchbus:0", bench)
    with pytest.raises(SourceError, match="no DBC"):
        _open_can(
            "virtual:x", i3.model_copy(update={"can": i3.can.model_copy(update={"dbc": None})})
        )
    with pytest.raises(SourceError, match="unknown option 'bogus'"):
        _open_can("virtual:x", bench, bogus=1)
    with pytest.raises(SourceError, match="CAN FD frame but the bus is classic"):
        _open_can("virtual:x", bench, fd=False)


def test_open_source_can_spec_uses_the_bench_defaults(tmp_path):
    bench = load_bench(can_bench_file(tmp_path))
    with open_source("can:", bench, idle_timeout_s=0.2) as src:
        assert (
            src.layout.metadata["interface"] == "virtual"
            and src.layout.metadata["channel"] == "ptinertia"
        )
    with open_source("can:virtual:other", bench) as src:
        assert src.layout.metadata["channel"] == "other"


def test_decoder_options_window_is_respected(plan, clean_frames):
    # a frame held back by more than the window is late: counted lost and late, never placed
    frames = list(clean_frames)
    i = next(i for i, f in enumerate(frames) if f.arbitration_id == 0x101)
    held = frames.pop(i)
    frames.insert(i + 400, held)  # ~0.12 s of frames later
    _, stats = decode_frames(plan, frames, DecoderOptions(reorder_window_s=0.05))
    assert stats.streams["DAQ_AccB"].late == 1 and stats.streams["DAQ_AccB"].lost == 1
    _, stats = decode_frames(plan, frames, DecoderOptions(reorder_window_s=0.3))
    assert stats.streams["DAQ_AccB"].late == 0 and stats.streams["DAQ_AccB"].out_of_order == 1
