"""The DBC conventions and the frame codec, checked against cantools and against hand counts."""

from __future__ import annotations

import binascii
import re

import cantools
import numpy as np
import pytest

from acquisition.can.bus_load import frame_time_s
from acquisition.can.dbc import load_dbc, plan_for_channels
from acquisition.can.encoder import encode_edge_frames, encode_sample_frames
from acquisition.can.fields import as_rows, frame_crc, raw_fields_slow, read_fields, scale_samples
from acquisition.can.frames import RawFrame, pack_frames, unpack_frames
from acquisition.can.plan import IntField
from acquisition.stream import SourceError
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source, simulated_bench
from ptinertia.to_acquisition import channel_needs
from ptinertia.to_can import can_plan

DBC = EXAMPLES_DIR / "bench.dbc"


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_file(str(DBC))


def messages(plan, kind):
    return [m for m in plan.messages if m.kind == kind]


# -- layout ------------------------------------------------------------------------------------


@pytest.mark.parametrize("bench_file", ["i3-bench.toml", "i4-bench.toml"])
@pytest.mark.parametrize("reference", ["none", "pressure", "cam"])
def test_plan_layout_matches_the_simulated_source(bench_file, reference):
    bench = simulated_bench(
        load_bench(EXAMPLES_DIR / bench_file), tacho={"phase_reference": reference}
    )
    plan = can_plan(bench, DBC)
    sim = open_source("sim", bench, duration_s=0.5)
    assert plan.layout.groups == sim.layout.groups
    assert plan.layout.edge_channels == sim.layout.edge_channels


def test_example_dbc_frames_are_what_docs_say(i3):
    plan = can_plan(i3, DBC)
    acc = messages(plan, "samples")
    by_name = {m.name: m for m in acc}
    assert [m.name for m in acc] == ["DAQ_AccA", "DAQ_AccB", "DAQ_AccC", "ECU_EngineSpeed"]
    for m in acc[:3]:
        assert (m.length, m.is_fd, m.samples_per_frame, m.rate_hz) == (64, True, 9, 5120.0)
        assert m.counter.bits == 32 and m.crc is not None and m.fast
    ecu = by_name["ECU_EngineSpeed"]
    # classic CAN, rate from GenMsgCycleTime = 10 ms, counter and CRC named by attributes
    assert (ecu.length, ecu.is_fd, ecu.rate_hz, ecu.counter.name, ecu.crc.name) == (
        8,
        False,
        100.0,
        "AliveCounter",
        "Checksum",
    )
    (edges,) = messages(plan, "edges")
    assert (edges.group, edges.samples_per_frame, edges.tick_s) == ("tacho", 13, 1e-9)


# -- fast path against cantools ----------------------------------------------------------------


def test_sample_frames_decode_like_cantools(i3, db):
    plan = can_plan(i3, DBC)
    rng = np.random.default_rng(3)
    for m in messages(plan, "samples"):
        sc = m.scalings[0]
        hi = sc.raw_max * sc.scale + sc.offset
        lo = sc.raw_min * sc.scale + sc.offset
        values = rng.uniform(lo, hi, (7, m.samples_per_frame, len(m.channels)))
        datas, clipped = encode_sample_frames(m, 65530, values)
        assert clipped == 0
        rows = as_rows(datas, m.length)
        ours = scale_samples(m, read_fields(rows, m.payload))
        counters = read_fields(rows, [m.counter])[:, 0]
        assert np.array_equal(counters, (65530 + np.arange(7)) % m.counter_modulus)
        # the independent reference: cantools decoding each frame, signal by signal
        for i, d in enumerate(datas):
            ref = db.decode_message(m.frame_id, d, decode_choices=False)
            assert ref[m.counter.name] == counters[i]
            got = {name: ours[i].ravel()[j] for j, name in enumerate(m.signal_names)}
            for name, v in got.items():
                assert v == pytest.approx(ref[name], abs=1e-9), name
            # CRC-16/CCITT-FALSE over every byte except the CRC, as binascii computes it
            crc_bytes = slice(m.crc.byte, m.crc.byte + 2)
            body = d[: crc_bytes.start] + d[crc_bytes.stop :]
            assert ref[m.crc.name] == binascii.crc_hqx(body, 0xFFFF)
        # quantisation: within half a step of the physical value
        assert np.abs(ours - values).max() <= 0.5 * sc.scale * (1 + 1e-9)
        assert np.array_equal(raw_fields_slow(m, datas), read_fields(rows, m.payload))


def test_cantools_encoded_frames_decode_by_the_fast_path(i3, db):
    plan = can_plan(i3, DBC)
    m = next(m for m in plan.messages if m.name == "DAQ_AccB")
    msg = db.get_message_by_name(m.name)
    rng = np.random.default_rng(4)
    phys = {
        s.name: float(np.round(rng.uniform(-300, 300), 2))
        for s in msg.signals
        if s.name.startswith("B_")
    }
    data = msg.encode({**phys, "SEQ": 123456789, "CRC": 0}, strict=False)
    values = scale_samples(m, read_fields(as_rows([data], 64), m.payload))[0]
    for k in range(9):
        for c, ch in enumerate(m.channels):
            assert values[k, c] == pytest.approx(phys[f"{ch}_s{k}"], abs=1e-9)


def test_edge_frames_decode_like_cantools(i3, db):
    plan = can_plan(i3, DBC)
    (m,) = messages(plan, "edges")
    ticks = [
        np.array([10**12 + 5, 10**12 + 400_001, 10**12 + 900_000]),
        np.arange(13, dtype=np.int64) * 333_333 + 7,
    ]
    datas = encode_edge_frames(m, 4, ticks)
    for d, t in zip(datas, ticks, strict=True):
        ref = db.decode_message(m.frame_id, d, decode_choices=False, scaling=False)
        assert ref["EDGE_N"] == t.size and ref["EDGE_T0"] == t[0]
        assert [ref[f"EDGE_D{k}"] for k in range(1, t.size)] == (t[1:] - t[0]).tolist()
    with pytest.raises(SourceError, match=r"1\.\.13 edges"):
        encode_edge_frames(m, 0, [np.arange(14)])


def test_invalid_and_out_of_range_samples(i3):
    plan = can_plan(i3, DBC)
    m = plan.messages[0]
    values = np.zeros((1, 9, 3))
    values[0, 0, 0] = np.nan
    values[0, 1, 1] = 1e6  # beyond +327.67 m/s^2: clipped, not wrapped
    datas, clipped = encode_sample_frames(m, 0, values)
    out = scale_samples(m, read_fields(as_rows(datas, 64), m.payload))[0]
    assert clipped == 1
    assert np.isnan(out[0, 0]) and np.isnan(out).sum() == 1
    assert out[1, 1] == pytest.approx(327.67)


def _rewrite_ax(text, fmt):
    """Every ``A_x_sK`` signal rewritten by ``fmt(start_bit)`` (the other channels stay)."""

    def sub(m):
        return f"A_x_s{m[1]} : {fmt(int(m[2]))}"

    return re.sub(r"A_x_s(\d) : (\d+)\|16@1- \(0\.01,0\) \[-327\.67\|327\.67\]", sub, text)


def test_big_endian_and_unaligned_signals_match_cantools(tmp_path, i3):
    # A DBC the fast path reads (big-endian, byte-aligned) and one it cannot (12-bit samples).
    text = DBC.read_text()
    (tmp_path / "be.dbc").write_text(
        _rewrite_ax(text, lambda b: f"{b + 7}|16@0- (0.01,0) [-327.67|327.67]")
    )
    (tmp_path / "packed.dbc").write_text(
        _rewrite_ax(text, lambda b: f"{b + 4}|12@1- (0.1,0) [-204.7|204.7]")
    )
    m_be = can_plan(i3, tmp_path / "be.dbc").messages[0]
    assert m_be.fast and m_be.payload[0].big_endian and not m_be.payload[1].big_endian
    m_sl = can_plan(i3, tmp_path / "packed.dbc").messages[0]
    assert not m_sl.fast and m_sl.scalings[0].scale == 0.1
    for m, name in ((m_be, "be.dbc"), (m_sl, "packed.dbc")):
        db = cantools.database.load_file(str(tmp_path / name))
        values = np.random.default_rng(5).uniform(-100, 100, (3, 9, 3))
        datas, _ = encode_sample_frames(m, 0, values)
        raw = read_fields(as_rows(datas, 64), m.payload) if m.fast else raw_fields_slow(m, datas)
        ours = scale_samples(m, raw)
        assert np.abs(ours - values).max() <= 0.5 * max(sc.scale for sc in m.scalings) + 1e-9
        for i, d in enumerate(datas):
            ref = db.decode_message(m.frame_id, d, decode_choices=False)
            for k in range(9):
                assert ours[i, k, 0] == pytest.approx(ref[f"A_x_s{k}"], abs=1e-9)
                assert ours[i, k, 2] == pytest.approx(ref[f"A_z_s{k}"], abs=1e-9)
            assert frame_crc(d, m.crc) == ref["CRC"]


# -- checks on the DBC -------------------------------------------------------------------------


def dbc_variant(tmp_path, old, new, name="v.dbc"):
    text = DBC.read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (" SG_ B_y_s3 ", " SG_ B_yy_s3 ", r"channel 'B_y' has samples \[0, 1, 2, 4, 5, 6, 7, 8\]"),
        (
            'BA_ "PtiSampleRate" BO_ 257 5120;',
            'BA_ "PtiSampleRate" BO_ 257 2560;',
            "share one sample rate.*DAQ_AccB 2560 Hz",
        ),
        (
            'BA_ "PtiEdgeChannel" BO_ 288 "tacho";',
            'BA_ "PtiEdgeChannel" BO_ 288 "crank";',
            "no edge message for tacho channel 'tacho'.*crank",
        ),
        (
            ' SG_ SEQ : 0|32@1+ (1,0) [0|4294967295] "" PTI\n SG_ CRC : 32|16@1+ (1,0) [0|65535] "" PTI\n SG_ A_x_s0',
            ' SG_ CRC : 32|16@1+ (1,0) [0|65535] "" PTI\n SG_ A_x_s0',
            "DAQ_AccA: no counter signal 'SEQ'",
        ),
    ],
)
def test_dbc_inconsistencies_are_named(tmp_path, i3, old, new, message):
    with pytest.raises(SourceError, match=message):
        can_plan(i3, dbc_variant(tmp_path, old, new))


def test_missing_channel_names_it(tmp_path, i3):
    path = dbc_variant(tmp_path, "SG_ C_z_s", "SG_ C_w_s")
    with pytest.raises(SourceError) as err:
        can_plan(i3, path)
    msg = str(err.value)
    assert "no signal carries channel 'C_z' (sensor C_torque_rod)" in msg and "\n" not in msg


def test_missing_unreadable_or_unnamed_dbc(tmp_path, i3):
    with pytest.raises(SourceError, match="no DBC: name it in the bench file"):
        can_plan(
            i3.model_copy(update={"can": i3.can.model_copy(update={"dbc": None})})
        )  # a bench that names none
    with pytest.raises(SourceError, match="not found"):
        load_dbc(tmp_path / "nope.dbc")
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ 1 X: 8 Y\n SG_ broken {\n")
    with pytest.raises(SourceError, match="cannot be read"):
        load_dbc(bad)


def test_sampled_tacho_cannot_travel_over_can(i3, db):
    bench = simulated_bench(i3, tacho={"delivery": "sampled"})
    with pytest.raises(
        SourceError, match="delivery = 'sampled' at 200000 Hz cannot travel over CAN"
    ):
        plan_for_channels(db, channel_needs(bench))


def test_rpm_channel_is_required_for_an_rpm_tacho_only(tmp_path, i3):
    path = dbc_variant(
        tmp_path,
        'BA_ "PtiChannel" SG_ 192 EngineSpeed "rpm";',
        'BA_ "PtiChannel" SG_ 192 EngineSpeed "speed";',
    )
    plan = can_plan(i3, path)
    assert [g.name for g in plan.layout.groups] == ["accel"]
    with pytest.raises(SourceError, match="channel 'rpm' \\(rpm channel of a kind='rpm' tacho\\)"):
        can_plan(simulated_bench(i3, tacho={"kind": "rpm"}), path)


# -- CRC, bus timing, raw-frame records --------------------------------------------------------


def test_crc_is_crc16_ccitt_false():
    # the catalogue check value of CRC-16/CCITT-FALSE is 0x29B1 for "123456789"
    field = IntField("CRC", 9, 2, False)
    assert frame_crc(b"123456789\x00\x00", field) == 0x29B1
    field_front = IntField("CRC", 0, 2, False)
    assert frame_crc(b"\xab\xcd123456789", field_front) == 0x29B1


def test_frame_time_against_a_field_count():
    # classic 11-bit frame, 8 bytes: 47 + 64 bits including 3 bits of interframe space
    assert frame_time_s(
        8, fd=False, bitrate=500e3, data_bitrate=500e3, stuffing=False
    ) == pytest.approx(111 / 500e3)
    # extended id: 67 + 8 n bits
    assert frame_time_s(
        8, fd=False, bitrate=1e6, data_bitrate=1e6, extended=True, stuffing=False
    ) == pytest.approx(131e-6)
    # worst-case stuffing adds one bit per 4 of the 98 stuffed bits (SOF..CRC)
    assert frame_time_s(8, fd=False, bitrate=500e3, data_bitrate=500e3) == pytest.approx(
        135 / 500e3
    )
    # CAN FD, 64 bytes, BRS: SOF, 11 id, RRS, IDE, FDF, res, BRS (17) + CRC delim, ACK, delim, EOF 7,
    # IFS 3 (13) at 500k; ESI, DLC 4, 512 data, stuff count 4, CRC 21, 7 fixed stuff bits at 2M
    t = 30 / 500e3 + (1 + 4 + 512 + 4 + 21 + 7) / 2e6
    assert frame_time_s(
        64, fd=True, bitrate=500e3, data_bitrate=2e6, stuffing=False
    ) == pytest.approx(t)


def test_raw_frame_records_round_trip():
    frames = [
        RawFrame(1_700_000_000_123_456_789, 0x120, False, bytes(range(64)), True),
        RawFrame(-5, 0x1FFFFFFF, True, b"", False),
        RawFrame(42, 0xC0, False, b"\x01\x02\x03\x04\x05\x06\x07\x08", False),
    ]
    assert unpack_frames(pack_frames(frames)) == frames
    with pytest.raises(SourceError, match="needs"):
        unpack_frames(pack_frames(frames)[:-1])
