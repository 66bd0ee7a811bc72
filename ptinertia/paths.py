"""Where the shipped example benches live.

In a checkout (and an editable install) that is the repository's ``examples/``;
an installed wheel carries the same files as the package data ``ptinertia/examples``
(see ``pyproject.toml``).
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_CHECKOUT = _PACKAGE.parent / "examples"
EXAMPLES_DIR = _CHECKOUT if (_CHECKOUT / "i3-bench.toml").is_file() else _PACKAGE / "examples"
DEFAULT_BENCH = EXAMPLES_DIR / "i3-bench.toml"
