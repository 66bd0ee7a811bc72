"""``ptinertia can-sim`` and the whole chain over CAN: the estimate does not care how the data came.

One body (:func:`estimate`) runs the pipeline on the simulated source and on the
CAN paths fed from the same simulation (virtual bus in process, BLF and ASC logs,
a bus with lost, duplicated and corrupted frames, two processes through python-can-remote on
loopback).
Over a clean path the estimates agree to a small fraction of their own standard
deviation (only the DBC's quantisation differs); every path stays within the
realistic tolerance of the simulated truth (3 standard deviations per term).
"""

from __future__ import annotations

import json
import threading

import can
import numpy as np
import pytest
from support.can_streams import (
    DBC,
    RUN,
    TERMS,
    assemble,
    can_bench_file,
    check_same_stream,
    estimate,
    realistic_bench,
    simulated,
)

from acquisition.can.bus import CanBusSource
from acquisition.can.faults import FaultInjector, FaultRates
from acquisition.can.logs import FrameLogWriter
from ptinertia import cli
from ptinertia.commands.can_sim import simulate_to_bus
from ptinertia.config import load_bench
from ptinertia.runner import RunOptions, run_source
from ptinertia.sources import open_source
from ptinertia.to_can import can_plan


@pytest.fixture(scope="module")
def bench_path(tmp_path_factory):
    return can_bench_file(tmp_path_factory.mktemp("can"))


@pytest.fixture(scope="module")
def bench(bench_path):
    return load_bench(bench_path)


@pytest.fixture(scope="module")
def plan(bench):
    return can_plan(bench)


@pytest.fixture(scope="module")
def sim_doc(bench_path, bench):
    return estimate(bench_path, open_source("sim", bench, **RUN), "sim")


def assert_same_estimate(doc, ref, fraction):
    """Every inertia term and cog coordinate within ``fraction`` of the reference's standard deviation."""
    for k in TERMS:
        d = doc["inertia_kgm2"]["value"][k] - ref["inertia_kgm2"]["value"][k]
        assert abs(d) <= fraction * ref["inertia_kgm2"]["std"][k], (k, d)
    d = np.subtract(doc["cog_m"]["value"], ref["cog_m"]["value"])
    assert np.all(np.abs(d) <= fraction * np.array(ref["cog_m"]["std"])), d


def assert_realistic(doc, truth):
    """The realistic tolerance: within 3 standard deviations of the truth, term by term."""
    for k in TERMS:
        err = doc["inertia_kgm2"]["value"][k] - truth["inertia_kgm2"]["value"][k]
        assert abs(err) <= 3 * doc["inertia_kgm2"]["std"][k], (k, err)
    err = np.subtract(doc["cog_m"]["value"], truth["cog_m"]["value"])
    assert np.all(np.abs(err) <= 3 * np.array(doc["cog_m"]["std"])), err


def test_sim_estimate_is_realistic(sim_doc):
    assert_realistic(sim_doc, sim_doc["truth"])


@pytest.fixture(scope="module")
def live(bench_path, bench, plan):
    """The estimate and the CAN counts of the stream received live on a virtual bus."""
    channel = "ptinertia-e2e-virtual"
    source = CanBusSource(plan, interface="virtual", channel=channel, idle_timeout_s=10.0)
    tx = can.Bus(interface="virtual", channel=channel)
    sender = threading.Thread(
        target=simulate_to_bus,
        args=(bench, plan),
        kwargs={"bus": tx, "pace": False, "sim_overrides": RUN},
    )
    sender.start()
    try:
        doc = estimate(bench_path, source, f"can:virtual:{channel}")
    finally:
        sender.join()
        tx.shutdown()
    return doc, source.stats


def test_virtual_bus_estimate_equals_the_sim_estimate(live, sim_doc):
    doc, _ = live
    assert doc["frames"]["used"] == sim_doc["frames"]["used"]
    assert_same_estimate(doc, sim_doc, 0.01)
    assert_realistic(doc, sim_doc["truth"])


@pytest.mark.parametrize("fmt", ["blf", "asc", "trc", "mf4"])
def test_a_can_log_gives_exactly_what_the_live_bus_gave(
    tmp_path, bench_path, bench, plan, live, fmt
):
    """The same stream written to a log by can-sim's writer: the same frames, the same estimate."""
    log = tmp_path / f"run.{fmt}"
    with FrameLogWriter(log) as writer:
        simulate_to_bus(
            bench, plan, bus=None, log_frame=writer.write, pace=False, sim_overrides=RUN
        )
    source = open_source(f"file:{log}", bench)
    doc = estimate(bench_path, source, f"file:{log}")
    live_doc, live_stats = live
    assert source.stats.frames_in == live_stats.frames_in
    assert source.stats.as_dict()["streams"] == live_stats.as_dict()["streams"]
    assert doc["frames"] == live_doc["frames"]
    # the same items cut into other blocks: the dsp's sums differ by rounding only
    for k in TERMS:
        for what in ("value", "std"):
            a, b = doc["inertia_kgm2"][what][k], live_doc["inertia_kgm2"][what][k]
            assert abs(a - b) <= 1e-10 * abs(b), (k, what, a, b)
    assert np.allclose(doc["cog_m"]["value"], live_doc["cog_m"]["value"], rtol=1e-10, atol=0)


def test_can_sim_log_gives_the_same_estimate(tmp_path, bench_path, sim_doc):
    log = tmp_path / "run.blf"
    real_bench = realistic_bench(tmp_path, bench_path)
    args = ["can-sim", "--bench", str(real_bench), "--interface", "none", "--log", str(log)]
    assert (
        cli.main([*args, "--json", "--duration", "8", "--sweep", "1500:4500", "--seed", "3"]) == 0
    )
    doc = estimate(real_bench, open_source(f"file:{log}", load_bench(real_bench)), f"file:{log}")
    assert_same_estimate(doc, sim_doc, 0.01)


def test_lost_duplicated_corrupted_frames_keep_the_estimate_realistic(
    bench_path, bench, plan, sim_doc
):
    injector = FaultInjector(FaultRates(drop=0.01, duplicate=0.005, corrupt=0.005), plan, seed=7)
    frames = []
    simulate_to_bus(
        bench,
        plan,
        bus=None,
        log_frame=frames.append,
        pace=False,
        faults=injector,
        sim_overrides=RUN,
    )
    from acquisition.can.source import CanFrameSource

    source = CanFrameSource(plan, [frames[i : i + 2000] for i in range(0, len(frames), 2000)])
    doc = estimate(bench_path, source, "can:faulty")
    stats = source.stats
    spoiled = sum(len(v) for v in injector.log.spoiled.values())
    assert (
        stats.total("lost") <= spoiled and stats.total("lost") >= spoiled - 2
    )  # edge tails go unseen
    assert stats.total("duplicate") == sum(injector.log.duplicated.values())
    assert_realistic(doc, sim_doc["truth"])
    assert_same_estimate(doc, sim_doc, 0.5)


def test_recorded_raw_frames_decode_again(tmp_path, bench_path, bench, plan):
    """The raw frames go into the MCAP recording; its replay decodes them again to the same stream."""
    from acquisition.can.source import CanFrameSource
    from replay.reader import open_log
    from replay.recorder import McapRecorder

    recorder = McapRecorder(tmp_path / "run.mcap")
    channel = "ptinertia-e2e-record"
    source = CanBusSource(
        plan, interface="virtual", channel=channel, frame_listener=recorder.on_can_frames
    )
    tx = can.Bus(interface="virtual", channel=channel)
    short = {**RUN, "duration_s": 3.0}
    sender = threading.Thread(
        target=simulate_to_bus,
        args=(bench, plan),
        kwargs={"bus": tx, "pace": False, "sim_overrides": short},
    )
    sender.start()
    try:
        run_source(
            bench,
            bench_path.read_text(),
            source,
            "can:virtual",
            RunOptions(quiet=True, live=True, sinks=(recorder,)),
        )
    finally:
        sender.join()
        tx.shutdown()
    log = open_log(tmp_path / "run.mcap")
    with CanFrameSource(plan, log.can_frames()) as replayed:
        items = list(replayed)
    check_same_stream(plan, *simulated(bench, **short), items)
    assert replayed.stats.frames_in == source.stats.frames_in > 6000

    # The same through the CLI: decoding the raw frames again with the DBC gives the
    # samples the live run decoded, so the same estimate as a plain replay.
    plain, again = tmp_path / "plain.json", tmp_path / "again.json"
    argv = ["replay", str(tmp_path / "run.mcap"), "--quiet"]
    assert cli.main([*argv, "--json", str(plain)]) == 0
    assert cli.main([*argv, "--dbc", str(DBC), "--json", str(again)]) == 0
    a, b = json.loads(plain.read_text()), json.loads(again.read_text())
    assert a["inertia_kgm2"] == b["inertia_kgm2"] and a["frames"] == b["frames"]


def test_replay_dbc_of_a_log_without_can_frames_is_one_line(tmp_path, capsys):
    log = tmp_path / "sim.mcap"
    assert cli.main(["simulate", "--duration", "2", "--out", str(log)]) == 0
    capsys.readouterr()
    assert cli.main(["replay", str(log), "--dbc", str(DBC), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds no raw CAN frames" in err, err


# -- the command itself ----------------------------------------------------------------------------


def test_can_sim_on_a_virtual_bus_sends_the_simulated_stream(tmp_path, bench_path, plan, capsys):
    channel = "ptinertia-cli-virtual"
    with CanBusSource(plan, interface="virtual", channel=channel, idle_timeout_s=5.0) as rx:
        code = cli.main(
            [
                "can-sim",
                "--bench",
                str(bench_path),
                "--channel",
                channel,
                "--no-pace",
                "--duration",
                "2",
                "--sweep",
                "1500:4500",
            ]
        )
        assert code == 0
        items = list(rx)
    out = capsys.readouterr().out
    assert (
        "frames in 2 s of sweep to virtual:" + channel in out
        and "bus load at the top speed 71-86 %" in out
    )
    sim = simulated(load_bench(bench_path), duration_s=2.0, noise_snr_db=None)
    check_same_stream(plan, *sim, items)


def test_can_sim_faults_are_reported(tmp_path, bench_path, plan, capsys):
    log = tmp_path / "f.blf"
    args = [
        "can-sim",
        "--bench",
        str(bench_path),
        "--interface",
        "none",
        "--log",
        str(log),
        "--duration",
        "2",
        "--json",
    ]
    assert (
        cli.main(
            [
                *args,
                "--drop",
                "0.02",
                "--duplicate",
                "0.01",
                "--corrupt",
                "0.01",
                "--fault-seed",
                "5",
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    faults = summary["faults"]
    assert sum(faults["dropped"].values()) > 20 and sum(faults["duplicated"].values()) > 5
    with open_source(f"file:{log}", load_bench(bench_path)) as src:
        items = list(src)
    _, _, events = assemble(items, src.layout)
    assert src.stats.total("duplicate") == sum(faults["duplicated"].values())
    assert any(e.kind == "gap" for e in events)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--interface", "nosuchbus"], "unknown CAN interface 'nosuchbus'"),
        (["--dbc", "/nonexistent/x.dbc"], "DBC file '/nonexistent/x.dbc' not found"),
        (["--drop", "1.5"], "--drop: expected a fraction in \\[0, 1\\], got 1.5"),
        (["--interface", "none"], "--interface none sends nothing: give --log PATH"),
        (["--no-fd"], "DAQ_AccA is a CAN FD frame"),
    ],
)
def test_can_sim_bad_input_is_one_line_and_exit_2(bench_path, capsys, extra, message):
    code = cli.main(["can-sim", "--bench", str(bench_path), "--duration", "1", *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("ptinertia can-sim: error: ")
    import re

    assert re.search(message, err), err


def test_no_dbc_and_dbc_without_the_channels_exit_2(tmp_path, capsys):
    from ptinertia.paths import EXAMPLES_DIR

    no_dbc = tmp_path / "no-dbc.toml"
    no_dbc.write_text((EXAMPLES_DIR / "i3-bench.toml").read_text().partition("\n[can]\n")[0])
    assert cli.main(["can-sim", "--bench", str(no_dbc), "--duration", "1"]) == 2
    assert "no DBC: name it in the bench file" in capsys.readouterr().err
    short = tmp_path / "short.dbc"
    short.write_text(DBC.read_text().replace(" SG_ A_y_s", " SG_ Q_y_s"))
    bench = can_bench_file(tmp_path, dbc=short)
    assert (
        cli.main(
            [
                "run",
                "--bench",
                str(bench),
                "--source",
                "file:/nonexistent.blf",
                "--quiet",
                "--rerun",
                "off",
            ]
        )
        == 2
    )
    assert "not found" in capsys.readouterr().err
    assert (
        cli.main(
            ["run", "--bench", str(bench), "--source", "can:virtual:x", "--quiet", "--rerun", "off"]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no signal carries channel 'A_y' (sensor A_engine_mount)" in err
    good = can_bench_file(tmp_path)
    run = ["run", "--bench", str(good), "--quiet", "--rerun", "off"]
    assert cli.main([*run, "--source", "can:nosuchbus:0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown CAN interface 'nosuchbus'" in err


# -- two processes ---------------------------------------------------------------------------------


def test_a_recording_of_a_can_log_run_keeps_the_dbc_and_the_raw_frames(
    tmp_path, bench_path, bench, plan
):
    from replay.reader import open_log

    log = tmp_path / "run.blf"
    with FrameLogWriter(log) as writer:
        short = {**RUN, "duration_s": 3.0}
        simulate_to_bus(
            bench, plan, bus=None, log_frame=writer.write, pace=False, sim_overrides=short
        )
    rec = tmp_path / "run.mcap"
    argv = [
        "run",
        "--bench",
        str(bench_path),
        "--source",
        f"file:{log}",
        "--quiet",
        "--rerun",
        "off",
    ]
    assert cli.main([*argv, "--record", str(rec), "--json", str(tmp_path / "run.json")]) == 0
    recorded = open_log(rec)
    assert recorded.attachments[DBC.name] == DBC.read_bytes()
    assert sum(len(b) for b in recorded.can_frames()) == writer.count
    plain, again = tmp_path / "plain.json", tmp_path / "again.json"
    replay = ["replay", str(rec), "--quiet"]
    assert cli.main([*replay, "--json", str(plain)]) == 0
    assert cli.main([*replay, "--dbc", str(DBC), "--json", str(again)]) == 0
    a, b = json.loads(plain.read_text()), json.loads(again.read_text())
    assert a["frames"] == b["frames"]
    for k in TERMS:
        x, y = a["inertia_kgm2"]["value"][k], b["inertia_kgm2"]["value"][k]
        assert abs(x - y) <= 1e-10 * abs(y), (k, x, y)
