"""``ptinertia compare``: estimates from any methods side by side, with their differences.

Reads result documents (``ptinertia run``, ``pendulum``, ``massline`` ``--json``
output; optionally a bench file's values as a nominal column) and prints, per
quantity, each value with its 95 % interval, then each estimate against the
first: the difference, the difference in combined standard deviations
``z = |b - a| / sqrt(s_a^2 + s_b^2)``, and whether the two 95 % intervals overlap
(:mod:`ptinertia.estimates` reads the documents and compares them).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from estimator.result import Z95
from ptinertia.errors import UsageError
from ptinertia.estimates import (
    bench_values,
    compare_estimates,
    method_name,
    read_estimate,
    write_document,
)


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
        name = method_name(path)
        if name in {n for n, _ in columns}:
            name = f"{name} ({Path(path).stem})"
        columns.append((name, read_estimate(path)))
    if len(columns) < 2:
        raise UsageError("compare needs at least two columns: give two results, or one and --bench")
    data = compare_estimates(columns)
    if args.json:
        write_document(data, args.json)
    if args.json != "-":
        print(format_table(data))
    return 0
