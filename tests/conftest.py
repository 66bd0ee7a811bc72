"""Fixtures shared by the whole suite.

Helpers that tests import (independent forward models, recorded logs, CAN streams) live in
``tests/support``; fixtures that many test modules take by name live here.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ptinertia.config import Bench, load_bench
from ptinertia.paths import EXAMPLES_DIR


@pytest.fixture(scope="session")
def i3_path() -> Path:
    """The example inline-3 bench file (sensors, mounts, engine, DBC names)."""
    return EXAMPLES_DIR / "i3-bench.toml"


@pytest.fixture(scope="module")
def i3(i3_path: Path) -> Bench:
    """The example inline-3 bench, parsed (one per test module, as each module had its own)."""
    return load_bench(i3_path)
