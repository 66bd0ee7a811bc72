"""``ptinertia excitation``: the engine's loads on the block per order (paper eq. 1).

Forces and moments about the cog, gas and inertia parts apart and their sum,
as amplitude and phase: ``x(t) = |X| cos(h phi + arg X)`` with ``phi`` the crank
angle from cylinder 1's firing TDC.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from ptinertia.commands.arg_types import rpm as rpm_type
from ptinertia.config import load_bench
from ptinertia.errors import UsageError
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.to_physics import build_model

COMPONENTS = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("--bench", default=str(DEFAULT_BENCH), help="bench file (default: %(default)s)")
    p.add_argument("--rpm", type=rpm_type, required=True, help="crank speed, rev/min")
    p.add_argument(
        "--orders",
        default=None,
        help="comma-separated engine orders, multiples of 0.5 (default: 0.5 to the bench's simulation.max_order)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def parse_orders(text: str | None, max_order: float) -> np.ndarray:
    """Orders from ``"0.5,1,1.5"``, or every half order up to ``max_order``."""
    if text is None:
        return np.arange(1, round(2 * max_order) + 1) / 2.0
    try:
        orders = np.array([float(v) for v in text.split(",") if v.strip()])
    except ValueError:
        raise UsageError(f"--orders: expected comma-separated numbers, got {text!r}") from None
    if orders.size == 0 or np.any(orders < 0):
        raise UsageError(f"--orders: expected orders >= 0, got {text!r}")
    return orders


def excitation_table(bench_path: str, rpm: float, orders_text: str | None) -> dict[str, Any]:
    """Everything the command prints, as plain data (complex kept as complex)."""
    if not rpm > 0:
        raise UsageError(f"--rpm: expected a positive speed, got {rpm:g}")
    bench = load_bench(bench_path)
    model = build_model(bench)
    orders = parse_orders(orders_text, bench.simulation.max_order)
    cog = model.body.cog
    parts = model.engine.excitation_parts(rpm, orders, about=cog)
    rows = {}
    for part, (f, m) in parts.items():
        rows[part] = np.hstack([f, m])
    rows["total"] = rows["gas"] + rows["inertia"]
    return {
        "bench": bench.meta.name,
        "rpm": rpm,
        "about_m": cog.tolist(),
        "orders": orders,
        "rows": rows,
    }


def _cell(value: complex, floor: float) -> tuple[str, str]:
    amp = abs(value)
    if amp <= floor:
        return "0", "-"
    return f"{amp:.4g}", f"{np.degrees(np.angle(value)):.1f}"


def format_table(data: dict[str, Any]) -> str:
    rows = data["rows"]
    floor = 1e-9 * max(float(np.abs(r).max()) for r in rows.values())
    lines = [
        f"Engine loads on the block: {data['bench']} at {data['rpm']:g} rpm, about the cog "
        f"({', '.join(f'{v:g}' for v in data['about_m'])}) m",
        "amplitude and phase (deg): x(t) = |X| cos(h phi + phase), phi from cylinder-1 firing TDC",
        "",
    ]
    header = ["order", "part"]
    for name in COMPONENTS:
        unit = "N" if name.startswith("F") else "N m"
        header += [f"|{name}| {unit}", "phase"]
    table = [header]
    for i, h in enumerate(data["orders"]):
        for part in ("gas", "inertia", "total"):
            row = [f"{h:g}", part]
            for value in rows[part][i]:
                row += list(_cell(complex(value), floor))
            table.append(row)
    widths = [max(len(r[j]) for r in table) for j in range(len(header))]
    for r in table:
        lines.append(
            "  ".join(
                v.rjust(w) if j != 1 else v.ljust(w)
                for j, (v, w) in enumerate(zip(r, widths, strict=True))
            )
        )
    return "\n".join(lines)


def to_json(data: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {
        "bench": data["bench"],
        "rpm": data["rpm"],
        "about_m": data["about_m"],
        "units": {"force": "N", "moment": "N m", "phase": "deg"},
        "convention": "x(t) = Re{X exp(i h phi)}, phi from cylinder-1 firing TDC",
        "orders": [],
    }
    for i, h in enumerate(data["orders"]):
        entry: dict[str, Any] = {"order": float(h)}
        for part, values in data["rows"].items():
            entry[part] = {
                name: {
                    "re": float(v.real),
                    "im": float(v.imag),
                    "amplitude": float(abs(v)),
                    "phase_deg": float(np.degrees(np.angle(v))),
                }
                for name, v in zip(COMPONENTS, values[i], strict=True)
            }
        out["orders"].append(entry)
    return out


def run(args: argparse.Namespace) -> int:
    data = excitation_table(args.bench, args.rpm, args.orders)
    print(json.dumps(to_json(data), indent=1) if args.json else format_table(data))
    return 0
