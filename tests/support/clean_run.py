"""A short real recording (``ptinertia run``) and its clean replay: what damaged copies are compared with."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ptinertia.cli import main


@dataclass(frozen=True)
class CleanRun:
    """A simulated sweep recorded to ``log``, and the result of replaying it untouched.

    The bytes and the result are left out of the repr: hypothesis prints the
    arguments of a failing example.
    """

    log: Path
    data: bytes = field(repr=False)
    result: dict[str, Any] = field(repr=False)


def record_clean_run(folder: Path, duration_s: float = 4.0) -> CleanRun:
    """Record a ``duration_s`` sweep in ``folder`` and replay it once."""
    log, result = folder / "run.mcap", folder / "run.json"
    argv = ["run", "--duration", str(duration_s), "--rerun", "off", "--quiet", "--record", str(log)]
    if main(argv) != 0:
        raise RuntimeError("the clean recording failed")
    if main(["replay", str(log), "--quiet", "--json", str(result)]) != 0:
        raise RuntimeError("the clean replay failed")
    return CleanRun(log, log.read_bytes(), json.loads(result.read_text()))
