"""The estimator benchmark's cases (benchmarks/bench_estimator.py): the simulated benches,
one run of a case through the real dsp, and the error and coverage of its result."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from ptinertia.sources import REALISTIC_SIMULATION

ROOT = Path(__file__).resolve().parent.parent
I3 = ROOT / "examples" / "i3-bench.toml"
I4 = ROOT / "examples" / "i4-bench.toml"
TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
REALISTIC = REALISTIC_SIMULATION
DEAD_C = {"dead_channels": ["C_x", "C_y", "C_z"]}


def run_case(
    bench_path: Path,
    overrides: dict[str, Any],
    off: tuple[str, ...] = (),
    rpm_max: float | None = None,
    estimator: dict[str, Any] | None = None,
) -> dict[str, Any]:
    from ptinertia.config import load_bench
    from ptinertia.runner import RunOptions, run_source
    from ptinertia.sources import open_source

    bench = load_bench(bench_path)
    overrides = dict(overrides)
    settings = dict(estimator or {})
    if rpm_max is not None:
        settings["rpm_max"] = rpm_max
    if settings:
        est = bench.estimator.model_copy(update=settings)
        bench = bench.model_copy(update={"estimator": est})
    source = open_source("sim", bench, **overrides)
    t0 = time.perf_counter()
    summary, doc = run_source(
        bench, bench_path.read_text(), source, "sim", RunOptions(quiet=True, corrections_off=off)
    )
    doc = doc or {}
    doc["_seconds"] = time.perf_counter() - t0
    doc["_frames"] = summary.frames
    return doc


def errors(doc: dict[str, Any]) -> dict[str, float]:
    """Relative error per inertia term (products relative to their own value), cog in mm, mass %."""
    t = doc["truth"]
    out = {}
    for k in TERMS:
        tv = t["inertia_kgm2"]["value"][k]
        out[k] = 100 * (doc["inertia_kgm2"]["value"][k] - tv) / abs(tv)
    cog = np.array(doc["cog_m"]["value"]) - np.array(t["cog_m"]["value"])
    out["cog_mm"] = float(1e3 * np.linalg.norm(cog))
    if doc.get("mass_kg"):
        out["mass_%"] = (
            100 * (doc["mass_kg"]["value"] - t["mass_kg"]["value"]) / t["mass_kg"]["value"]
        )
    return out


def covered(doc: dict[str, Any]) -> dict[str, bool]:
    t = doc["truth"]
    out = {}
    for k in TERMS:
        lo, hi = doc["inertia_kgm2"]["ci95"][k]
        out[k] = lo <= t["inertia_kgm2"]["value"][k] <= hi
    for i, axis in enumerate("xyz"):
        v, s = doc["cog_m"]["value"][i], doc["cog_m"]["std"][i]
        out[f"G{axis}"] = abs(v - t["cog_m"]["value"][i]) <= 1.96 * s
    return out


def line(label: str, err: dict[str, float]) -> str:
    terms = "  ".join(f"{k} {err[k]:+6.2f}%" for k in TERMS)
    extra = f"  cog {err['cog_mm']:.2f} mm"
    if "mass_%" in err:
        extra += f"  mass {err['mass_%']:+.2f}%"
    return f"{label:28} {terms}{extra}"


ELASTIC_140 = {"frequency_hz": 140.0, "damping_ratio": 0.03, "participation": 0.1}
