"""The package list of pyproject.toml (explicit, for the shipped examples) against the tree."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_package_and_example_is_shipped() -> None:
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(setup["packages"])
    # the top-level directories holding a package, not the virtual environment's thousands
    tops = [
        d
        for d in ROOT.iterdir()
        if (d / "__init__.py").is_file() and d.name not in {"tests", "benchmarks"}
    ]
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts) for d in tops for p in d.glob("**/__init__.py")
    }
    assert on_disk <= listed, f"packages missing from pyproject.toml: {sorted(on_disk - listed)}"
    assert setup["package-dir"]["ptinertia.examples"] == "examples"
    patterns = setup["package-data"]["ptinertia.examples"]
    shipped = {p.name for pat in patterns for p in (ROOT / "examples").glob(pat)}
    assert shipped == {p.name for p in (ROOT / "examples").iterdir() if p.is_file()}
