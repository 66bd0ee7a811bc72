"""Outputs never destroy inputs or special files, and a bad output path fails before the run.

Every case of issue 25 item 2: the input intact, the device or FIFO untouched (still a
device, still a FIFO), one line and exit 2, and the check made before any processing.
"""

from __future__ import annotations

import errno
import os
import stat
import threading
from pathlib import Path

import pytest

from ptinertia.cli import main
from ptinertia.errors import UsageError
from ptinertia.outputs import REFUSE, WARN, atomic_output, atomic_write, check_output
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.runner import write_json

DOC = {"a": 1.0}


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert len(lines) == 1, err
    return lines[0]


# -- the module ---------------------------------------------------------------------------------


def test_atomic_write_replaces_the_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    out = tmp_path / "r.json"
    out.write_text("old")
    write_json(DOC, out)
    assert out.read_text().strip() == '{\n  "a": 1.0\n}'
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]
    # the mode a plain open would give (mkstemp's private 0600 is not kept)
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~umask


def test_a_full_disk_is_one_line_and_leaves_the_old_file_and_no_part(tmp_path: Path) -> None:
    out = tmp_path / "r.json"
    out.write_text("old")
    with pytest.raises(UsageError, match=r"cannot write .*r\.json: No space left on device"):
        with atomic_output(out) as tmp:
            tmp.write_text("half")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert out.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_dev_full_is_written_in_place_and_stays_a_device() -> None:
    with pytest.raises(UsageError, match="No space left on device"):
        write_json(DOC, "/dev/full")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def test_dev_null_is_written_in_place() -> None:
    write_json(DOC, os.devnull)
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)


def test_a_fifo_is_written_in_place_and_its_reader_gets_everything(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    atomic_write(fifo, "payload\n")
    reader.join()
    assert got == [b"payload\n"]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_planted_symlink_at_the_old_part_name_is_not_followed(tmp_path: Path) -> None:
    victim = tmp_path / "victim"
    victim.write_text("keep")
    (tmp_path / "r.json.part").symlink_to(victim)
    write_json(DOC, tmp_path / "r.json")
    assert victim.read_text() == "keep"
    assert (tmp_path / "r.json").exists()


def test_check_output_cases(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "in.mcap"
    src.write_bytes(b"data")
    with pytest.raises(UsageError, match="empty path"):
        check_output("", "--json")
    with pytest.raises(UsageError, match="is a directory"):
        check_output(tmp_path, "--json")
    with pytest.raises(UsageError, match="does not exist"):
        check_output(tmp_path / "nowhere" / "r.json", "--json")
    with pytest.raises(UsageError, match="is an input"):
        check_output(src, "--json", [src], force=True)
    with pytest.raises(UsageError, match="is an input"):  # the same file by another name
        (tmp_path / "link.mcap").symlink_to(src)
        check_output(tmp_path / "link.mcap", "--record", [src], force=True)
    with pytest.raises(UsageError, match="add --force"):
        check_output(src, "--record", policy=REFUSE)
    assert check_output(src, "--record", force=True, policy=REFUSE) == src
    capsys.readouterr()
    check_output(src, "--json", policy=WARN)
    assert capsys.readouterr().err.strip() == f"ptinertia: --json {src}: exists, overwriting it"


# -- the commands -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A short simulated sweep as an MCAP recording and as CSV files."""
    d = tmp_path_factory.mktemp("sweep")
    out = {}
    for ext in ("mcap", "csv"):
        path = d / f"s.{ext}"
        assert (
            main(["simulate", "--out", str(path), "--duration", "0.3", "--sweep", "1500:1600"]) == 0
        )
        out[ext] = path
    return out


def _never_run(*args: object, **kwargs: object) -> None:
    raise AssertionError("the run started before its outputs were checked")


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["replay", "{mcap}", "--record", "{mcap}", "--force"], "is an input"),
        (["replay", "{mcap}", "--json", "{mcap}", "--force"], "is an input"),
        (
            ["run", "--bench", "{bench}", "--source", "file:{csv}", "--record", "{csv}", "--force"],
            "is an input",
        ),
        (  # a file read with the one named
            ["run", "--bench", "{bench}", "--source", "file:{csv}", "--json", "{rpm_csv}"],
            "is an input",
        ),
        (["run", "--json", ""], "--json: empty path"),
        (["run", "--json", "{missing}"], "no-such-dir does not exist"),
        (["run", "--record", "{mcap}"], "exists; add --force"),  # an existing recording
        (["run", "--json", "{dir}"], "is a directory"),
    ],
)
def test_a_bad_output_path_is_refused_before_the_run_and_the_input_is_intact(
    sweep: dict[str, Path],
    argv: list[str],
    says: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import ptinertia.commands.replay as replay_cmd
    import ptinertia.commands.run as run_cmd

    monkeypatch.setattr(run_cmd, "open_source", _never_run)
    monkeypatch.setattr(replay_cmd, "replay_one", _never_run)
    paths = {
        "mcap": sweep["mcap"],
        "csv": sweep["csv"],
        "rpm_csv": sweep["csv"].with_name("s.rpm.csv"),
        "missing": sweep["csv"].parent / "no-such-dir" / "r.json",
        "dir": sweep["csv"].parent,
        "bench": DEFAULT_BENCH,
    }
    before = {p: p.read_bytes() for p in sweep["csv"].parent.iterdir()}
    args = [a.format(**paths) for a in argv] + ["--rerun", "off", "--quiet"]
    assert main(args) == 2
    line = _one_line_error(capsys)
    assert line.startswith(f"ptinertia {argv[0]}: error: ")
    assert says in line
    assert {p: p.read_bytes() for p in sweep["csv"].parent.iterdir()} == before


def test_simulate_refuses_an_existing_output_and_overwrites_it_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "s.mf4"
    argv = ["simulate", "--out", str(out), "--duration", "0.2", "--sweep", "1500:1550"]
    assert main(argv) == 0
    first = out.read_bytes()
    out.write_bytes(b"precious")
    capsys.readouterr()
    assert main(argv) == 2
    assert "add --force" in _one_line_error(capsys)
    assert out.read_bytes() == b"precious"
    assert main([*argv, "--force"]) == 0
    assert len(out.read_bytes()) == len(first)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mf4"]  # no temporary left


def test_export_to_dev_full_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    terms = {"Ixx": 2.0, "Iyy": 3.0, "Izz": 4.0, "Ixy": 0.0, "Ixz": 0.0, "Iyz": 0.0}
    result = {
        "inertia_kgm2": {"value": terms, "std": dict.fromkeys(terms, 0.01)},
        "cog_m": {"value": [0.0, 0.0, 0.1], "std": [0.002] * 3},
        "mass_kg": {"value": 100.0, "std": 0.5},
        "frames": {"used": 100},
        "rpm_range": [1500.0, 4500.0],
        "source": "sim",
    }
    doc = tmp_path / "r.json"
    write_json(result, doc)
    assert main(["export", str(doc), "--format", "csv", "--out", os.devnull]) == 0
    assert main(["export", str(doc), "--format", "csv", "--out", "/dev/full"]) == 2
    assert "No space left on device" in _one_line_error(capsys)
    assert main(["export", str(doc), "--format", "csv", "--out", str(doc)]) == 2
    assert "is an input" in _one_line_error(capsys)
