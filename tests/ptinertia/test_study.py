"""Monte Carlo studies: draws from (seed, run index) only, same numbers on 1 and 2 workers."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from ptinertia.batch.study import DEFAULT_VARY, draw_run, parse_vary, run_seeds
from ptinertia.cli import main
from ptinertia.config import Bench, Simulation
from ptinertia.errors import UsageError
from ptinertia.to_physics import build_simulated_model

LAYOUTS = """
[[layouts]]
name = "two sensors"

[[layouts.sensors]]
name = "A_engine_mount"
position_m = [0.05, 0.30, 0.29]
channels = ["A_x", "A_y", "A_z"]

[[layouts.sensors]]
name = "C_rod"
position_m = [-0.28, -0.02, -0.12]
channels = ["C_x", "C_y", "C_z"]
"""


def test_each_run_draws_from_the_seed_and_its_index_only(i3: Bench) -> None:
    few = [draw_run(i3, DEFAULT_VARY, s) for s in run_seeds(7, 3)]
    many = [draw_run(i3, DEFAULT_VARY, s) for s in run_seeds(7, 10)]
    assert few == many[:3]
    assert len({d["seed"] for d in many}) == 10
    other = [draw_run(i3, DEFAULT_VARY, s) for s in run_seeds(8, 3)]
    assert other != few


def test_draws_follow_the_declared_tolerances(i3: Bench) -> None:
    d = draw_run(i3, ("gain", "alignment", "position"), run_seeds(0, 1)[0])
    tol = i3.estimator
    assert d["gain_error_pct"] == tol.gain_tolerance_pct
    assert d["misalignment_deg"] == tol.alignment_tolerance_deg
    assert d["position_error_m"] == tol.position_tolerance_m
    assert "noise_snr_db" not in d and "residual_unbalance_kgm" not in d


def test_model_inputs_are_drawn_from_their_declared_tolerances_and_simulated(i3: Bench) -> None:
    vary = ("gas", "spin_inertia", "masses", "mounts")
    draws = [draw_run(i3, vary, s) for s in run_seeds(3, 400)]
    tol = i3.estimator
    for key, sigma in (
        ("heat_release_error_pct", tol.gas_tolerance_pct),
        ("spin_inertia_error_pct", tol.spin_inertia_tolerance_pct),
        ("piston_mass_error_pct", tol.piston_mass_tolerance_pct),
        ("conrod_mass_error_pct", tol.conrod_mass_tolerance_pct),
    ):
        v = np.array([d[key] for d in draws])
        assert np.std(v) == pytest.approx(sigma, rel=0.12), key  # 400 draws: 3.5 % 1-sigma
        assert abs(np.mean(v)) < 0.2 * sigma, key
    mounts = np.array([d["mount_stiffness_error_pct"] for d in draws])
    assert mounts.shape == (400, len(i3.mounts))
    assert np.std(mounts, axis=0) == pytest.approx(tol.mount_stiffness_tolerance_pct, rel=0.12)
    assert abs(np.corrcoef(mounts.T)[0, 1]) < 0.15  # each mount on its own
    # varying the model inputs leaves the sensor draws (and the run's seed) as they were
    assert [d["seed"] for d in draws[:5]] == [
        draw_run(i3, DEFAULT_VARY, s)["seed"] for s in run_seeds(3, 5)
    ]
    # the simulator builds what was drawn
    d = draws[0]
    sim = Simulation.model_validate({**i3.simulation.model_dump(), **d})
    model, truth = build_simulated_model(i3, sim)
    e = i3.engine
    assert truth["crank_spin_inertia_kgm2"] == pytest.approx(
        e.crank_spin_inertia_kgm2 * (1 + d["spin_inertia_error_pct"] / 100)
    )
    assert truth["piston_mass_kg"] == pytest.approx(
        e.piston_mass_kg * (1 + d["piston_mass_error_pct"] / 100)
    )
    assert model.engine.conrod_mass == pytest.approx(
        e.conrod_mass_kg * (1 + d["conrod_mass_error_pct"] / 100)
    )
    for m, built, pct in zip(i3.mounts, model.mounts, d["mount_stiffness_error_pct"], strict=True):
        assert built.stiffness == pytest.approx(np.array(m.stiffness_n_per_m) * (1 + pct / 100))


def test_vary_names() -> None:
    assert parse_vary(None) == DEFAULT_VARY
    assert parse_vary("gain,mounts,gas") == ("gain", "mounts", "gas")
    with pytest.raises(UsageError, match="'wind'"):
        parse_vary("gain,wind")


def _study(out: Path, workers: int, layouts: Path) -> int:
    argv = ["study", "--runs", "3", "--duration", "3", "--seed", "5", "--quiet"]
    return main([*argv, "--layouts", str(layouts), "--workers", str(workers), "--out", str(out)])


def test_a_study_gives_the_same_numbers_on_one_and_two_workers(tmp_path: Path) -> None:
    layouts = tmp_path / "layouts.toml"
    layouts.write_text(LAYOUTS)
    one, two = tmp_path / "one", tmp_path / "two"
    assert _study(one, 1, layouts) == 0
    assert _study(two, 2, layouts) == 0
    for name in ("study.csv", "runs.csv", "layouts.csv"):
        assert (one / name).read_bytes() == (two / name).read_bytes(), name
    stats = list(csv.DictReader((one / "study.csv").open()))
    assert {r["layout"] for r in stats} == {"bench", "two sensors"}
    assert {r["term"] for r in stats} >= {"Ixx", "Iyz", "Gx", "Gz"}
    for r in stats:
        assert int(r["runs"]) == 3 and 0.0 <= float(r["coverage95"]) <= 1.0
    ranking = list(csv.DictReader((one / "layouts.csv").open()))
    assert [r["rank"] for r in ranking] == ["1", "2"]
    assert float(ranking[0]["inertia_rms_pct"]) <= float(ranking[1]["inertia_rms_pct"])
    assert (one / "study.png").stat().st_size > 1000


def test_bad_study_inputs_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (
        ["--vary", "gain,wind"],
        ["--runs", "0"],
        ["--duration", "-1"],  # refused by argparse, before any run is drawn
        ["--duration", "nan"],
        ["--seed", "-1"],
        ["--layouts", str(tmp_path / "missing.toml")],
        ["--scheduler", "tcp://nowhere"],
    ):
        try:
            code = main(["study", "--out", str(tmp_path / "o"), "--quiet", *argv])
        except SystemExit as stop:  # argparse's own one line
            code = stop.code
        err = capsys.readouterr().err.strip()
        assert code == 2, argv
        assert "\n" not in err and "Traceback" not in err, err


def test_layouts_file_is_read_as_a_bench_file_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], i3: Bench
) -> None:
    """UTF-8 with a byte order mark (Windows editors) reads as without; not UTF-8 is one
    line naming the file and the byte (it was a UnicodeDecodeError traceback)."""
    from ptinertia.batch.study import load_layouts

    bench = i3
    plain, bom, latin = tmp_path / "plain.toml", tmp_path / "bom.toml", tmp_path / "latin.toml"
    plain.write_text(LAYOUTS, encoding="utf-8")
    bom.write_bytes(b"\xef\xbb\xbf" + LAYOUTS.encode())
    latin.write_bytes(("# Kapazit\u00e4t\n" + LAYOUTS).encode("latin-1"))
    assert load_layouts(str(bom), bench) == load_layouts(str(plain), bench)
    assert len(load_layouts(str(plain), bench)) > 1
    code = main(["study", "--out", str(tmp_path / "o"), "--quiet", "--layouts", str(latin)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert "\n" not in err and "not UTF-8" in err and "latin.toml" in err, err
