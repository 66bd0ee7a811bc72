"""End-to-end runs of the example benches scored against their truth, shared by the estimator tests."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import RunOptions, run_source
from ptinertia.sources import open_source

I3 = EXAMPLES_DIR / "i3-bench.toml"


TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def run(
    path: Path,
    overrides: dict[str, Any] | None = None,
    rpm_max: float | None = None,
    estimator: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The result document of a simulated run (``overrides``: ``[simulation]``,
    ``estimator``: ``[estimator]`` settings)."""
    bench = load_bench(path)
    settings = dict(estimator or {})
    if rpm_max is not None:
        settings["rpm_max"] = rpm_max
    if settings:
        bench = bench.model_copy(update={"estimator": bench.estimator.model_copy(update=settings)})
    source = open_source("sim", bench, **(overrides or {}))
    _, doc = run_source(bench, path.read_text(), source, "sim", RunOptions(quiet=True))
    assert doc is not None
    return doc


def rel_errors(doc: dict[str, Any]) -> dict[str, float]:
    truth = doc["truth"]["inertia_kgm2"]["value"]
    return {k: (doc["inertia_kgm2"]["value"][k] - truth[k]) / abs(truth[k]) for k in TERMS}


def cog_error_m(doc: dict[str, Any]) -> np.ndarray:
    return np.abs(np.array(doc["cog_m"]["value"]) - np.array(doc["truth"]["cog_m"]["value"]))
