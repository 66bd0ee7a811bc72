"""The classical methods' result documents: a pendulum test, mass-line FRFs.

The app's side of ``ptinertia pendulum`` and ``ptinertia massline``: read the inputs
(:mod:`acquisition.classical`), run the estimators (:mod:`estimator.classical`), and
put the result in the shared document (:func:`ptinertia.estimates.estimate_document`)
with what each method adds to it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from acquisition.classical.frf_matrix import SensorPoint, frf_matrix
from acquisition.classical.modal_setup import load_modal_setup
from acquisition.classical.pendulum_file import load_pendulum_test
from acquisition.classical.uff import read_uff
from estimator.classical.massline import estimate_mass_line
from estimator.classical.massline_band import FrfGeometry
from estimator.classical.massline_rigid import MassLineTolerances
from estimator.classical.pendulum import Plate, Swing, inertia_from_swings
from estimator.classical.pendulum_axes import BEST_CONDITION, CONDITION_WARN
from estimator.classical.plumb_lines import cog_from_lines
from powertrain.rigidbody import TERMS
from ptinertia.config import load_bench
from ptinertia.estimates import estimate_document

DEG = math.pi / 180.0


def _pendulum_swings(test: Any) -> list[Any]:
    unc = test.uncertainty
    out = []
    for i, c in enumerate(test.configurations):
        period_std = (
            c.period_std_s if c.period_std_s is not None else c.period_s * unc.period_pct / 100
        )
        stiff_std = (
            c.stiffness_std_nm_per_rad
            if c.stiffness_std_nm_per_rad is not None
            else c.stiffness_nm_per_rad * unc.stiffness_pct / 100
        )
        axis_std = (c.axis_std_deg if c.axis_std_deg is not None else unc.axis_std_deg) * DEG
        out.append(
            Swing(
                axis=np.array(c.axis),
                period=c.period_s,
                stiffness=c.stiffness_nm_per_rad,
                period_std=period_std,
                stiffness_std=stiff_std,
                axis_std=axis_std,
                plate_point=None
                if c.plate_axis_point_m is None
                else np.array(c.plate_axis_point_m),
                plate_point_std=c.plate_point_std_m
                if c.plate_point_std_m is not None
                else unc.plate_point_std_m,
                name=c.name or f"configuration {i + 1}",
            )
        )
    return out


def pendulum_document(path: str) -> dict[str, Any]:
    """The result document of a pendulum or rolling-plate test file."""
    test = load_pendulum_test(path)
    unc = test.uncertainty
    warnings: list[str] = []
    cog_fit = None
    if test.lines:
        if len(test.lines) < 2:
            warnings.append("one plumb line cannot locate the cog: give at least two")
        else:
            cog_fit = cog_from_lines(
                [ln.point_m for ln in test.lines],
                [ln.direction for ln in test.lines],
                [
                    ln.position_std_m if ln.position_std_m is not None else unc.line_position_std_m
                    for ln in test.lines
                ],
                [
                    (ln.angle_std_deg if ln.angle_std_deg is not None else unc.line_angle_std_deg)
                    * DEG
                    for ln in test.lines
                ],
            )
    plate = None
    if test.meta.method == "rolling_plate":
        assert test.plate is not None  # the file schema requires it
        if test.plate.cog_m is not None:
            cog, cog_cov = np.array(test.plate.cog_m), np.eye(3) * test.plate.cog_std_m**2
        else:
            assert cog_fit is not None  # the schema requires two lines without plate.cog_m
            cog, cog_cov = cog_fit.cog, cog_fit.cov
        plate = Plate(
            inertia=test.plate.inertia_kgm2,
            body_mass=test.plate.body_mass_kg,
            cog=cog,
            inertia_std=test.plate.inertia_std_kgm2,
            body_mass_std=test.plate.body_mass_std_kg,
            cog_cov=cog_cov,
        )
    swings = _pendulum_swings(test)
    fit = inertia_from_swings(swings, plate, unc.stiffness_calibration_pct / 100)
    if fit.condition > CONDITION_WARN:
        warnings.append(
            f"axis set poorly conditioned: condition number {fit.condition:.3g} (best possible "
            f"{BEST_CONDITION:.2f}, X/Y/Z + three face diagonals 3.2): period errors are "
            f"amplified up to {fit.condition:.3g} times"
        )
    if not np.any(fit.row_std > 1e-5 * np.abs(fit.measured).max()):  # above the exact floor
        warnings.append("no uncertainty stated: the intervals are zero ([uncertainty] table)")
    if fit.variance_factor > 1:
        warnings.append(
            f"the {len(swings)} configurations disagree more than their stated uncertainties "
            f"allow (chi2 {fit.chi2:.3g} for {fit.dof} dof): intervals widened by "
            f"{math.sqrt(fit.variance_factor):.2f}"
        )
    if cog_fit is not None and cog_fit.variance_factor > 1:
        warnings.append(
            f"plumb lines miss the cog by up to {1e3 * cog_fit.distances.max():.1f} mm, more "
            f"than their stated uncertainty allows (chi2 {cog_fit.chi2:.3g} for {cog_fit.dof} "
            f"dof): cog interval widened by {math.sqrt(cog_fit.variance_factor):.2f}"
        )
    doc = estimate_document(
        method=test.meta.method,
        terms=fit.terms,
        terms_std=fit.std,
        cog=None if cog_fit is None else cog_fit.cog,
        cog_std=None if cog_fit is None else np.sqrt(np.diag(cog_fit.cov)),
        covariance=(list(TERMS), fit.cov),
    )
    doc.update(
        {
            "source": str(path),
            "name": test.meta.name,
            "condition_number": fit.condition,
            "condition_reference": {
                "best_possible": BEST_CONDITION,
                "xyz_and_face_diagonals": 3.2255,
            },
            "variance_factor": fit.variance_factor,
            "chi2": fit.chi2,
            "dof": fit.dof,
            "configurations": [
                {
                    "name": s.name,
                    "axis": s.axis.tolist(),
                    "measured_kgm2": float(m),
                    "fitted_kgm2": float(f),
                    "std_kgm2": float(sd),
                }
                for s, m, f, sd in zip(swings, fit.measured, fit.fitted, fit.row_std, strict=True)
            ],
            "lines": None
            if cog_fit is None
            else {
                "count": len(test.lines),
                "distance_to_cog_m": cog_fit.distances.tolist(),
                "variance_factor": cog_fit.variance_factor,
            },
            "mass_input_kg": None if test.plate is None else test.plate.body_mass_kg,
            "warnings": warnings,
        }
    )
    if test.truth is not None:
        doc["truth"] = test.truth.model_dump(exclude_none=True)
    return doc


def massline_document(
    frf_path: str,
    bench_path: str,
    setup_path: str | None = None,
    band: tuple[float, float] | None = None,
    residual_stiffness: bool = True,
    node_tolerance_m: float = 0.005,
    tolerances: MassLineTolerances | None = None,
) -> dict[str, Any]:
    """The result document of a mass-line evaluation (the bench file gives the response points)."""
    bench = load_bench(bench_path)
    sensors = [
        SensorPoint(s.name, np.array(s.position_m), np.array(s.axes), tuple(s.channels))
        for s in bench.sensors
    ]
    setup = None if setup_path is None else load_modal_setup(setup_path)
    uff = read_uff(frf_path)
    data = frf_matrix(uff, sensors, setup, node_tolerance_m)
    geometry = FrfGeometry(
        channel_positions=data.channel_positions,
        channel_directions=data.channel_directions,
        force_positions=data.excitation_positions,
        force_directions=data.excitation_directions,
        channel_names=data.channel_names,
        excitation_names=data.excitation_names,
        channel_sensor=data.channel_sensor,
    )
    result = estimate_mass_line(
        data.frequency_hz, data.h, geometry, band, residual_stiffness, tolerances
    )
    body = result.body
    std = body.std
    doc = estimate_document(
        method="massline",
        terms=body.terms,
        terms_std=std[4:],
        cog=body.cog,
        cog_std=std[1:4],
        mass=body.mass,
        mass_std=float(std[0]),
        covariance=(["mass", "Gx", "Gy", "Gz", *TERMS], body.cov),
    )
    doc.update(
        {
            "source": str(frf_path),
            "bench": str(bench_path),
            "band_hz": {
                "low": result.band.low_hz,
                "high": result.band.high_hz,
                "chosen": result.band.chosen,
                "resonances": list(result.band.resonances_hz),
            },
            "fit": {
                "powers": list(result.fit.powers),
                "residual_stiffness": residual_stiffness,
                "lines": result.fit.lines,
                "misfit": result.fit.misfit,
                "residual_share": result.fit.residual_share,
            },
            "rigid_body": {
                "misfit": body.rigid_misfit,
                "variance_factor": body.variance_factor,
                "chi2": body.chi2,
                "dof": body.dof,
                "iterations": body.iterations,
            },
            "excitations": list(data.excitation_names),
            "channels": list(data.channel_names),
            "response_nodes": data.response_nodes,
            "unused_frfs": data.unused,
        }
    )
    return doc
