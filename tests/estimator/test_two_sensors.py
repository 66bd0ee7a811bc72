"""Two usable sensors: the rotation about their line is unseen and fitted per frame.

Checked against the independent forward model of ``estimator_harness`` (exact
data give the body back whichever sensor is lost, from a start far from it),
against finite differences (the projected Jacobian gives the exact gradient)
and end to end through the simulator, the dsp and the CLI with a dead sensor.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support.estimator_harness import Body, Frame, frames, make_setup

from estimator.channel_fits import UNSEEN_AFTER_FRAMES
from estimator.partial import PartialRows, project_out
from estimator.streaming import InertiaEstimator

RPMS = np.linspace(1500, 4500, 120)
ROOT = Path(__file__).resolve().parents[2]


def _lose_sensor(sensor: int, f: Frame) -> Frame:
    ok = f.channel_ok.copy()
    ok[3 * sensor : 3 * sensor + 3] = False
    amps = f.amplitudes.copy()
    amps[:, 3 * sensor : 3 * sensor + 3] = np.nan
    return dataclasses.replace(f, channel_ok=ok, amplitudes=amps)


def _far_setup(body: Body):
    """Nominal values far from the body: isotropic inertia 1.5x its mean, cog 10 cm off."""
    setup = make_setup(body)
    return dataclasses.replace(
        setup,
        inertia_nominal=1.5 * np.trace(body.inertia) / 3 * np.eye(3),
        cog_nominal=body.cog + 0.1,
    )


@pytest.mark.parametrize("lost", [0, 1, 2])
def test_exact_data_from_two_sensors_give_the_body_back(lost: int) -> None:
    body = Body(unbalance=4e-4 * np.exp(-1j * np.radians(30.0)))
    est = InertiaEstimator(_far_setup(body))
    for f in frames(body, RPMS):
        est.update(_lose_sensor(lost, f))
    e = est.estimate()
    # the first frames without the sensor are rejected until the loss has lasted
    assert e.frames_used == len(RPMS) - (UNSEEN_AFTER_FRAMES - 1)
    assert e.frames_rejected == {"sensor_geometry": UNSEEN_AFTER_FRAMES - 1}
    np.testing.assert_allclose(e.inertia, body.inertia, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e.cog, body.cog, rtol=0, atol=1e-10)
    unb = e.unbalance()
    assert unb is not None and unb["mr_kgm"]["value"] == pytest.approx(4e-4, rel=1e-6)
    assert e.unseen_motion["converged"]
    assert e.unseen_motion["pairs"] == 3 * e.frames_used
    # the unseen rotation is about the line through the two sensors left
    left = np.delete(
        np.array([[0.05, 0.30, 0.29], [0.02, -0.42, 0.25], [-0.26, -0.02, -0.12]]), lost, 0
    )
    line = (left[1] - left[0]) / np.linalg.norm(left[1] - left[0])
    assert abs(np.dot(e.unseen_motion["unseen_rotation_axis"], line)) == pytest.approx(
        1.0, abs=1e-9
    )
    offset = np.asarray(e.unseen_motion["unseen_rotation_point_m"]) - left[0]
    assert np.linalg.norm(offset - np.dot(offset, line) * line) < 1e-9


def test_a_sensor_lost_midway_keeps_both_kinds_of_frames() -> None:
    body = Body()
    est = InertiaEstimator(_far_setup(body))
    for i, f in enumerate(frames(body, RPMS)):
        est.update(_lose_sensor(2, f) if i >= len(RPMS) // 2 else f)
    e = est.estimate()
    assert e.unseen_motion["pairs"] == 3 * (len(RPMS) - len(RPMS) // 2 - UNSEEN_AFTER_FRAMES + 1)
    np.testing.assert_allclose(e.inertia, body.inertia, rtol=0, atol=1e-9)


def test_flush_timing_matters_from_the_first_frame_with_an_unseen_motion() -> None:
    # (a pipeline skips the estimates nobody reads only while it does not: ptinertia.pipeline)
    body = Body()
    est = InertiaEstimator(_far_setup(body))
    half = len(RPMS) // 2
    matters = []
    for i, f in enumerate(frames(body, RPMS[: half + UNSEEN_AFTER_FRAMES + 2])):
        outcome = est.update(_lose_sensor(2, f) if i >= half else f)
        matters.append((outcome.reason is None and i >= half, est.flush_timing_matters))
    first_unseen = half + UNSEEN_AFTER_FRAMES - 1  # (the earlier ones rejected)
    assert [m for _, m in matters] == [i >= first_unseen for i in range(len(matters))]
    assert matters[first_unseen][0]


def test_half_order_sign_without_a_reference_is_decided_by_the_unseen_motion_fit() -> None:
    body = Body()

    def lose_cycle(f: Frame) -> Frame:
        amps = f.amplitudes.copy()
        amps[1] *= -1  # H1.5 seen through phi + 360 deg
        return _lose_sensor(
            2, dataclasses.replace(f, amplitudes=amps, flags=frozenset({"cycle_ambiguous"}))
        )

    est = InertiaEstimator(_far_setup(body))
    for f in frames(body, RPMS):
        est.update(lose_cycle(f))
    e = est.estimate()
    sign = e.unseen_motion["half_order_sign"]
    assert sign["sign"] == -1 and sign["residual_ratio"] > 1e6
    np.testing.assert_allclose(e.inertia, body.inertia, rtol=0, atol=1e-9)


def test_projected_jacobian_gives_the_exact_gradient() -> None:
    """``J^T r`` is the gradient of the variable-projection cost 1/2 |r(theta)|^2,
    checked by central differences on random rows."""
    rng = np.random.default_rng(3)
    p, n = 7, 5
    rows = PartialRows(
        *(
            rng.standard_normal(s)
            for s in [(p, 12, n), (p, 12), (p, 12, n), (p, 12), (p, 12, n), (p, 12)]
        ),
        dr=np.zeros((p, 12, 1)),
    )
    theta = rng.standard_normal(n)

    def cost(t: np.ndarray) -> float:
        return 0.5 * float(np.sum(project_out(rows, t)[1] ** 2))

    j, r, _ = project_out(rows, theta)
    grad = np.einsum("pkn,pk->n", j, r)
    step = 1e-6
    numeric = np.array(
        [(cost(theta + step * e) - cost(theta - step * e)) / (2 * step) for e in np.eye(n)]
    )
    np.testing.assert_allclose(grad, numeric, rtol=1e-6, atol=1e-8)
    # and w is each pair's least-squares fit: the residual is orthogonal to its columns
    c1 = rows.B1 @ theta - rows.b1
    c2 = rows.B2 @ theta - rows.b2
    assert np.max(np.abs(np.einsum("pk,pk->p", r, c1))) < 1e-10
    assert np.max(np.abs(np.einsum("pk,pk->p", r, c2))) < 1e-10


def test_cli_run_with_a_dead_sensor_estimates_from_the_two_left(tmp_path: Path) -> None:
    """A simulated sweep whose sensor C reads NaN throughout, through the dsp and the CLI."""
    bench = (ROOT / "examples" / "i3-bench.toml").read_text()
    bench = bench.replace('dbc = "bench.dbc"', f'dbc = "{ROOT / "examples" / "bench.dbc"}"')
    bench = bench.replace(
        "duration_s = 60.0", 'duration_s = 12.0\ndead_channels = ["C_x", "C_y", "C_z"]'
    )
    (tmp_path / "b.toml").write_text(bench)
    out = tmp_path / "r.json"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ptinertia",
            "run",
            "--bench",
            str(tmp_path / "b.toml"),
            "--rerun",
            "off",
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert "do not see the rotation" in proc.stdout
    doc = json.loads(out.read_text())
    truth = doc["truth"]["inertia_kgm2"]["value"]
    for k, v in doc["inertia_kgm2"]["value"].items():
        assert abs(v - truth[k]) < 0.002 * abs(truth[k]), (k, v, truth[k])
    assert np.allclose(doc["cog_m"]["value"], doc["truth"]["cog_m"]["value"], atol=5e-4)
    assert doc["unseen_motion"]["converged"]
    assert doc["unobservable"] == []
