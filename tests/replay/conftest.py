"""A short real recording (``ptinertia run``) and its clean replay, shared by the integrity tests."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from ptinertia.cli import main


@dataclass(frozen=True)
class CleanRun:
    """A 4 s simulated sweep recorded to ``log``, and the result of replaying it untouched."""

    log: Path
    data: bytes = field(repr=False)
    result: dict[str, Any] = field(repr=False)


@pytest.fixture(scope="session")
def clean_run(tmp_path_factory: pytest.TempPathFactory) -> CleanRun:
    folder = tmp_path_factory.mktemp("clean-run")
    log, result = folder / "run.mcap", folder / "run.json"
    argv = ["run", "--duration", "4", "--rerun", "off", "--quiet", "--record", str(log)]
    assert main(argv) == 0
    assert main(["replay", str(log), "--quiet", "--json", str(result)]) == 0
    return CleanRun(log, log.read_bytes(), json.loads(result.read_text()))
