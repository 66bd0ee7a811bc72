"""``ptinertia export``: bench-file TOML, JSON/CSV tables and the Nastran CONM2 card.

The CONM2 test reads the card back with a small parser written here from the
Nastran Quick Reference Guide (large-field entries: 8-character field 1, then
16-character fields; the inertia matrix about the cog is
``[[I11, -I21, -I31], [-I21, I22, -I32], [-I31, -I32, I33]]`` with
``I21 = integral(x1 x2 dm)``) and compares it with the tensor of a cloud of point
masses computed directly as ``sum m (|r|^2 1 - r r^T)``: no ptinertia convention
is trusted on either side.
"""

from __future__ import annotations

import csv
import io
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from support.report_logs import realistic_log

from ptinertia.cli import main
from ptinertia.config import loads_bench
from ptinertia.errors import UsageError
from ptinertia.export import properties_from_result, to_conm2, to_csv, to_json, to_toml
from ptinertia.paths import DEFAULT_BENCH

TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def point_cloud() -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, cog and inertia tensor about the cog of 40 point masses, from the definitions."""
    rng = np.random.default_rng(11)
    m = rng.uniform(0.5, 4.0, 40)
    p = rng.normal([0.03, -0.08, 0.1], [0.3, 0.2, 0.15], (40, 3))
    p[:, 1] += 0.4 * p[:, 0]  # make every product of inertia clearly non-zero
    p[:, 2] += 0.3 * p[:, 0] + 0.6 * p[:, 1]
    mass = float(m.sum())
    cog = (m[:, None] * p).sum(axis=0) / mass
    r = p - cog
    tensor = sum(mi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for mi, ri in zip(m, r, strict=True))
    return mass, cog, tensor


def doc_of(mass: float | None, cog: np.ndarray, tensor: np.ndarray) -> dict:
    """A result document holding these properties, with ptinertia's Ixy = integral(x y dm) = -I[0, 1]."""
    terms = {
        "Ixx": tensor[0, 0],
        "Iyy": tensor[1, 1],
        "Izz": tensor[2, 2],
        "Ixy": -tensor[0, 1],
        "Ixz": -tensor[0, 2],
        "Iyz": -tensor[1, 2],
    }
    moments, axes = np.linalg.eigh(tensor)
    return {
        "inertia_kgm2": {"value": terms, "std": {k: 0.01 for k in TERMS}},
        "cog_m": {"value": cog.tolist(), "std": [0.002] * 3},
        "mass_kg": None if mass is None else {"value": mass, "std": 0.5},
        "principal": {"moments_kgm2": moments.tolist(), "axes": axes.T.tolist()},
        "frames": {"used": 100},
        "rpm_range": [1500.0, 4500.0],
        "source": "sim",
    }


def parse_conm2(text: str) -> dict[str, float | int]:
    """Read a large-field CONM2 (``CONM2*`` + ``*`` continuations) into its named fields."""
    fields: list[str] = []
    for line in text.splitlines():
        if not line.strip() or line.startswith("$"):
            continue
        head, body = line[:8].strip(), line[8:72]
        assert head in ("CONM2*", "*"), f"unexpected line {line!r}"
        fields += [body[i : i + 16].strip() for i in range(0, 64, 16)]
    names = ["EID", "G", "CID", "M", "X1", "X2", "X3", "", "I11", "I21", "I22", "I31", "I32", "I33"]
    out: dict[str, float | int] = {}
    for name, raw in zip(names, fields, strict=False):
        if not name:
            continue
        out[name] = int(raw) if name in ("EID", "G", "CID") else float(raw or 0.0)
    return out


def nastran_tensor(card: dict[str, float | int]) -> np.ndarray:
    """The inertia matrix Nastran builds from the card (QRG, CONM2 remark)."""
    i11, i21, i22, i31, i32, i33 = (
        float(card[k]) for k in ("I11", "I21", "I22", "I31", "I32", "I33")
    )
    return np.array([[i11, -i21, -i31], [-i21, i22, -i32], [-i31, -i32, i33]])


def test_conm2_read_back_gives_the_body_tensor() -> None:
    mass, cog, tensor = point_cloud()
    assert (
        min(abs(tensor[0, 1]), abs(tensor[0, 2]), abs(tensor[1, 2])) > 0.05 * np.trace(tensor) / 3
    )
    card = parse_conm2(to_conm2(properties_from_result(doc_of(mass, cog, tensor)), eid=7, grid=42))
    assert (card["EID"], card["G"], card["CID"]) == (7, 42, -1)
    assert card["M"] == pytest.approx(mass, rel=1e-8)
    np.testing.assert_allclose([card["X1"], card["X2"], card["X3"]], cog, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(nastran_tensor(card), tensor, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("field", ["I21", "I31", "I32"])
def test_a_product_of_inertia_sign_flip_is_caught(field: str) -> None:
    mass, cog, tensor = point_cloud()
    card = parse_conm2(to_conm2(properties_from_result(doc_of(mass, cog, tensor))))
    card[field] = -float(card[field])  # what a writer with the tensor-entry convention produces
    assert not np.allclose(nastran_tensor(card), tensor, rtol=1e-3)


def test_conm2_units_and_grid_offset() -> None:
    mass, cog, tensor = point_cloud()
    p = properties_from_result(doc_of(mass, cog, tensor))
    grid = (0.1, 0.2, -0.05)
    card = parse_conm2(to_conm2(p, grid_at=grid, units="mm-t-s"))
    assert card["CID"] == 0
    assert card["M"] == pytest.approx(mass / 1000.0, rel=1e-8)  # t
    np.testing.assert_allclose(
        [card["X1"], card["X2"], card["X3"]], (cog - grid) * 1000.0, rtol=1e-8
    )  # mm
    np.testing.assert_allclose(
        nastran_tensor(card), tensor * 1e3, rtol=1e-8
    )  # 1 kg m^2 = 1e3 t mm^2


def test_conm2_needs_a_mass() -> None:
    _, cog, tensor = point_cloud()
    with pytest.raises(UsageError, match="--mass"):
        to_conm2(properties_from_result(doc_of(None, cog, tensor)))
    card = parse_conm2(to_conm2(properties_from_result(doc_of(None, cog, tensor), mass=99.5)))
    assert card["M"] == pytest.approx(99.5)


def test_toml_fragment_replaces_the_bench_powertrain() -> None:
    mass, cog, tensor = point_cloud()
    fragment = to_toml(properties_from_result(doc_of(mass, cog, tensor)))
    table = tomllib.loads(fragment)["powertrain"]
    assert table["mass_known"] is False  # an estimated mass stays estimated
    text = DEFAULT_BENCH.read_text(encoding="utf-8")
    start = text.index("[powertrain]")
    end = text.index("[[mounts]]")
    bench = loads_bench(text[:start] + fragment + "\n" + text[end:])
    np.testing.assert_allclose(bench.powertrain.inertia_kgm2.matrix(), tensor, rtol=1e-12)
    np.testing.assert_allclose(bench.powertrain.cog_m, cog, rtol=1e-12)
    assert bench.powertrain.mass_kg == mass


def test_tables_hold_values_and_intervals() -> None:
    mass, cog, tensor = point_cloud()
    p = properties_from_result(doc_of(mass, cog, tensor))
    doc = json.loads(to_json(p))
    np.testing.assert_allclose(doc["tensor_kgm2"], tensor, rtol=1e-12)
    q = doc["quantities"]
    assert q["Ixy"]["value"] == pytest.approx(-tensor[0, 1])
    assert q["Ixy"]["ci95"] == pytest.approx(
        [-tensor[0, 1] - 1.959964 * 0.01, -tensor[0, 1] + 1.959964 * 0.01]
    )
    rows = {r["quantity"]: r for r in csv.DictReader(io.StringIO(to_csv(p)))}
    assert float(rows["Gz"]["value"]) == cog[2]
    assert float(rows["mass"]["ci95_high"]) == pytest.approx(mass + 1.959964 * 0.5)
    assert rows["I1"]["std"] == ""
    axes = np.array([[float(rows[f"axis{j}_{c}"]["value"]) for c in "xyz"] for j in (1, 2, 3)])
    moments = np.array([float(rows[f"I{j}"]["value"]) for j in (1, 2, 3)])
    np.testing.assert_allclose(axes.T @ np.diag(moments) @ axes, tensor, atol=1e-10)


def test_cli_on_the_realistic_run(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log, doc_path = realistic_log(tmp_path_factory)
    doc = json.loads(doc_path.read_text(encoding="utf-8"))
    # the i3's mass is not observable: a CONM2 needs it from somewhere
    assert main(["export", str(doc_path), "--format", "nastran"]) == 2
    assert "--mass" in capsys.readouterr().err
    out = tmp_path / "pt.bdf"
    assert (
        main(
            [
                "export",
                str(doc_path),
                "--format",
                "nastran",
                "--bench",
                str(DEFAULT_BENCH),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    card = parse_conm2(out.read_text(encoding="utf-8"))
    assert card["M"] == pytest.approx(110.0)
    ours = doc["inertia_kgm2"]["value"]
    expected = np.array(
        [
            [ours["Ixx"], -ours["Ixy"], -ours["Ixz"]],
            [-ours["Ixy"], ours["Iyy"], -ours["Iyz"]],
            [-ours["Ixz"], -ours["Iyz"], ours["Izz"]],
        ]
    )
    np.testing.assert_allclose(nastran_tensor(card), expected, rtol=1e-8)
    # from the recording itself, the bench's weighed mass comes with it
    assert main(["export", str(log), "--format", "toml"]) == 0
    table = tomllib.loads(capsys.readouterr().out)["powertrain"]
    assert table["mass_kg"] == 110.0 and table["mass_known"] is True
    assert table["inertia_kgm2"]["Ixz"] == ours["Ixz"]
