"""Where the shipped example benches live (the repository's ``examples/``)."""

from __future__ import annotations

from pathlib import Path

EXAMPLES_DIR = Path(__file__).resolve().parent.parent / "examples"
DEFAULT_BENCH = EXAMPLES_DIR / "i3-bench.toml"
