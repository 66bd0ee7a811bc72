"""``ptinertia pendulum``: inertia tensor (and cog) from a pendulum or rolling-plate test.

Reads a test file (``examples/pendulum-test.toml``, format in
``docs/classical-methods.md``), solves eqs. 7 or 8 for six or more
configurations, the cog from the plumb lines, and propagates the stated
period, stiffness, angle (and plate) uncertainties into the intervals. The
condition number of the axis set is printed with a warning when it is poor;
a degenerate set (all axes in one plane, ...) is refused with the reason.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

DEG = math.pi / 180.0


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("test", help="pendulum test file (TOML)")
    p.add_argument(
        "--json", default=None, metavar="OUT", help="write the result document ('-': stdout)"
    )
    return p


def _swings(test: Any) -> list[Any]:
    from estimator.classical.pendulum import Swing

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


def compute(path: str) -> dict[str, Any]:
    """The result document of a pendulum test file."""
    from acquisition.classical.pendulum_file import load_pendulum_test
    from estimator.classical.pendulum import Plate, inertia_from_swings
    from estimator.classical.pendulum_axes import BEST_CONDITION, CONDITION_WARN
    from estimator.classical.plumb_lines import cog_from_lines
    from ptinertia.commands.compare import estimate_document

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
    swings = _swings(test)
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
        covariance=(["Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"], fit.cov),
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


def format_report(doc: dict[str, Any]) -> str:
    from ptinertia.commands.compare import Z95

    lines = [
        f"{doc['method'].replace('_', ' ')} test {doc['name']!r}: {len(doc['configurations'])} "
        f"configurations, condition number {doc['condition_number']:.3g}",
        "",
        "inertia about the cog, bench frame (kg m^2), 95 % intervals:",
    ]
    inertia = doc["inertia_kgm2"]
    for t, v in inertia["value"].items():
        s = inertia["std"][t]
        lines.append(f"  {t}  {v:10.5g} +- {Z95 * s:.2g}" if s is not None else f"  {t}  {v:10.5g}")
    if doc["cog_m"] is not None:
        lines.append("cog (mm), 95 % intervals:")
        for axis, v, s in zip("xyz", doc["cog_m"]["value"], doc["cog_m"]["std"], strict=True):
            lines.append(f"  {axis}  {1e3 * v:10.2f} +- {1e3 * Z95 * (s or 0):.2f}")
    lines.append("per configuration (kg m^2): measured, fitted")
    for c in doc["configurations"]:
        lines.append(
            f"  {c['name']:<16} axis {np.round(c['axis'], 3).tolist()}  "
            f"{c['measured_kgm2']:.5g}  {c['fitted_kgm2']:.5g}"
        )
    for w in doc["warnings"]:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ptinertia.commands.compare import write_document

    doc = compute(args.test)
    if args.json:
        write_document(doc, args.json)
    if args.json != "-":
        print(format_report(doc))
    return 0
