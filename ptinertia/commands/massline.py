"""``ptinertia massline``: mass, cog and inertia from hammer or shaker FRFs (UFF58).

The response points are the bench file's sensors (matched to UFF nodes by a
set-up file or by position); the excitation points and directions come from
the set-up file or the UFF node table. The mass-line band is chosen between
the suspension modes and the first elastic mode (printed; ``--band``
overrides it). All excitations are fitted at once, with the suspension's
residual stiffness estimated alongside (``--no-residual-stiffness`` shows the
bias it removes). The evaluation is :func:`ptinertia.classical.massline_document`.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from estimator.classical.massline_rigid import MassLineTolerances
from estimator.result import Z95
from ptinertia.classical import massline_document
from ptinertia.commands.arg_types import finite_float
from ptinertia.errors import UsageError
from ptinertia.estimates import write_document
from ptinertia.paths import DEFAULT_BENCH

DEG = math.pi / 180.0


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("frf", help="accelerance FRFs, universal file (dataset 58, ASCII or 58b)")
    p.add_argument("--bench", default=str(DEFAULT_BENCH), help="bench file (default: %(default)s)")
    p.add_argument(
        "--setup", default=None, help="set-up TOML: response nodes -> sensors, excitation points"
    )
    p.add_argument(
        "--band",
        nargs=2,
        type=finite_float,
        default=None,
        metavar=("LOW_HZ", "HIGH_HZ"),
        help="mass-line band (default: chosen from the resonances)",
    )
    p.add_argument(
        "--no-residual-stiffness",
        action="store_true",
        help="do not fit the suspension's residual terms (shows their bias)",
    )
    p.add_argument(
        "--node-tolerance-mm",
        type=finite_float,
        default=5.0,
        help="match UFF nodes to bench sensors within this distance (default: %(default)s)",
    )
    tol = p.add_argument_group("declared 1-sigma uncertainties, propagated into the intervals")
    tol.add_argument(
        "--force-gain-pct", type=finite_float, default=0.0, help="force gauge calibration"
    )
    tol.add_argument(
        "--hit-position-mm", type=finite_float, default=0.0, help="each hit's position"
    )
    tol.add_argument(
        "--hit-direction-deg", type=finite_float, default=0.0, help="each hit's direction"
    )
    tol.add_argument(
        "--sensor-gain-pct", type=finite_float, default=0.0, help="each channel's gain"
    )
    tol.add_argument(
        "--sensor-position-mm", type=finite_float, default=0.0, help="each sensor's position"
    )
    tol.add_argument(
        "--sensor-alignment-deg", type=finite_float, default=0.0, help="each sensor's orientation"
    )
    p.add_argument(
        "--json", default=None, metavar="OUT", help="write the result document ('-': stdout)"
    )
    return p


def format_report(doc: dict[str, Any]) -> str:
    band = doc["band_hz"]
    res = ", ".join(f"{r:.4g}" for r in band["resonances"])
    powers = ", ".join(f"{2 * k:+d}" for k in doc["fit"]["powers"])
    lines = [
        f"mass line of {doc['source']}: {len(doc['channels'])} channels x "
        f"{len(doc['excitations'])} excitations",
        f"band {band['low']:.4g} to {band['high']:.4g} Hz ({band['chosen']}; resonances at "
        f"[{res}] Hz), {doc['fit']['lines']} lines, powers of w fitted besides the constant: "
        f"[{powers}]",
        f"FRF misfit {100 * doc['fit']['misfit']:.2f} %, residual terms up to "
        f"{100 * doc['fit']['residual_share']:.0f} % of the mass line, rigid-body misfit "
        f"{100 * doc['rigid_body']['misfit']:.2f} %",
        "",
    ]
    m = doc["mass_kg"]
    lines.append(f"mass  {m['value']:.5g} kg +- {Z95 * m['std']:.2g} (95 %)")
    lines.append("cog (mm), 95 % intervals:")
    for axis, v, s in zip("xyz", doc["cog_m"]["value"], doc["cog_m"]["std"], strict=True):
        lines.append(f"  {axis}  {1e3 * v:10.2f} +- {1e3 * Z95 * (s or 0):.2f}")
    lines.append("inertia about the cog, bench frame (kg m^2), 95 % intervals:")
    inertia = doc["inertia_kgm2"]
    for t, v in inertia["value"].items():
        lines.append(f"  {t}  {v:10.5g} +- {Z95 * (inertia['std'][t] or 0):.2g}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    values = {
        "--force-gain-pct": args.force_gain_pct,
        "--hit-position-mm": args.hit_position_mm,
        "--hit-direction-deg": args.hit_direction_deg,
        "--sensor-gain-pct": args.sensor_gain_pct,
        "--sensor-position-mm": args.sensor_position_mm,
        "--sensor-alignment-deg": args.sensor_alignment_deg,
    }
    for option, value in values.items():
        if not value >= 0:
            raise UsageError(f"{option}: expected a 1-sigma value >= 0, got {value:g}")
    if args.band is not None and not (0 <= args.band[0] < args.band[1]):
        raise UsageError(f"--band: expected 0 <= LOW < HIGH, got {args.band[0]:g} {args.band[1]:g}")
    if not args.node_tolerance_mm / 1e3 > 0:
        raise UsageError(f"--node-tolerance-mm: expected > 0, got {args.node_tolerance_mm:g}")
    tolerances = MassLineTolerances(
        force_gain_rel=args.force_gain_pct / 100,
        hit_position_m=args.hit_position_mm / 1e3,
        hit_direction_rad=args.hit_direction_deg * DEG,
        sensor_gain_rel=args.sensor_gain_pct / 100,
        sensor_position_m=args.sensor_position_mm / 1e3,
        sensor_alignment_rad=args.sensor_alignment_deg * DEG,
    )
    doc = massline_document(
        args.frf,
        args.bench,
        args.setup,
        None if args.band is None else (args.band[0], args.band[1]),
        not args.no_residual_stiffness,
        args.node_tolerance_mm / 1e3,
        tolerances,
    )
    if args.json:
        write_document(doc, args.json)
    if args.json != "-":
        print(format_report(doc))
    return 0
