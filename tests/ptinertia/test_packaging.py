"""The package list of pyproject.toml (explicit, for the shipped examples) against the tree."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib.metadata import packages_distributions
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


def _imported_top_modules(folders: list[Path]) -> set[str]:
    names: set[str] = set()
    for folder in folders:
        for path in folder.glob("**/*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names |= {a.name.split(".")[0] for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names.add(node.module.split(".")[0])
    return names


def _requirement_name(req: str) -> str:
    return re.split(r"[<>=!~;\[ ]", req, maxsplit=1)[0].lower().replace("_", "-")


def test_every_third_party_import_is_declared() -> None:
    """What the packages import is in [project] dependencies; what tests import, in the dev extra."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    ours = {"acquisition", "dsp", "estimator", "replay", "powertrain", "ptinertia", "support"}
    # import name -> distribution names, as installed (google -> protobuf, can -> python-can ...)
    dists = {k: {d.lower() for d in v} for k, v in packages_distributions().items()}

    def undeclared(imports: set[str], declared: set[str]) -> list[str]:
        third = sorted(imports - set(sys.stdlib_module_names) - ours - {"__future__"})
        return [m for m in third if not dists.get(m, {m}) & declared]

    runtime = {_requirement_name(r) for r in project["dependencies"]}
    extras = {
        _requirement_name(r) for group in project["optional-dependencies"].values() for r in group
    }
    packages = [
        ROOT / p for p in ("acquisition", "dsp", "estimator", "replay", "powertrain", "ptinertia")
    ]
    # lz4 and numba are optional (extras) and imported only when chosen
    assert undeclared(_imported_top_modules(packages), runtime | {"lz4", "numba"}) == []
    assert undeclared(_imported_top_modules([ROOT / "tests"]), runtime | extras) == []
