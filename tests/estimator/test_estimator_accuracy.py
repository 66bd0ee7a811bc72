"""Issue-4 accuracy through the whole chain: simulated bench -> real dsp -> estimator.

i3 example, sweep 1500 -> 4500 rpm in 60 s, accelerometers at 5120 Hz.
Errors of products of inertia are relative to their own value.
"""

from __future__ import annotations

import re
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
import pytest
from support.estimator_runs import I3, cog_error_m, rel_errors, run

from ptinertia.config import ConfigError, load_bench, loads_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import RunOptions, make_estimator, run_source
from ptinertia.sources import REALISTIC_SIMULATION, open_source

I4 = EXAMPLES_DIR / "i4-bench.toml"
REALISTIC = REALISTIC_SIMULATION


@pytest.fixture(scope="module")
def noise_free() -> dict[str, Any]:
    return run(I3)


def test_noise_free_i3_every_term_within_0_2_percent(noise_free: dict[str, Any]) -> None:
    errs = rel_errors(noise_free)
    assert max(abs(e) for e in errs.values()) < 0.002, errs
    assert np.all(cog_error_m(noise_free) < 0.0005)
    assert noise_free["frames"]["used"] > 1400  # every other revolution (720 deg apart)


def test_noise_free_i3_converged_by_3000_rpm() -> None:
    doc = run(I3, rpm_max=3000.0)
    assert doc["rpm_range"][1] <= 3000.0
    errs = rel_errors(doc)
    assert max(abs(e) for e in errs.values()) < 0.002, errs
    assert np.all(cog_error_m(doc) < 0.0005)


def test_i4_mass_from_the_order_two_free_force() -> None:
    doc = run(I4)
    assert doc["mass_kg"] is not None
    assert doc["mass_kg"]["value"] == pytest.approx(doc["truth"]["mass_kg"]["value"], rel=0.01)


def _realistic(seed: int) -> dict[str, Any]:
    return run(I3, {**REALISTIC, "seed": seed})


@pytest.fixture(scope="module")
def realistic_runs() -> list[dict[str, Any]]:
    with ProcessPoolExecutor(max_workers=2) as pool:
        return list(pool.map(_realistic, range(20)))


@pytest.mark.slow
def test_realistic_intervals_contain_the_truth_in_90_percent_of_seeds(
    realistic_runs: list[dict[str, Any]],
) -> None:
    def covers(doc: dict[str, Any]) -> bool:
        truth = doc["truth"]["inertia_kgm2"]["value"]
        ok = all(lo <= truth[k] <= hi for k, (lo, hi) in doc["inertia_kgm2"]["ci95"].items())
        std = np.array(doc["cog_m"]["std"])
        return ok and bool(np.all(cog_error_m(doc) <= 1.96 * std))

    assert sum(covers(d) for d in realistic_runs) >= 18


@pytest.fixture(scope="module")
def realistic_default(realistic_runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The realistic scenario with the example's own seed (1): the run the README quotes."""
    return realistic_runs[1]


@pytest.mark.slow
def test_realistic_run_principal_terms_cog_and_unbalance(realistic_default: dict[str, Any]) -> None:
    # The 2 % / 3 mm / 10 % figures are checked on the scenario run; over 20 seeds the
    # sensor errors are drawn anew and the honest check is the interval coverage above
    # (benchmarks/bench_estimator.py prints the error distribution over the seeds).
    errs = rel_errors(realistic_default)
    assert max(abs(errs[k]) for k in ("Ixx", "Iyy", "Izz")) < 0.02, errs
    assert np.all(cog_error_m(realistic_default) < 0.003)
    unb = realistic_default["unbalance"]
    assert unb is not None
    assert unb["mr_kgm"]["value"] == pytest.approx(5e-4, rel=0.10)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="products of inertia within 2 % of their own value need the sensor positions to "
    "0.5 mm, not 2 mm; [estimator] self_calibration gets the angles and gains from the sweep "
    "(Ixy/Ixz/Iyz mean 1.0/0.4/5.0 %) but cannot tell the positions from them with three "
    "sensors (see README, accuracy; benchmarks/bench_sensor_positions.py)",
)
def test_realistic_run_products_within_2_percent_of_their_own_value(
    realistic_default: dict[str, Any],
) -> None:
    errs = rel_errors(realistic_default)
    assert max(abs(errs[k]) for k in ("Ixy", "Ixz", "Iyz")) < 0.02, errs


ELASTIC = {"frequency_hz": 140.0, "damping_ratio": 0.03, "participation": 0.1}


@pytest.fixture(scope="module")
def elastic_run() -> dict[str, Any]:
    """Realistic run with an elastic mode at 140 Hz, inside the sweep (H2 reaches 150 Hz)."""
    return run(I3, {**REALISTIC, "seed": 1, "elastic_mode": ELASTIC})


def test_elastic_mode_frames_are_rejected_and_the_principal_terms_hold(
    elastic_run: dict[str, Any],
) -> None:
    assert elastic_run["frames"]["orders_rejected"].get("non_rigid", 0) > 500
    errs = rel_errors(elastic_run)
    assert max(abs(errs[k]) for k in ("Ixx", "Iyy", "Izz")) < 0.02, errs


def test_elastic_mode_cog_within_the_realistic_3_mm(elastic_run: dict[str, Any]) -> None:
    # Below the mode, the part of its shape that looks rigid grows like f^2 and shifts
    # the cog (3.5 mm here) before the residual gate fires; once the gate confirms the
    # mode, the f^2 tail is fitted out and the 0 Hz value reported.
    assert elastic_run["elastic_mode"] is not None
    assert np.all(cog_error_m(elastic_run) < 0.003)
    truth = elastic_run["truth"]["cog_m"]["value"]
    std = np.array(elastic_run["cog_m"]["std"])
    assert np.all(np.abs(np.array(elastic_run["cog_m"]["value"]) - truth) <= 1.96 * std)


@pytest.mark.slow
def test_no_elastic_mode_no_tail(
    noise_free: dict[str, Any], realistic_default: dict[str, Any]
) -> None:
    assert noise_free["elastic_mode"] is None and realistic_default["elastic_mode"] is None


def test_a_fast_sweep_just_above_the_modes_is_refused(noise_free: dict[str, Any]) -> None:
    # 600 -> 900 rpm in 5 s: H2 just above the rigid-body modes, H1 and H1.5 among them.
    # The dsp's cycle-long window cannot follow the bending response, and the bending
    # orders leak into H2: every frame is rejected rather than estimated wrongly.
    bench = load_bench(I3)
    source = open_source("sim", bench, rpm_start=600.0, rpm_end=900.0, duration_s=5.0)
    summary, doc = run_source(bench, I3.read_text(), source, "sim", RunOptions(quiet=True))
    assert doc is None
    bent = summary.orders_rejected
    assert bent.get("off_mass_line", 0) + bent.get("neighbour_leakage", 0) >= 10, bent
    for reason in ("off_mass_line", "neighbour_leakage"):
        assert reason not in noise_free["frames"]["orders_rejected"]


def test_a_quick_sweep_just_above_the_modes_keeps_honest_intervals() -> None:
    # The same range in 10 s: the frames that bend or leak most are rejected, the rest
    # carry the dsp's error as a floor, and every 95 % interval still holds the truth
    # (without the leakage floor Ixz came out 9 % off with an interval of +-8 %).
    doc = run(I3, {"rpm_start": 600.0, "rpm_end": 900.0, "duration_s": 10.0})
    assert doc["frames"]["orders_rejected"].get("neighbour_leakage", 0) >= 5
    truth = doc["truth"]["inertia_kgm2"]["value"]
    for term, (lo, hi) in doc["inertia_kgm2"]["ci95"].items():
        assert lo <= truth[term] <= hi, term


def _stiffer_mounts(text: str, factor: float) -> str:
    def scale(m: Any) -> str:
        vals = [float(v) * factor for v in m.group(1).split(",")]
        return "stiffness_kn_per_m = [" + ", ".join(f"{v:.3f}" for v in vals) + "]"

    return re.sub(r"stiffness_kn_per_m = \[([^\]]*)\]", scale, text)


@pytest.mark.parametrize("scaled", [False, True])
def test_mount_stiffness_30_percent_off_is_estimated_as_a_scale(scaled: bool) -> None:
    # The bench's mounts are 30 % stiffer than its file says. With known stiffness the
    # mount reactions are wrong and Ixx comes out ~3 % low (products up to 26 %); with
    # one scale per mount estimated (reactions scale like 1 / (h omega)^2, the inertia
    # terms do not) the sweep separates them and the scales come out as 1.3.
    text = I3.read_text()
    sim = open_source("sim", loads_bench(_stiffer_mounts(text, 1.3), "stiffer.toml"))
    est_text = text + ("\n[estimator]\nmount_scale = true\n" if scaled else "")
    bench = loads_bench(est_text, "bench.toml")
    _, doc = run_source(bench, est_text, sim, "sim", RunOptions(quiet=True))
    assert doc is not None
    errs = rel_errors(doc)
    if scaled:
        assert max(abs(e) for e in errs.values()) < 0.002, errs
        assert np.all(cog_error_m(doc) < 0.0005)
        for name, s in doc["mount_stiffness_scale"].items():
            assert s["value"] == pytest.approx(1.3, rel=0.01), name
    else:
        assert doc["mount_stiffness_scale"] is None
        assert max(abs(e) for e in errs.values()) > 0.02, errs


def test_mount_scale_with_an_estimated_mass_is_a_bench_error() -> None:
    bench = loads_bench(I4.read_text() + "\n[estimator]\nmount_scale = true\n", "i4.toml")
    with pytest.raises(ConfigError, match="mount_scale"):
        make_estimator(bench)
