"""Result documents: the one every estimator writes, read back, and several compared.

The result document (shared by ``run``, ``pendulum`` and ``massline``)::

    {"method": str,
     "inertia_kgm2": {"value": {Ixx..Iyz}, "std": {...}, "ci95": {...}},
     "cog_m": {"value": [x, y, z], "std": [...]} | null,
     "mass_kg": {"value": m, "std": s} | null, ...}

Inertia about the cog, bench frame, products ``Ixy = integral(x y dm)``; a
``std`` of null means not observable. A comparison sets each estimate against the
first: the difference, the difference in combined standard deviations
``z = |b - a| / sqrt(s_a^2 + s_b^2)``, and whether the two 95 % intervals overlap.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from estimator.result import Z95, enforce_physical, principal_axes
from powertrain.rigidbody import TERMS, inertia_matrix
from ptinertia.config import load_bench
from ptinertia.errors import UsageError

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
    """The shared result document (see the module docstring), plus principal moments and axes.

    Parameters
    ----------
    method : label ("pendulum", "rolling_plate", "massline", ...).
    terms, terms_std : (6,) kg m^2, ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` and 1 sigma.
    cog, cog_std : (3,) m, or None when the method gives no cog.
    mass, mass_std : kg, or None when the method gives no mass.
    covariance : optional (names, matrix) of the parameters, SI.
    """
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


def method_name(path: str) -> str:
    """The ``method`` a result document names, else the file's stem."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        return str(doc.get("method") or Path(path).stem)
    except (OSError, json.JSONDecodeError, AttributeError):
        return Path(path).stem


def bench_values(path: str) -> dict[str, tuple[float | None, float | None]]:
    """The bench file's powertrain as a column without intervals."""
    p = load_bench(path).powertrain
    out: dict[str, tuple[float | None, float | None]] = {"mass": (p.mass_kg, 0.0)}
    for key, v in zip(("Gx", "Gy", "Gz"), p.cog_m, strict=True):
        out[key] = (v, 0.0)
    for t in TERMS:
        out[t] = (getattr(p.inertia_kgm2, t), 0.0)
    return out


def compare_estimates(
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
