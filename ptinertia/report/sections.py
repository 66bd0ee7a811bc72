"""The report's sections as HTML fragments (see :mod:`ptinertia.report.build`).

Each function takes the :class:`ptinertia.report.data.ReportData` (and what was
already computed from it) and returns HTML; figures it draws are added to the
``figures`` dict it is given, so ``--png`` can write them too.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimator.result import Z95
from estimator.unbalance import DETECTED_STDS, detected
from ptinertia.report import plots
from ptinertia.report.data import ConvergenceSeries, ReportData
from ptinertia.report.html import esc, fixed, flatten, image, table
from ptinertia.report.stats import (
    COG,
    TERMS,
    ParameterCovariance,
    mode_stats,
    principal_stats,
    tensors,
)
from ptinertia.resim import estimated_properties, resim_model
from ptinertia.resim_compare import ResimCheck
from ptinertia.to_physics import build_model


def reference(data: ReportData) -> tuple[dict[str, float], str]:
    """Parameter -> reference value (SI), and its label: the truth, else the bench file's values."""
    truth = data.truth or (data.result or {}).get("truth")
    out: dict[str, float] = {}
    if truth:
        terms = (truth.get("inertia_kgm2") or {}).get("value") or {}
        out.update({k: float(v) for k, v in terms.items() if k in TERMS})
        cog = (truth.get("cog_m") or {}).get("value")
        if cog:
            out.update(dict(zip(COG, map(float, cog), strict=True)))
        mass = (truth.get("mass_kg") or {}).get("value")
        if mass:
            out["mass"] = float(mass)
        return out, "truth (simulation)"
    if data.bench is not None:
        p = data.bench.powertrain
        out.update({k: float(getattr(p.inertia_kgm2, k)) for k in TERMS})
        out.update(dict(zip(COG, map(float, p.cog_m), strict=True)))
        out["mass"] = float(p.mass_kg)
        return out, "nominal (bench file)"
    return out, ""


def _row(
    name: str, unit: str, scale: float, value: float, std: float | None, ref: float | None
) -> list[str]:
    ci = (
        ""
        if std is None or not math.isfinite(std)
        else f"{fixed((value - Z95 * std) * scale, 4)} .. {fixed((value + Z95 * std) * scale, 4)}"
    )
    cells = [name, unit, fixed(value * scale, 4), ci]
    if ref is None:
        return [*cells, "", "", ""]
    err = value - ref
    rel = f"{100 * err / abs(ref):+.2f} %" if unit != "mm" and ref != 0 else ""
    inside = (
        "" if std is None or not math.isfinite(std) else ("yes" if abs(err) <= Z95 * std else "no")
    )
    return [*cells, fixed(ref * scale, 4), f"{fixed(err * scale, 4)} {rel}".strip(), inside]


def estimate_section(data: ReportData, pc: ParameterCovariance) -> str:
    doc = data.result
    assert doc is not None
    ref, ref_label = reference(data)
    std = dict(zip(pc.names, np.sqrt(np.diag(pc.cov)), strict=True))
    rows = []
    mass = doc.get("mass_kg")
    if mass:
        rows.append(_row("mass", "kg", 1.0, mass["value"], mass.get("std"), ref.get("mass")))
    elif data.bench is not None:
        rows.append(
            [
                "mass",
                "kg",
                fixed(data.bench.powertrain.mass_kg, 4),
                "input (weighed: not observable)",
                "",
                "",
                "",
            ]
        )
    for i, n in enumerate(COG):
        rows.append(_row(n, "mm", 1e3, doc["cog_m"]["value"][i], std.get(n), ref.get(n)))
    for n in TERMS:
        rows.append(_row(n, "kg m^2", 1.0, doc["inertia_kgm2"]["value"][n], std.get(n), ref.get(n)))
    prin = principal_stats(pc.value[:6], pc.cov[:6, :6])
    ref_prin = None
    if all(k in ref for k in TERMS):
        m_ref, v_ref = np.linalg.eigh(tensors(np.array([ref[k] for k in TERMS])))
        ref_prin = (m_ref, v_ref.T)
    for j in range(3):
        lo, hi = prin.moments_ci95[j]
        r = None if ref_prin is None else float(ref_prin[0][j])
        err = (
            ""
            if r is None
            else f"{fixed(prin.moments[j] - r, 4)} {100 * (prin.moments[j] - r) / r:+.2f} %"
        )
        inside = "" if r is None else ("yes" if lo <= r <= hi else "no")
        rows.append(
            [
                f"I{j + 1} (principal)",
                "kg m^2",
                fixed(prin.moments[j], 4),
                f"{fixed(lo, 4)} .. {fixed(hi, 4)}",
                "" if r is None else fixed(r, 4),
                err,
                inside,
            ]
        )
    for j in range(3):
        axis = prin.axes[j]
        r_axis = None if ref_prin is None else ref_prin[1][j]
        angle = (
            None if r_axis is None else math.degrees(math.acos(min(1.0, abs(float(axis @ r_axis)))))
        )
        rows.append(
            [
                f"axis of I{j + 1}",
                "unit vector",
                "[" + ", ".join(f"{v:+.3f}" for v in axis) + "]",
                f"cone {prin.cone95_deg[j]:.1f} deg",
                "" if r_axis is None else "[" + ", ".join(f"{v:+.3f}" for v in r_axis) + "]",
                "" if angle is None else f"{angle:.1f} deg",
                "" if angle is None else ("yes" if angle <= prin.cone95_deg[j] else "no"),
            ]
        )
    header = [
        "quantity",
        "unit",
        "estimate",
        "95 % interval",
        ref_label or "reference",
        "error",
        "reference in interval",
    ]
    notes = [
        "Inertia about the cog, bench frame (X forward, Y along the crank of a transverse engine, Z up); "
        "products Ixy = integral(x y dm): the tensor holds -Ixy off the diagonal.",
        "Principal moments ascending; their intervals and the axes' 95 % cones come from sampling the estimate's covariance"
        + (
            ""
            if pc.correlated
            else " (standard deviations only: a result document has no correlations)"
        )
        + ".",
    ]
    extra = []
    unb = doc.get("unbalance")
    if unb:
        extra.append(unbalance_line(unb))
    off = doc.get("crank_offset_deg")
    if off:
        extra.append(
            f"crank reference offset {off['value']:.3f} deg (std {off['std'] or math.nan:.3f})"
        )
    if doc.get("unobservable"):
        extra.append("unobservable (no excitation reaches them): " + ", ".join(doc["unobservable"]))
    problems = doc.get("principal", {}).get("consistency", {}).get("problems") or []
    if problems:
        extra.append("physical consistency enforced on the tensor: " + "; ".join(problems))
    return (
        "<h2>1. Estimate</h2>"
        + table(header, rows, left=2)
        + "".join(f'<p class="small">{esc(n)}</p>' for n in notes)
        + ("<ul>" + "".join(f"<li>{esc(e)}</li>" for e in extra) + "</ul>" if extra else "")
    )


def unbalance_line(unb: dict[str, Any]) -> str:
    """The residual unbalance as the run's table prints it: an angle only when it is detected.

    Detected: ``estimator.unbalance.detected`` (``m r > 2 std(m r)``, the run table's rule); below
    that, ``m r`` is noise around zero and its angle is undefined (its std runs to 1e7 deg),
    and so is its location along the crank. The couple (``couple_kgm2``, what no point
    unbalance explains: ``estimator.unbalance``) follows the same rule.
    """
    mr, mr_std = unb["mr_kgm"]["value"], unb["mr_kgm"]["std"] or 0.0
    if detected(unb["mr_kgm"]):
        angle = unb["angle_deg"]
        line = (
            f"residual static unbalance {1e3 * mr:.3f} g m (std {1e3 * mr_std:.3f}) at "
            f"{angle['value']:.1f} deg (std {angle['std'] or math.nan:.1f})"
        )
        axial = unb.get("axial_m")
        if axial:
            line += (
                f", {1e3 * axial['value']:.1f} mm (std {1e3 * (axial['std'] or math.nan):.1f}) "
                "along the crank axis from the reference point"
            )
    else:
        line = (
            f"residual static unbalance not detected (below {1e3 * DETECTED_STDS * mr_std:.3f} g m)"
        )
    couple = unb.get("couple_kgm2")
    if couple:
        c, c_std = couple["value"], couple["std"] or 0.0
        if detected(couple):
            angle = unb["couple_angle_deg"]
            line += (
                f"; couple unbalance {1e3 * c:.4f} g m^2 (std {1e3 * c_std:.4f}) at "
                f"{angle['value']:.1f} deg (std {angle['std'] or math.nan:.1f})"
            )
        else:
            line += (
                f"; couple unbalance not detected (below {1e3 * DETECTED_STDS * c_std:.4f} g m^2)"
            )
    return line


PANELS = [*((n, f"{n}, kg m^2", 1.0) for n in TERMS), *((n, f"{n}, mm", 1e3) for n in COG)]


def with_mass(conv: ConvergenceSeries) -> ConvergenceSeries:
    """Add a ``mass`` column (1 / inv_mass, delta-method std) when the mass was estimated."""
    if "inv_mass" not in conv.names:
        return conv
    mu, s_mu = conv.column("inv_mass")
    with np.errstate(divide="ignore", invalid="ignore"):
        mass = np.where(mu > 0, 1.0 / mu, np.nan)
        s_m = s_mu / mu**2
    return ConvergenceSeries(
        conv.time_s,
        conv.rpm,
        (*conv.names, "mass"),
        np.column_stack([conv.value, mass]),
        np.column_stack([conv.std, s_m]),
    )


def resim_table(check: ResimCheck) -> str:
    rows, dim = [], []
    for k, h in enumerate(check.orders):
        span = check.mass_line_rpm(k)
        for j, c in enumerate(check.channels):
            judged = bool(check.assessable[k, j])
            if judged:
                judgement = "yes: within" if check.within(k, j) else "yes: OVER THE LIMIT"
            elif np.isfinite(check.p95_db[k, j]):
                judgement = "no (tolerance-limited)"
            else:
                judgement = "no data"
            rows.append(
                [
                    f"H{h:g}",
                    c,
                    "" if span is None else f"{span[0]:.0f}-{span[1]:.0f}",
                    fixed(check.level_db[k, j], 1),
                    fixed(check.median_db[k, j], 2),
                    fixed(check.p95_db[k, j], 2),
                    fixed(check.median_deg[k, j], 2),
                    fixed(check.p95_deg[k, j], 2),
                    fixed(100 * check.tolerance_rel[k, j], 1),
                    judgement,
                ]
            )
            dim.append(not judged)
    header = [
        "order",
        "channel",
        "mass-line rpm",
        "level dB",
        "median dB",
        "95 % |dB|",
        "median deg",
        "95 % |deg|",
        "sensor tol. %",
        "judged",
    ]
    return table(header, rows, left=2, dim=dim)


def modes_section(
    data: ReportData, pc: ParameterCovariance | None, figures: dict[str, bytes]
) -> str:
    bench = data.bench
    if bench is None or not bench.mounts:
        return "<h2>5. Rigid-body modes</h2><p>No bench file with mounts: no modes.</p>"
    nominal = build_model(bench)
    if data.result is not None:
        props = estimated_properties(data.result, bench)
        model = resim_model(bench, props)
        what = "with the estimated mass, cog and inertia"
    else:
        model = nominal
        what = "with the bench file's nominal properties (no estimate)"
    ms = mode_stats(
        model.body, model.mounts, model.engine.crank_spin_inertia, model.engine.crank_axis, pc
    )
    f_nom = nominal.modes().frequency_hz
    rows = []
    for j in range(6):
        lo, hi = ms.frequency_ci95[j]
        ci = "" if not np.isfinite(lo) else f"{lo:.2f} .. {hi:.2f}"
        rows.append(
            [
                str(j + 1),
                fixed(ms.frequency_hz[j], 2),
                ci,
                fixed(f_nom[j], 2),
                ms.dominant[j],
                *(f"{100 * ms.energy[i, j]:.0f}" for i in range(6)),
            ]
        )
    header = [
        "mode",
        "Hz",
        "95 % interval",
        "bench file Hz",
        "dominant",
        *(f"{lab} %" for lab in ms.labels),
    ]
    gates = (data.settings.get("estimator") or {}).get("gates") or {}
    ratio = gates.get("min_mode_ratio", bench.estimator.min_mode_ratio)
    if data.frames is not None and len(data.frames):
        rpm_max = float(np.nanmax(data.frames.rpm))
    else:
        rpm_max = max(bench.simulation.rpm_start, bench.simulation.rpm_end)
    orders = data.frames.orders if data.frames is not None else tuple(bench.dsp.orders)
    figures["modes"] = plots.png(plots.campbell(ms, orders, rpm_max, ratio))
    return (
        f"<h2>5. Rigid-body modes</h2><p>Undamped modes at zero speed {esc(what)}, on the bench file's mounts; "
        "shapes as the share of kinetic energy per degree of freedom (roll = about the crank axis). "
        "Intervals by sampling the estimate's covariance.</p>"
        + table(header, rows, left=1)
        + image(
            "modes",
            figures["modes"],
            "Mode frequencies (grey: 95 % bands) and engine orders; green: the mass-line region the estimator uses",
        )
    )


def settings_section(data: ReportData) -> str:
    rows = flatten("", data.settings) if data.settings else []
    doc = data.result or {}
    if doc.get("half_order"):
        rows += flatten("half_order", doc["half_order"])
    if doc.get("variance_factor") is not None:
        rows.append(("variance_factor", f"{doc['variance_factor']:.4g}"))
    body = (
        table(["setting", "value"], rows, left=2)
        if rows
        else "<p>No settings recorded (result document).</p>"
    )
    notes = "".join(f"<li>{esc(n)}</li>" for n in data.notes)
    return "<h2>7. Settings and input</h2>" + body + (f"<ul>{notes}</ul>" if notes else "")
