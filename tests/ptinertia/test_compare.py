"""``ptinertia compare``: the shared result document and the side-by-side table."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ptinertia.cli import main
from ptinertia.errors import UsageError
from ptinertia.estimates import compare_estimates as compare
from ptinertia.estimates import estimate_document, read_estimate
from ptinertia.paths import EXAMPLES_DIR

TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def insitu_like(path, mass=None, std_scale=1.0, shift=0.0):
    """A document shaped like ``ptinertia run --json`` (nulls where unobservable)."""
    doc = {
        "method": "insitu",
        "inertia_kgm2": {
            "value": {
                "Ixx": 4.62 + shift,
                "Iyy": 3.08,
                "Izz": 4.25,
                "Ixy": 0.27,
                "Ixz": -0.41,
                "Iyz": 0.2,
            },
            "std": {
                "Ixx": 0.01 * std_scale,
                "Iyy": 0.01,
                "Izz": 0.02,
                "Ixy": 0.005,
                "Ixz": 0.005,
                "Iyz": None,
            },
        },
        "cog_m": {"value": [0.036, -0.084, 0.104], "std": [0.001, None, 0.001]},
        "mass_kg": mass,
        "frames": {"used": 100},
    }
    path.write_text(json.dumps(doc))
    return path


def test_document_has_the_shared_shape_and_principal_moments():
    terms = np.array([4.0, 3.0, 5.0, 0.0, 0.0, 0.0])
    doc = estimate_document("x", terms, np.full(6, 0.01), np.zeros(3), np.full(3, 1e-3), 100.0, 0.1)
    assert doc["principal"]["moments_kgm2"] == pytest.approx([3.0, 4.0, 5.0])
    assert doc["inertia_kgm2"]["ci95"]["Ixx"] == pytest.approx(
        [4.0 - 0.0196, 4.0 + 0.0196], rel=1e-4
    )
    assert doc["mass_kg"] == {"value": 100.0, "std": 0.1}
    json.dumps(doc)  # plain JSON


def test_differences_z_and_overlap_by_hand(tmp_path):
    a = read_estimate(str(insitu_like(tmp_path / "a.json")))
    b = read_estimate(
        str(insitu_like(tmp_path / "b.json", mass={"value": 110.0, "std": 0.5}, shift=0.05))
    )
    data = compare([("a", a), ("b", b)])
    rows = {r["quantity"]: r for r in data["rows"]}
    ixx = rows["Ixx"]["differences"][0]
    # 4.67 - 4.62 = 0.05; combined std sqrt(2) 0.01; 95 % half-widths 0.0196 each: no overlap.
    assert ixx["difference"] == pytest.approx(0.05)
    assert ixx["z"] == pytest.approx(0.05 / (math.sqrt(2) * 0.01))
    assert ixx["overlap"] is False
    iyy = rows["Iyy"]["differences"][0]
    assert iyy["difference"] == 0 and iyy["z"] == 0 and iyy["overlap"] is True
    # Unobservable (null std) and absent (null mass) quantities are not compared.
    assert rows["Iyz"]["differences"][0]["z"] is None
    assert rows["cog y"]["differences"][0]["overlap"] is None
    assert rows["mass"]["differences"][0]["difference"] is None
    assert rows["mass"]["estimates"][1] == {"name": "b", "value": 110.0, "std": 0.5}


def test_compare_command_with_the_bench_column(tmp_path, capsys):
    a = insitu_like(tmp_path / "a.json")
    out = tmp_path / "pendulum.json"
    assert main(["pendulum", str(EXAMPLES_DIR / "pendulum-test.toml"), "--json", str(out)]) == 0
    capsys.readouterr()
    table_json = tmp_path / "cmp.json"
    code = main(
        [
            "compare",
            str(a),
            str(out),
            "--bench",
            str(EXAMPLES_DIR / "i3-bench.toml"),
            "--json",
            str(table_json),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    header = text.splitlines()[0]
    assert "bench (95 %)" in header and "insitu (95 %)" in header and "pendulum (95 %)" in header
    assert "insitu - bench" in header and "pendulum - bench" in header
    data = json.loads(table_json.read_text())
    assert data["reference"] == "bench" and data["columns"] == ["bench", "insitu", "pendulum"]
    ixx = next(r for r in data["rows"] if r["quantity"] == "Ixx")
    # Against the bench (no interval) the overlap is "the bench value is inside the interval".
    assert ixx["differences"][0]["overlap"] == (abs(4.62 - 4.6) <= 1.96 * 0.01)


def test_compare_refuses_what_is_not_a_result(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"hello": 1}))
    a = insitu_like(tmp_path / "a.json")
    assert main(["compare", str(a), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "not a result document (no inertia_kgm2 table)" in err
    assert main(["compare", str(a)]) == 2
    assert "at least two columns" in capsys.readouterr().err
    with pytest.raises(UsageError, match="cannot read"):
        read_estimate(str(tmp_path / "missing.json"))
