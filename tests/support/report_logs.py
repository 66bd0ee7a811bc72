"""Recordings made once per test session for the report, resim, export and browser tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from ptinertia.cli import main
from ptinertia.paths import DEFAULT_BENCH


def _cached(tmp_path_factory: pytest.TempPathFactory, name: str) -> Path:
    d = tmp_path_factory.getbasetemp() / f"ptinertia-{name}"
    d.mkdir(exist_ok=True)
    return d


def realistic_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The recording and result document of a realistic simulated i3 sweep (20 s), made once."""
    d = _cached(tmp_path_factory, "realistic-i3")
    log, doc = d / "run.mcap", d / "result.json"
    if not (log.exists() and doc.exists()):
        argv = ["run", "--duration", "20", "--rerun", "off", "--quiet", "--realistic"]
        code = main([*argv, "--record", str(log), "--json", str(doc)])
        assert code == 0
    return log, doc


def no_estimate_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run whose every frame is gated out: the estimator's rpm range is above the sweep."""
    d = _cached(tmp_path_factory, "no-estimate")
    log = d / "run.mcap"
    if not log.exists():
        text = DEFAULT_BENCH.read_text(encoding="utf-8") + "\n[estimator]\nrpm_min = 8000.0\n"
        bench = d / "bench.toml"
        bench.write_text(text, encoding="utf-8")
        argv = ["run", "--bench", str(bench), "--duration", "3", "--rerun", "off", "--quiet"]
        code = main([*argv, "--record", str(log)])
        assert code == 1  # no estimate: the run says so and still writes its recording
    return log
