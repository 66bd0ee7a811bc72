"""``ptinertia compare``: estimates from any methods side by side, with their differences.

Reads result documents (``ptinertia run``, ``pendulum``, ``massline`` ``--json``
output; optionally a bench file's values as a nominal column) and prints, per
quantity, each value with its 95 % interval, then each estimate against the
first: the difference, the difference in combined standard deviations
``z = |b - a| / sqrt(s_a^2 + s_b^2)``, and whether the two 95 % intervals overlap.

The result document (shared by every estimator, see :func:`estimate_document`)::

    {"method": str,
     "inertia_kgm2": {"value": {Ixx..Iyz}, "std": {...}, "ci95": {...}},
     "cog_m": {"value": [x, y, z], "std": [...]} | null,
     "mass_kg": {"value": m, "std": s} | null, ...}

Inertia about the cog, bench frame, products ``Ixy = integral(x y dm)``; a
``std`` of null means not observable.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ptinertia.errors import UsageError

TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
Z95 = 1.959963984540054
#: (key, label, unit, display scale)
QUANTITIES = (
    ("mass", "mass", "kg", 1.0),
    ("Gx", "cog x", "mm", 1e3),
    ("Gy", "cog y", "mm", 1e3),
    ("Gz", "cog z", "mm", 1e3),
    *((t, t, "kg m^2", 1.0) for t in TERMS),
)


def _finite(x: float | None) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def estimate_document(
    method: str,
    terms: np.ndarray,
    terms_std: np.ndarray,
    cog: np.ndarray | None = None,
    cog_std: np.ndarray | None = None,
    mass: float | None = None,
    mass_std: float | None = None,
    covariance: tuple[list[str], np.ndarray] | None = None,
) -> dict[str, Any]:
    """The shared result document (module docstring), plus principal moments and axes.

    Parameters
    ----------
    method : label ("pendulum", "rolling_plate", "massline", ...).
    terms, terms_std : (6,) kg m^2, ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` and 1 sigma.
    cog, cog_std : (3,) m, or None when the method gives no cog.
    mass, mass_std : kg, or None when the method gives no mass.
    covariance : optional (names, matrix) of the parameters, SI.
    """
    from estimator.result import enforce_physical, principal_axes
    from powertrain.rigidbody import inertia_matrix

    terms = np.asarray(terms, dtype=float)
    std = np.asarray(terms_std, dtype=float)
    fixed, problems = enforce_physical(inertia_matrix(*terms))
    moments, axes = principal_axes(fixed)
    doc: dict[str, Any] = {
        "method": method,
        "inertia_kgm2": {
            "value": dict(zip(TERMS, terms.tolist(), strict=True)),
            "std": {t: _finite(s) for t, s in zip(TERMS, std.tolist(), strict=True)},
            "ci95": {
                t: [v - Z95 * s, v + Z95 * s]
                for t, v, s in zip(TERMS, terms.tolist(), std.tolist(), strict=True)
            },
        },
        "cog_m": None
        if cog is None
        else {
            "value": np.asarray(cog, dtype=float).tolist(),
            "std": [_finite(s) for s in np.asarray(cog_std, dtype=float).tolist()]
            if cog_std is not None
            else None,
        },
        "mass_kg": None if mass is None else {"value": float(mass), "std": _finite(mass_std)},
        "principal": {
            "moments_kgm2": moments.tolist(),
            "axes": axes.T.tolist(),
            "consistency": {"problems": problems, "enforced": bool(problems)},
        },
    }
    if covariance is not None:
        names, matrix = covariance
        doc["covariance"] = {"names": list(names), "matrix": np.asarray(matrix).tolist()}
    return doc


def write_document(doc: dict[str, Any], target: str) -> None:
    """Write ``doc`` as JSON to ``target`` (``-`` for stdout)."""
    text = json.dumps(doc, indent=1)
    if target == "-":
        print(text)
        return
    try:
        Path(target).write_text(text + "\n", encoding="utf-8")
    except OSError as err:
        raise UsageError(f"--json: cannot write {target} ({err.strerror})") from None


def _pair(entry: Any, index: int | None = None) -> tuple[float | None, float | None]:
    if entry is None:
        return None, None
    value, std = entry.get("value"), entry.get("std")
    if index is not None:
        value = None if value is None else value[index]
        std = None if std is None else std[index]
    return _finite(value), _finite(std)


def read_estimate(path: str) -> dict[str, tuple[float | None, float | None]]:
    """(value, std) per quantity key of :data:`QUANTITIES` from a result document.

    Raises
    ------
    UsageError
        Unreadable file or not a result document.
    """
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as err:
        raise UsageError(f"{path}: cannot read ({err.strerror})") from None
    except json.JSONDecodeError as err:
        raise UsageError(f"{path}: not JSON ({err.msg} at line {err.lineno})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("inertia_kgm2"), dict):
        raise UsageError(f"{path}: not a result document (no inertia_kgm2 table)")
    out: dict[str, tuple[float | None, float | None]] = {}
    try:
        out["mass"] = _pair(doc.get("mass_kg"))
        for i, key in enumerate(("Gx", "Gy", "Gz")):
            out[key] = _pair(doc.get("cog_m"), i)
        inertia = doc["inertia_kgm2"]
        for t in TERMS:
            out[t] = (
                _finite(inertia["value"].get(t)),
                _finite((inertia.get("std") or {}).get(t)),
            )
    except (AttributeError, TypeError, IndexError, KeyError) as err:
        raise UsageError(f"{path}: malformed result document ({err!r})") from None
    return out


def _method(path: str) -> str:
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        return str(doc.get("method") or Path(path).stem)
    except (OSError, json.JSONDecodeError, AttributeError):
        return Path(path).stem


def bench_values(path: str) -> dict[str, tuple[float | None, float | None]]:
    """The bench file's powertrain as a column without intervals."""
    from ptinertia.config import load_bench

    p = load_bench(path).powertrain
    out: dict[str, tuple[float | None, float | None]] = {"mass": (p.mass_kg, 0.0)}
    for key, v in zip(("Gx", "Gy", "Gz"), p.cog_m, strict=True):
        out[key] = (v, 0.0)
    for t in TERMS:
        out[t] = (getattr(p.inertia_kgm2, t), 0.0)
    return out


def compare(
    columns: list[tuple[str, dict[str, tuple[float | None, float | None]]]],
) -> dict[str, Any]:
    """Each column against the first, per quantity (plain data for the table and the JSON)."""
    ref_name, ref = columns[0]
    rows = []
    for key, label, unit, scale in QUANTITIES:
        row: dict[str, Any] = {"quantity": label, "unit": unit, "scale": scale, "estimates": []}
        for name, col in columns:
            v, s = col.get(key, (None, None))
            row["estimates"].append({"name": name, "value": v, "std": s})
        a, sa = ref.get(key, (None, None))
        row["differences"] = []
        for name, col in columns[1:]:
            b, sb = col.get(key, (None, None))
            diff: dict[str, Any] = {"name": name, "against": ref_name}
            if a is None or b is None:
                diff.update(difference=None, z=None, overlap=None)
            else:
                diff["difference"] = b - a
                if sa is None or sb is None:
                    diff.update(z=None, overlap=None)
                else:
                    comb = math.hypot(sa, sb)
                    diff["z"] = abs(b - a) / comb if comb > 0 else (0.0 if b == a else math.inf)
                    diff["overlap"] = bool(abs(b - a) <= Z95 * (sa + sb))
            row["differences"].append(diff)
        rows.append(row)
    return {"reference": ref_name, "columns": [n for n, _ in columns], "rows": rows}


def _fmt(v: float | None, scale: float, digits: int = 4) -> str:
    return "-" if v is None else f"{v * scale:.{digits}g}"


def format_table(data: dict[str, Any]) -> str:
    names = data["columns"]
    header = ["quantity", "unit", *(f"{n} (95 %)" for n in names)]
    header += [f"{d['name']} - {data['reference']}" for d in data["rows"][0]["differences"]]
    table = [header]
    for row in data["rows"]:
        scale = row["scale"]
        cells = [row["quantity"], row["unit"]]
        for est in row["estimates"]:
            v, s = est["value"], est["std"]
            if v is None:
                cells.append("-")
            elif s is None:
                cells.append(f"{_fmt(v, scale)} +- ?")
            elif s == 0:
                cells.append(_fmt(v, scale))
            else:
                cells.append(f"{_fmt(v, scale)} +- {_fmt(Z95 * s, scale, 2)}")
        for d in row["differences"]:
            if d["difference"] is None:
                cells.append("-")
                continue
            text = f"{_fmt(d['difference'], scale, 3)}"
            if d["z"] is not None:
                text += f" (z {d['z']:.1f}, {'overlap' if d['overlap'] else 'NO overlap'})"
            cells.append(text)
        table.append(cells)
    widths = [max(len(r[k]) for r in table) for k in range(len(header))]
    lines = [
        "  ".join(
            c.ljust(w) if k < 2 else c.rjust(w)
            for k, (c, w) in enumerate(zip(r, widths, strict=True))
        )
        for r in table
    ]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append("")
    lines.append(
        "z: difference over the combined standard deviation; overlap: the two 95 % intervals meet"
    )
    return "\n".join(lines)


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("results", nargs="+", help="result JSON files (run, pendulum, massline, ...)")
    p.add_argument(
        "--bench", default=None, help="add the bench file's powertrain values as the first column"
    )
    p.add_argument(
        "--json",
        default=None,
        metavar="OUT",
        help="also write the comparison as JSON ('-': stdout)",
    )
    return p


def run(args: argparse.Namespace) -> int:
    columns: list[tuple[str, dict[str, tuple[float | None, float | None]]]] = []
    if args.bench:
        columns.append(("bench", bench_values(args.bench)))
    for path in args.results:
        name = _method(path)
        if name in {n for n, _ in columns}:
            name = f"{name} ({Path(path).stem})"
        columns.append((name, read_estimate(path)))
    if len(columns) < 2:
        raise UsageError("compare needs at least two columns: give two results, or one and --bench")
    data = compare(columns)
    if args.json:
        write_document(data, args.json)
    if args.json != "-":
        print(format_table(data))
    return 0
