"""Campaign replay on Dask: a real LocalCluster, a real scheduler with two workers, a killed worker.

Every campaign result must be the file a serial ``ptinertia replay LOG --json`` writes, byte for
byte; a corrupt log is a row carrying its error while the others complete.
"""

from __future__ import annotations

import csv
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from dask.distributed import Client

from ptinertia.batch.campaign import ReplayJob, replay_log, run_campaign
from ptinertia.batch.cluster import ClusterSpec, open_client
from ptinertia.cli import main
from ptinertia.errors import UsageError
from replay.reader import open_log

BIN = Path(sys.executable).parent
SEEDS = (1, 2, 3)


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, bytes]]:
    """Three short realistic recordings and a corrupt one; the serial replay result of each."""
    folder = tmp_path_factory.mktemp("campaign") / "logs"
    folder.mkdir()
    serial = folder.parent / "serial"
    serial.mkdir()
    expected = {}
    for seed in SEEDS:
        log = folder / f"run{seed}.mcap"
        argv = ["run", "--rerun", "off", "--quiet", "--duration", "5", "--realistic"]
        assert main([*argv, "--seed", str(seed), "--record", str(log)]) == 0
        result = serial / f"run{seed}.result.json"
        assert main(["replay", str(log), "--quiet", "--json", str(result)]) == 0
        expected[result.name] = result.read_bytes()
    (folder / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    return folder, expected


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _check_campaign(out: Path, expected: dict[str, bytes]) -> None:
    for name, data in expected.items():
        assert (out / name).read_bytes() == data, name
    rows = {r["log"]: r for r in csv.DictReader((out / "campaign.csv").open())}
    assert sorted(rows) == ["broken.mcap", "run1.mcap", "run2.mcap", "run3.mcap"]
    assert rows["broken.mcap"]["status"] == "error"
    assert "broken.mcap" in rows["broken.mcap"]["error"]
    assert "\n" not in rows["broken.mcap"]["error"]
    for seed in SEEDS:
        row = rows[f"run{seed}.mcap"]
        assert row["status"] == "ok" and not row["error"]
        assert float(row["Ixx_std_kgm2"]) > 0 and int(row["frames_used"]) > 50
    assert (out / "campaign.png").stat().st_size > 1000


def test_campaign_on_a_local_cluster_equals_serial_replay(
    logs: tuple[Path, dict[str, bytes]], tmp_path: Path
) -> None:
    folder, expected = logs
    out = tmp_path / "out"
    # 1: the broken log has no estimate, and its row says why
    assert main(["replay", str(folder), "--quiet", "--out", str(out), "--workers", "2"]) == 1
    _check_campaign(out, expected)


@pytest.fixture(scope="module")
def scheduler() -> Iterator[tuple[str, list[subprocess.Popen[bytes]]]]:
    """A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    # each in its own session: the nanny and its worker process end together at teardown
    quiet = {
        "stdout": subprocess.DEVNULL,
        "stderr": subprocess.DEVNULL,
        "env": env,
        "start_new_session": True,
    }
    sched = subprocess.Popen(
        [BIN / "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
        **quiet,  # type: ignore[call-overload]
    )
    worker_cmd = [BIN / "dask", "worker", address, "--host", "127.0.0.1", "--nthreads", "1"]
    workers = [
        subprocess.Popen([*worker_cmd, "--no-dashboard", "--name", f"w{k}"], **quiet)  # type: ignore[call-overload]
        for k in range(2)
    ]
    try:
        yield address, workers
    finally:
        for p in [*workers, sched]:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=20)


def test_campaign_on_a_running_scheduler_equals_serial_replay(
    logs: tuple[Path, dict[str, bytes]],
    scheduler: tuple[str, list[subprocess.Popen[bytes]]],
    tmp_path: Path,
) -> None:
    folder, expected = logs
    out = tmp_path / "out"
    address, _ = scheduler
    argv = ["replay", str(folder), "--quiet", "--out", str(out)]
    assert main([*argv, "--scheduler", address, "--workers", "2"]) == 1
    _check_campaign(out, expected)


def test_a_worker_killed_mid_campaign_is_replaced_and_the_campaign_completes(
    logs: tuple[Path, dict[str, bytes]],
    scheduler: tuple[str, list[subprocess.Popen[bytes]]],
    tmp_path: Path,
) -> None:
    folder, expected = logs
    address, _ = scheduler
    with Client(address, timeout=20) as client:
        client.wait_for_workers(2, timeout=20)
        pids = sorted(client.run(os.getpid).values())
    killed: list[int] = []

    def kill_workers(i: int, result: object) -> None:
        # at the first result the other logs are running or queued on the workers: kill
        # every worker process (SIGKILL, no goodbye); their nannies start new ones
        if killed:
            return
        for pid in pids:
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    out = tmp_path / "out"
    results = run_campaign(
        sorted(folder.glob("*.mcap")),
        ReplayJob(),
        out,
        ClusterSpec(address, workers=2),
        progress=False,
        on_result=kill_workers,
    )
    assert killed == pids
    assert [r.status for r in results] == ["error", "ok", "ok", "ok"]
    _check_campaign(out, expected)


def _one_line_error(capsys: pytest.CaptureFixture[str], code: int) -> str:
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_bad_campaign_inputs_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "nowhere"
    err = _one_line_error(capsys, main(["replay", str(missing), str(missing), "--quiet"]))
    assert "nowhere" in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "no .mcap files" in _one_line_error(capsys, main(["replay", str(empty), "--quiet"]))
    for name in ("a", "b"):
        (tmp_path / f"{name}.mcap").write_bytes(b"x")
    two = [str(tmp_path / "a.mcap"), str(tmp_path / "b.mcap")]
    err = _one_line_error(capsys, main(["replay", *two, "--scheduler", "nonsense", "--quiet"]))
    assert "nonsense" in err


def test_an_unreachable_scheduler_is_a_usage_error() -> None:
    spec = ClusterSpec(f"tcp://127.0.0.1:{_free_port()}", connect_timeout_s=1.0)
    with pytest.raises(UsageError, match="cannot reach"), open_client(spec):
        pass


def test_a_log_without_estimate_gives_the_reason_replay_prints(
    logs: tuple[Path, dict[str, bytes]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder, _ = logs
    log = folder / "run1.mcap"
    # the log's own bench with an estimator rpm range the 1500-4500 rpm sweep never enters
    bench_text = open_log(log).bench_text
    assert bench_text and "[estimator]" not in bench_text
    bench = tmp_path / "high.toml"
    bench.write_text(bench_text + "\n[estimator]\nrpm_min = 6000.0\n")
    row = replay_log(str(log), ReplayJob(bench_path=str(bench)))
    assert row.status == "no estimate"
    assert row.error is not None
    assert "never entered the [estimator] rpm range" in row.error
    assert main(["replay", str(log), "--quiet", "--bench", str(bench)]) == 1
    printed = capsys.readouterr().err
    assert row.error.split(": ", 1)[1] in printed
