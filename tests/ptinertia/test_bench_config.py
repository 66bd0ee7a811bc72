"""The bench file: examples load, every bad input gives one line naming the key."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from ptinertia.config import ConfigError, load_bench, loads_bench
from ptinertia.paths import EXAMPLES_DIR

I3 = EXAMPLES_DIR / "i3-bench.toml"
I4 = EXAMPLES_DIR / "i4-bench.toml"


@pytest.mark.parametrize("path", [I3, I4])
def test_examples_load_in_si(path: Path) -> None:
    bench = load_bench(path)
    assert 0.04 < bench.engine.stroke_m < 0.1  # converted from stroke_mm
    assert all(s > 1e4 for m in bench.mounts for s in m.stiffness_n_per_m)  # from kN/m
    assert len(bench.sensors) == 3


def test_i3_example_is_a_transverse_one_litre_three() -> None:
    b = load_bench(I3)
    e = b.engine
    displacement = e.cylinders * np.pi / 4 * e.bore_m**2 * e.stroke_m
    assert e.cylinders == 3 and 0.95e-3 < displacement < 1.05e-3
    assert e.crank_axis == [0.0, 1.0, 0.0]  # transverse: crank along bench Y
    assert 100 <= b.powertrain.mass_kg <= 120
    terms = b.powertrain.inertia_kgm2
    assert min(abs(terms.Ixy), abs(terms.Ixz), abs(terms.Iyz)) > 0.05  # non-trivial products


def _bad(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


BASE = I3.read_text()

BAD_CASES = [
    ("unknown key", "bore_mm = 71.0", "boar_mm = 71.0", r"engine\.boar_mm: unknown key"),
    ("missing unit", "stroke_mm = 84.1", "stroke = 84.1", r"engine: stroke: missing unit"),
    ("lambda >= 1", "conrod_length_mm = 133.0", "conrod_length_mm = 40.0", r"lambda must be < 1"),
    (
        "non-orthogonal axes",
        "axes = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]",
        "axes = [[0.0, 1.0, 0.0], [-1.0, 0.5, 0.0], [0.0, 0.0, 1.0]]",
        r"sensors\[1\]\.axes: .*orthonormal",
    ),
    (
        "non-positive-definite inertia",
        "Ixx = 4.60",
        "Ixx = -4.60",
        r"powertrain\.inertia_kgm2\.Ixx: .*greater than 0",
    ),
    (
        "triangle inequality",
        "Ixx = 4.60",
        "Ixx = 0.60",
        r"powertrain\.inertia_kgm2: .*triangle inequality",
    ),
    (
        "firing order vs throws",
        "throw_angles_deg = [0.0, 240.0, 120.0]",
        "throw_angles_deg = [0.0, 120.0, 240.0]",
        r"engine: throw_angles_deg: cylinder 2 fires 240 deg",
    ),
    ("not TOML", "[meta]", "[meta", r"not valid TOML"),
]


@pytest.mark.parametrize(
    ("label", "old", "new", "pattern"), BAD_CASES, ids=[c[0] for c in BAD_CASES]
)
def test_bad_bench_gives_one_line_naming_the_key(
    label: str, old: str, new: str, pattern: str
) -> None:
    with pytest.raises(ConfigError) as info:
        loads_bench(_bad(BASE, old, new), "bench.toml")
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("bench.toml: ")
    assert re.search(pattern, message), message


def test_sensors_at_one_point_refused() -> None:
    # Move B and C onto A: no rotation can be seen. (Two positions are accepted: the
    # rotation about their line is fitted per frame, see tests/estimator/test_two_sensors.py.)
    a = "position_m = [0.05, 0.30, 0.29]"
    text = _bad(BASE, "position_m = [-0.26, -0.02, -0.12]", a)
    text = _bad(text, "position_m = [0.02, -0.42, 0.25]", a)
    with pytest.raises(ConfigError, match=r"sensors: need at least two sensors at distinct"):
        loads_bench(text, "bench.toml")


def test_unit_alternatives_are_scaled_to_si() -> None:
    text = _bad(BASE, "bore_mm = 71.0", "bore_m = 0.071")
    text = _bad(text, "intake_pressure_bar = 0.45", "intake_pressure_pa = 45000.0")
    a, b = loads_bench(text), loads_bench(BASE)
    assert a.engine.bore_m == pytest.approx(b.engine.bore_m, rel=1e-12)
    assert a.gas.intake_pressure_pa == pytest.approx(b.gas.intake_pressure_pa, rel=1e-12)


def test_same_key_in_two_units_refused() -> None:
    text = _bad(BASE, "bore_mm = 71.0", "bore_mm = 71.0\nbore_m = 0.071")
    with pytest.raises(ConfigError, match="given twice"):
        loads_bench(text, "bench.toml")


def test_missing_file_is_one_line() -> None:
    with pytest.raises(ConfigError, match=r"nope\.toml: cannot read bench file"):
        load_bench("nope.toml")
