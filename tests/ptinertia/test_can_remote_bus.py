"""Two processes on one machine: ``can-sim`` and ``run`` through python-can-remote on loopback.

python-can's ``virtual`` bus connects only the buses of one process; the documented demo
(docs/can.md) is a ``python -m can_remote`` server bound to 127.0.0.1 holding the bus, with
``can-sim`` and ``run --source can:remote:ws://127.0.0.1:PORT/`` as its clients. Also here:
what a run says when that bus is missing or silent, and the interface options.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading

import numpy as np
import pytest
from support.can_streams import RUN, TERMS, can_bench_file, estimate, realistic_bench

from acquisition.can.source import CanFrameSource
from ptinertia import cli
from ptinertia.commands.can_sim import simulate_to_bus
from ptinertia.config import load_bench
from ptinertia.sources import open_source
from ptinertia.to_can import can_plan


@pytest.fixture(scope="module")
def bench_path(tmp_path_factory):
    return can_bench_file(tmp_path_factory.mktemp("can"))


@pytest.fixture(scope="module")
def live(bench_path):
    """The same stream decoded in one process (its frames handed over directly)."""
    bench = load_bench(bench_path)
    plan = can_plan(bench)
    frames = []
    simulate_to_bus(bench, plan, bus=None, log_frame=frames.append, pace=False, sim_overrides=RUN)
    source = CanFrameSource(plan, [frames[i : i + 200] for i in range(0, len(frames), 200)])
    return estimate(bench_path, source, "can:in-process"), source.stats


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


def test_bus_options_reach_the_bus(bench_path, capsys):
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
