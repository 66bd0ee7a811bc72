"""The estimate in the formats CAE and bench tools take: a bench-file fragment, plain tables, a CONM2.

Conventions (one set, as everywhere in ptinertia): bench frame (X forward, Y along
the crank axis of a transverse engine, Z up), inertia about the cog, products of
inertia ``Ixy = integral(x y dm)`` (the tensor holds ``-Ixy`` off the diagonal).

Nastran ``CONM2``. Fields ``EID G CID M X1 X2 X3`` then ``I11 I21 I22 I31 I32 I33``.
The MSC and NX Nastran Quick Reference Guides (CONM2, remark on the form of the
inertia matrix) define ``I21 = integral(x1 x2 dm)``, ``I31 = integral(x1 x3 dm)``,
``I32 = integral(x2 x3 dm)`` and build the matrix about the cog as
``[[I11, -I21, -I31], [-I21, I22, -I32], [-I31, -I32, I33]]``: "the negative signs for
the off-diagonal terms are supplied automatically". That is ptinertia's convention,
so ``I21 = Ixy``, ``I31 = Ixz``, ``I32 = Iyz`` with no sign change (a tool that
writes the tensor's entries instead, e.g. some multibody formats, needs the
opposite sign: do not copy those into a CONM2). The card is written in
large-field format (16-character fields, ``CONM2*``), with ``CID = -1`` by default:
``X1 X2 X3`` are then the cog's coordinates in the basic system, which must be the
bench frame; with a grid location, ``CID = 0`` and ``X`` is the offset from the grid.
"""

from __future__ import annotations

import csv
import io
import json
import math
import textwrap
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator.result import Z95
from powertrain.rigidbody import TERMS
from ptinertia.errors import UsageError

COG = ("Gx", "Gy", "Gz")
FORMATS = ("toml", "json", "csv", "nastran")
# unit system -> (mass, length, inertia) factor from SI, and their names
UNITS = {
    "si": ((1.0, 1.0, 1.0), ("kg", "m", "kg*m^2")),
    "mm-t-s": ((1e-3, 1e3, 1e3), ("t", "mm", "t*mm^2")),
}


@dataclass(frozen=True)
class MassProperties:
    """The estimate as exported (SI).

    Attributes
    ----------
    mass : kg or None (not estimated and not given); mass_std : kg or None.
    mass_source : ``estimated``, ``given``, ``bench file (weighed)`` or ``none``.
    cog : (3,) m; cog_std : (3,) m (NaN where unknown).
    terms : the six inertia terms, kg m^2; terms_std : their stds (NaN where unknown).
    principal_moments : (3,) kg m^2 ascending; principal_axes : (3, 3) rows, unit.
    origin : one line saying where the estimate comes from.
    """

    mass: float | None
    mass_std: float | None
    mass_source: str
    cog: np.ndarray
    cog_std: np.ndarray
    terms: dict[str, float]
    terms_std: dict[str, float]
    principal_moments: np.ndarray
    principal_axes: np.ndarray
    origin: str

    @property
    def tensor(self) -> np.ndarray:
        """(3, 3) kg m^2 about the cog, ``[[Ixx, -Ixy, -Ixz], ...]``."""
        t = self.terms
        return np.array(
            [
                [t["Ixx"], -t["Ixy"], -t["Ixz"]],
                [-t["Ixy"], t["Iyy"], -t["Iyz"]],
                [-t["Ixz"], -t["Iyz"], t["Izz"]],
            ]
        )


def _std(v: Any) -> float:
    return math.nan if v is None else float(v)


def properties_from_result(
    doc: dict[str, Any], mass: float | None = None, bench_mass: float | None = None
) -> MassProperties:
    """The exported quantities of a result document (``ptinertia run --json``).

    Parameters
    ----------
    doc : the result document.
    mass : kg, a mass to use instead of the estimate (``--mass``).
    bench_mass : kg, the bench file's (weighed) mass, used when the mass was not estimated.
    """
    try:
        terms = {k: float(doc["inertia_kgm2"]["value"][k]) for k in TERMS}
        terms_std = {k: _std(doc["inertia_kgm2"]["std"].get(k)) for k in TERMS}
        cog = np.array(doc["cog_m"]["value"], float)
        cog_std = np.array([_std(v) for v in doc["cog_m"].get("std", [None] * 3)])
    except (KeyError, TypeError, ValueError) as err:
        raise UsageError(f"not a ptinertia result document (missing or bad {err})") from None
    est = doc.get("mass_kg")
    if mass is not None:
        if not mass > 0:
            raise UsageError(f"--mass: expected a positive mass in kg, got {mass:g}")
        m, m_std, source = float(mass), None, "given"
    elif est and est.get("value"):
        m, m_std, source = float(est["value"]), est.get("std"), "estimated"
    elif bench_mass is not None:
        m, m_std, source = float(bench_mass), None, "bench file (weighed)"
    else:
        m, m_std, source = None, None, "none"
    principal = doc.get("principal") or {}
    moments = np.array(principal.get("moments_kgm2", [math.nan] * 3), float)
    axes = np.array(principal.get("axes", np.full((3, 3), math.nan)), float)
    rpm = doc.get("rpm_range") or [math.nan, math.nan]
    used = (doc.get("frames") or {}).get("used", "?")
    origin = f"{doc.get('source', 'unknown source')}: {used} frames, {rpm[0]:.0f}-{rpm[1]:.0f} rpm"
    return MassProperties(m, m_std, source, cog, cog_std, terms, terms_std, moments, axes, origin)


def _ci(value: float, std: float) -> str:
    if not math.isfinite(std):
        return "unknown"
    return f"{value - Z95 * std:.6g} .. {value + Z95 * std:.6g}"


def to_toml(p: MassProperties) -> str:
    """A ``[powertrain]`` table that replaces the bench file's (``docs/bench-file.md``)."""
    if p.mass is None:
        raise UsageError(
            "the mass was not estimated (no free force reaches it, e.g. an inline 3): "
            "give it with --mass KG or --bench BENCH.toml"
        )
    lines = [
        f"# ptinertia estimate ({p.origin})",
        "# inertia about the cog, bench frame; products Ixy = integral(x y dm) (the tensor holds -Ixy)",
        "# 95 % intervals:",
        *(f"#   {k}: {_ci(p.terms[k], p.terms_std[k])} kg m^2" for k in TERMS),
        *(f"#   {k}: {_ci(p.cog[i], p.cog_std[i])} m" for i, k in enumerate(COG)),
        "[powertrain]",
        # an estimated mass stays estimated when the fragment is used for the next run
        f"mass_kg = {p.mass!r}  # {p.mass_source}"
        + (f", 95 % {_ci(p.mass, _std(p.mass_std))} kg" if p.mass_source == "estimated" else ""),
        f"mass_known = {'false' if p.mass_source == 'estimated' else 'true'}",
        "cog_m = [" + ", ".join(repr(float(v)) for v in p.cog) + "]",
        "inertia_kgm2 = { " + ", ".join(f"{k} = {p.terms[k]!r}" for k in TERMS) + " }",
    ]
    return "\n".join(lines) + "\n"


def _rows(p: MassProperties) -> list[tuple[str, float | None, float | None, str]]:
    rows: list[tuple[str, float | None, float | None, str]] = [
        ("mass", p.mass, p.mass_std, "kg"),
        *((k, float(p.cog[i]), float(p.cog_std[i]), "m") for i, k in enumerate(COG)),
        *((k, p.terms[k], p.terms_std[k], "kg*m^2") for k in TERMS),
        *((f"I{j + 1}", float(p.principal_moments[j]), None, "kg*m^2") for j in range(3)),
    ]
    for j in range(3):
        rows += [
            (f"axis{j + 1}_{c}", float(p.principal_axes[j, i]), None, "1")
            for i, c in enumerate("xyz")
        ]
    return rows


def to_json(p: MassProperties) -> str:
    """Plain tables as JSON: value, std and 95 % interval per quantity, SI."""

    def entry(value: float | None, std: float | None, unit: str) -> dict[str, Any]:
        s = None if std is None or not math.isfinite(std) else float(std)
        ci = None if value is None or s is None else [value - Z95 * s, value + Z95 * s]
        return {"value": value, "std": s, "ci95": ci, "unit": unit}

    doc = {
        "origin": p.origin,
        "frame": "bench: X forward, Y along the crank axis (transverse engine), Z up; inertia about the cog",
        "convention": "Ixy = integral(x y dm); tensor [[Ixx, -Ixy, -Ixz], [-Ixy, Iyy, -Iyz], [-Ixz, -Iyz, Izz]]",
        "mass_source": p.mass_source,
        "quantities": {name: entry(v, s, u) for name, v, s, u in _rows(p)},
        "tensor_kgm2": p.tensor.tolist(),
    }
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def to_csv(p: MassProperties) -> str:
    """One row per quantity: ``quantity,value,std,ci95_low,ci95_high,unit`` (SI)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["quantity", "value", "std", "ci95_low", "ci95_high", "unit"])
    for name, v, s, unit in _rows(p):
        ok = v is not None and s is not None and math.isfinite(s)
        w.writerow(
            [
                name,
                "" if v is None else repr(v),
                repr(s) if ok else "",
                repr(v - Z95 * s) if ok else "",  # type: ignore[operator]
                repr(v + Z95 * s) if ok else "",  # type: ignore[operator]
                unit,
            ]
        )
    return buf.getvalue()


def _f16(value: float | int) -> str:
    """One large-field Nastran field: 16 characters, right-justified."""
    text = str(value) if isinstance(value, int) else f"{value:.8E}"
    if len(text) > 16:
        raise UsageError(f"value {value!r} does not fit a 16-character Nastran field")
    return text.rjust(16)


def to_conm2(
    p: MassProperties,
    eid: int = 1,
    grid: int = 1,
    grid_at: tuple[float, float, float] | None = None,
    units: str = "si",
) -> str:
    """A large-field ``CONM2`` card with a comment block stating frame, units and sign convention.

    Parameters
    ----------
    eid, grid : element and grid ids.
    grid_at : (3,) m, where grid ``grid`` is (bench frame): then ``CID = 0`` and ``X`` is the
        offset from it to the cog; None: ``CID = -1``, ``X`` the cog's basic coordinates.
    units : ``si`` (kg, m, kg m^2) or ``mm-t-s`` (t, mm, t mm^2).
    """
    if p.mass is None:
        raise UsageError(
            "CONM2 needs a mass, which was not estimated: give it with --mass KG or --bench BENCH.toml"
        )
    if units not in UNITS:
        raise UsageError(f"--units: expected one of {', '.join(UNITS)}, got {units!r}")
    if eid <= 0 or grid <= 0:
        raise UsageError(f"--eid and --grid must be positive integers, got {eid} and {grid}")
    (fm, fl, fi), (um, ul, ui) = UNITS[units]
    if grid_at is None:
        cid, x = -1, p.cog * fl
        where = "CID = -1: X1 X2 X3 = cog coordinates in the basic system (= bench frame)"
    else:
        cid, x = 0, (p.cog - np.asarray(grid_at, float)) * fl
        where = f"CID = 0: X1 X2 X3 = offset from grid {grid} at {list(grid_at)} m to the cog"
    t = {k: v * fi for k, v in p.terms.items()}
    comments = [
        f"ptinertia estimate: {p.origin}",
        f"mass: {p.mass_source}",
        f"units: mass {um}, length {ul}, inertia {ui}",
        where,
        "bench frame: X forward, Y along the crank axis (transverse engine), Z up",
        "inertia about the cog; Nastran CONM2 convention (MSC/NX QRG):",
        "  I21 = integral(x1 x2 dm), I31 = integral(x1 x3 dm),",
        "  I32 = integral(x2 x3 dm);",
        "  Nastran builds [[I11,-I21,-I31],[-I21,I22,-I32],[-I31,-I32,I33]]",
        "  so I21 = Ixy, I31 = Ixz, I32 = Iyz of ptinertia: no sign change",
        "95 % intervals (SI):",
        *(f"  {k} {_ci(p.terms[k], p.terms_std[k])} kg*m^2" for k in TERMS),
    ]
    fields1 = [eid, grid, cid, p.mass * fm]
    fields2 = [float(x[0]), float(x[1]), float(x[2])]
    fields3 = [t["Ixx"], t["Ixy"], t["Iyy"], t["Ixz"]]
    fields4 = [t["Iyz"], t["Izz"]]
    # comments kept within 80 columns: fixed-format decks are read to column 80
    lines = [
        f"$ {part}" for c in comments for part in textwrap.wrap(c, 76, subsequent_indent="    ")
    ]
    lines.append("CONM2*  " + "".join(_f16(v) for v in fields1))
    for fields in (fields2, fields3, fields4):
        lines.append("*       " + "".join(_f16(v) for v in fields))
    return "\n".join(lines) + "\n"


def export(p: MassProperties, fmt: str, **kwargs: Any) -> str:
    """The text of ``p`` in format ``fmt`` (one of :data:`FORMATS`)."""
    if fmt == "toml":
        return to_toml(p)
    if fmt == "json":
        return to_json(p)
    if fmt == "csv":
        return to_csv(p)
    if fmt == "nastran":
        return to_conm2(p, **kwargs)
    raise UsageError(f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")
