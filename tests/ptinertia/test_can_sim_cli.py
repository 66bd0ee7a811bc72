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
import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import can
import numpy as np
import pytest
from support.can_streams import DBC, assemble, can_bench_file, check_same_stream, simulated

from acquisition.can.bus import CanBusSource
from acquisition.can.faults import FaultInjector, FaultRates
from acquisition.can.logs import FrameLogWriter
from ptinertia import cli
from ptinertia.commands.can_sim import simulate_to_bus
from ptinertia.config import load_bench
from ptinertia.runner import RunOptions, run_source
from ptinertia.sources import REALISTIC_SIMULATION, open_source
from ptinertia.to_can import can_plan

REALISTIC = REALISTIC_SIMULATION
RUN = {**REALISTIC, "duration_s": 8.0, "rpm_start": 1500.0, "rpm_end": 4500.0, "seed": 3}
TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


@pytest.fixture(scope="module")
def bench_path(tmp_path_factory):
    return can_bench_file(tmp_path_factory.mktemp("can"))


@pytest.fixture(scope="module")
def bench(bench_path):
    return load_bench(bench_path)


@pytest.fixture(scope="module")
def plan(bench):
    return can_plan(bench)


def realistic_bench(tmp_path: Path, bench_path: Path) -> Path:
    """The bench file with the realistic imperfections in its ``[simulation]`` (for the CLI)."""
    keys = "".join(f"{k} = {v}\n" for k, v in REALISTIC.items())
    path = tmp_path / "realistic.toml"
    path.write_text(bench_path.read_text().replace("[simulation]\n", "[simulation]\n" + keys))
    return path


def estimate(bench_path: Path, source, spec: str) -> dict:
    """The result document of the chain on ``source`` (the shared body)."""
    bench = load_bench(bench_path)
    summary, doc = run_source(
        bench,
        bench_path.read_text(),
        source,
        spec,
        RunOptions(quiet=True, live=spec.startswith("can")),
    )
    assert doc is not None and not summary.interrupted
    return doc


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


def _free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Server:
    """``python -m can_remote`` on loopback, its log lines watched for client connections."""

    def __init__(self, port: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "can_remote", "--interface", "virtual", "--channel", "0",
             "--host", "127.0.0.1", "--port", str(port)],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        self.listening = threading.Event()
        self.clients = threading.Semaphore(0)
        self.lines: list[str] = []
        threading.Thread(target=self._watch, daemon=True).start()

    def _watch(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)
            if "Server listening" in line:
                self.listening.set()
            if "Got connection" in line:
                self.clients.release()
        self.listening.set()  # the server died: let the waiter see it

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=30)


@pytest.mark.slow
def test_two_processes_over_the_loopback_remote_bus(tmp_path, bench_path, live):
    """``can-sim`` and ``run --source can:remote:ws://127.0.0.1:PORT/`` as two processes, through
    python-can-remote's server on loopback: the in-process run's frames and estimate."""
    port = _free_loopback_port()
    url = f"ws://127.0.0.1:{port}/"
    real_bench = realistic_bench(tmp_path, bench_path)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    result = tmp_path / "result.json"
    server = _Server(port)
    try:
        assert server.listening.wait(60) and server.proc.poll() is None, server.lines
        run = subprocess.Popen(
            [sys.executable, "-m", "ptinertia", "run", "--bench", str(real_bench), "--source",
             f"can:remote:{url}", "--quiet", "--rerun", "off", "--json", str(result)],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        # can-sim starts once the run is connected (the server logs it), so nothing is missed
        assert server.clients.acquire(timeout=120), server.lines
        sim = subprocess.run(
            [sys.executable, "-m", "ptinertia", "can-sim", "--bench", str(real_bench),
             "--interface", "remote", "--channel", url, "--duration", "8", "--sweep",
             "1500:4500", "--seed", "3", "--no-pace", "--json"],
            env=env, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        _, err = run.communicate(timeout=300)  # ends by itself at can-sim's stop frame
    finally:
        server.stop()
    assert sim.returncode == 0, sim.stderr
    assert run.returncode == 0, err
    doc = json.loads(result.read_text())
    live_doc, _ = live
    assert doc["frames"] == live_doc["frames"]
    for k in TERMS:
        a, b = doc["inertia_kgm2"]["value"][k], live_doc["inertia_kgm2"]["value"][k]
        assert abs(a - b) <= 1e-10 * abs(b), (k, a, b)
    assert np.allclose(doc["cog_m"]["value"], live_doc["cog_m"]["value"], rtol=1e-10, atol=0)


def test_a_remote_bus_without_its_server_is_one_line_naming_it(bench_path, capsys):
    url = f"ws://127.0.0.1:{_free_loopback_port()}/"  # nothing listens there
    argv = ["run", "--bench", str(bench_path), "--source", f"can:remote:{url}", "--quiet"]
    assert cli.main([*argv, "--rerun", "off"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"cannot open CAN bus remote:{url}" in err
    assert "python -m can_remote" in err


def test_a_run_that_hears_nothing_says_what_to_check_and_exits_1(bench_path, capsys):
    # nothing listens on this loopback address: the bus cannot even open (exit 2); a server
    # that nobody sends through is the silent case
    port = _free_loopback_port()
    server = _Server(port)
    try:
        assert server.listening.wait(60), server.lines
        argv = ["run", "--bench", str(bench_path), "--source", f"can:remote:ws://127.0.0.1:{port}/"]
        code = cli.main([*argv, "--quiet", "--rerun", "off", "--start-timeout", "0.5"])
    finally:
        server.stop()
    err = capsys.readouterr().err
    assert code == 1
    assert f"no CAN frame on remote:ws://127.0.0.1:{port}/ within 0.5 s: check" in err, err


def test_bus_options_reach_the_bus(tmp_path, bench_path, plan, capsys):
    from ptinertia.to_can import parse_bus_options

    assert parse_bus_options(["receive_own_messages=true", "n=3", "x=0.5", "name=a=b"]) == {
        "receive_own_messages": True, "n": 3, "x": 0.5, "name": "a=b",
    }  # fmt: skip
    bench = load_bench(bench_path)
    seen = {}
    bench = bench.model_copy(
        update={"can": bench.can.model_copy(update={"bus_options": {"preserve_timestamps": True}})}
    )
    src = open_source(
        "can:virtual:opts", bench, bus_kwargs={"rx_queue_size": 7}, idle_timeout_s=0.1
    )
    try:
        seen.update(src._rx.bus.__dict__)
    finally:
        src.close()
    assert seen["preserve_timestamps"] is True and seen["queue"].maxsize == 7
    assert cli.main(["run", "--bench", str(bench_path), "--source", "can:virtual:x",
                     "--bus-option", "novalue", "--quiet", "--rerun", "off"]) == 2  # fmt: skip
    assert "--bus-option: expected KEY=VALUE, got 'novalue'" in capsys.readouterr().err


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
