"""The package list of pyproject.toml (explicit, for the shipped examples) against the tree."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_and_example_is_shipped() -> None:
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(setup["packages"])
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in ROOT.glob("**/__init__.py")
        if not {"tests", ".venv", "build", "benchmarks"} & set(p.relative_to(ROOT).parts)
    }
    assert on_disk <= listed, f"packages missing from pyproject.toml: {sorted(on_disk - listed)}"
    assert setup["package-dir"]["ptinertia.examples"] == "examples"
    patterns = setup["package-data"]["ptinertia.examples"]
    shipped = {p.name for pat in patterns for p in (ROOT / "examples").glob(pat)}
    assert shipped == {p.name for p in (ROOT / "examples").iterdir() if p.is_file()}
