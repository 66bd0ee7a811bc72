"""``ptinertia pendulum``: inertia tensor (and cog) from a pendulum or rolling-plate test.

Reads a test file (``examples/pendulum-test.toml``, format in
``docs/classical-methods.md``), solves eqs. 7 or 8 for six or more
configurations, the cog from the plumb lines, and propagates the stated
period, stiffness, angle (and plate) uncertainties into the intervals. The
condition number of the axis set is printed with a warning when it is poor;
a degenerate set (all axes in one plane, ...) is refused with the reason
(:func:`ptinertia.classical.pendulum_document`).
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from estimator.result import Z95
from ptinertia.classical import pendulum_document
from ptinertia.estimates import write_document


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("test", help="pendulum test file (TOML)")
    p.add_argument(
        "--json", default=None, metavar="OUT", help="write the result document ('-': stdout)"
    )
    return p


def format_report(doc: dict[str, Any]) -> str:
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
    doc = pendulum_document(args.test)
    if args.json:
        write_document(doc, args.json)
    if args.json != "-":
        print(format_report(doc))
    return 0
