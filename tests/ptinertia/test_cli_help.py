"""What a user sees first: ``--help`` in plain text, ``--version`` with the dependencies."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from ptinertia.cli import COMMANDS, KEY_DEPENDENCIES, build_parser, main, plain_help


def _command_parser(name: str) -> argparse.ArgumentParser:
    parser, _ = build_parser([name])
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return subparsers.choices[name]


def test_plain_help_drops_the_rst_markup() -> None:
    doc = "``ptinertia run``: acquire, see :mod:`ptinertia.runner`.\n\nUse ``--json`` or :func:`~x.y`."
    assert plain_help(doc) == "Acquire, see ptinertia.runner.\n\nUse --json or x.y."


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_help_is_plain_text(name: str) -> None:
    text = _command_parser(name).format_help()
    assert "``" not in text and ":mod:`" not in text and ":func:`" not in text, text
    description = text.split("\n\n")[1]
    assert not description.lower().startswith("ptinertia"), description
    assert description[:1].isupper(), description


def test_simulate_help_names_every_output_format() -> None:
    text = _command_parser("simulate").format_help()
    assert ".mcap" in text and ".mf4" in text and ".csv" in text


def test_version_lists_the_key_dependencies(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("ptinertia ")
    named = {line.split()[0] for line in lines[1:]}
    assert {"Python", *KEY_DEPENDENCIES} == named
    numpy_line = next(line for line in lines if line.split()[0] == "numpy")
    import numpy

    assert numpy_line.split()[1] == numpy.__version__


def test_python_dash_m_runs_the_cli() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "ptinertia", "--version"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("ptinertia ")


def test_compiled_kernels_asked_for_without_numba_say_so_in_one_line(monkeypatch, capsys) -> None:
    """PTINERTIA_NUMBA=1 on an install without the fast extra: one line, the numpy
    kernels run (it was silent)."""
    import importlib.util

    from ptinertia.cli import main

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "numba" else real(name, *a)
    )
    monkeypatch.setenv("PTINERTIA_NUMBA", "1")
    assert main(["excitation", "--rpm", "2000", "--orders", "1.5"]) == 0
    err = capsys.readouterr().err
    assert "PTINERTIA_NUMBA=1 but numba is not installed" in err
    assert len(err.strip().splitlines()) == 1


def test_a_numba_compile_is_announced_once_and_a_cache_load_is_not(capsys) -> None:
    """PTINERTIA_NUMBA=1: the first compile of a run says so in one line (15-20 s without
    a word looked like a hang); later compiles say nothing."""
    numba = pytest.importorskip("numba")
    from numba.core import event

    from ptinertia.cli import announce_compiling

    listener = announce_compiling("run")
    try:
        numba.njit(cache=False)(lambda x: x + 1)(1)
        numba.njit(cache=False)(lambda x: x * 2.0)(1.0)
    finally:
        event.unregister("numba:compile", listener)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "ptinertia run: compiling the numba kernels (once after an install or an update, "
        "30-35 s; later runs load them from numba's cache)"
    ]


def test_a_command_leaves_no_compile_listener_behind(monkeypatch, tmp_path) -> None:
    # main called again in one process (tests, a notebook) registered one more listener a
    # call, and the first compile then printed its line once per earlier call
    pytest.importorskip("numba")
    from numba.core import event

    monkeypatch.setenv("PTINERTIA_NUMBA", "1")
    before = list(event._registered["numba:compile"])
    for _ in range(2):  # a user error: the command ends at once, through main's exits
        assert main(["run", "--bench", str(tmp_path / "missing.toml"), "--rerun", "off"]) == 2
    assert event._registered["numba:compile"] == before
