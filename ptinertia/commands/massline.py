"""``ptinertia massline``: mass, cog and inertia from hammer or shaker FRFs (UFF58).

The response points are the bench file's sensors (matched to UFF nodes by a
set-up file or by position); the excitation points and directions come from
the set-up file or the UFF node table. The mass-line band is chosen between
the suspension modes and the first elastic mode (printed; ``--band``
overrides it). All excitations are fitted at once, with the suspension's
residual stiffness estimated alongside (``--no-residual-stiffness`` shows the
bias it removes).
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from ptinertia.errors import UsageError

DEG = math.pi / 180.0


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    from ptinertia.paths import DEFAULT_BENCH

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
        type=float,
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
        type=float,
        default=5.0,
        help="match UFF nodes to bench sensors within this distance (default: %(default)s)",
    )
    tol = p.add_argument_group("declared 1-sigma uncertainties, propagated into the intervals")
    tol.add_argument("--force-gain-pct", type=float, default=0.0, help="force gauge calibration")
    tol.add_argument("--hit-position-mm", type=float, default=0.0, help="each hit's position")
    tol.add_argument("--hit-direction-deg", type=float, default=0.0, help="each hit's direction")
    tol.add_argument("--sensor-gain-pct", type=float, default=0.0, help="each channel's gain")
    tol.add_argument("--sensor-position-mm", type=float, default=0.0, help="each sensor's position")
    tol.add_argument(
        "--sensor-alignment-deg", type=float, default=0.0, help="each sensor's orientation"
    )
    p.add_argument(
        "--json", default=None, metavar="OUT", help="write the result document ('-': stdout)"
    )
    return p


def compute(
    frf_path: str,
    bench_path: str,
    setup_path: str | None = None,
    band: tuple[float, float] | None = None,
    residual_stiffness: bool = True,
    node_tolerance_m: float = 0.005,
    tolerances: Any = None,
) -> dict[str, Any]:
    """The result document of a mass-line evaluation."""
    from acquisition.classical.frf_matrix import SensorPoint, frf_matrix
    from acquisition.classical.modal_setup import load_modal_setup
    from acquisition.classical.uff import read_uff
    from estimator.classical.massline import FrfGeometry, estimate_mass_line
    from ptinertia.commands.compare import estimate_document
    from ptinertia.config import load_bench

    if band is not None and not (0 <= band[0] < band[1]):
        raise UsageError(f"--band: expected 0 <= LOW < HIGH, got {band[0]:g} {band[1]:g}")
    if not node_tolerance_m > 0:
        raise UsageError(f"--node-tolerance-mm: expected > 0, got {1e3 * node_tolerance_m:g}")
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
        covariance=(["mass", "Gx", "Gy", "Gz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"], body.cov),
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


def format_report(doc: dict[str, Any]) -> str:
    from ptinertia.commands.compare import Z95

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
    from estimator.classical.massline import MassLineTolerances
    from ptinertia.commands.compare import write_document

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
    tolerances = MassLineTolerances(
        force_gain_rel=args.force_gain_pct / 100,
        hit_position_m=args.hit_position_mm / 1e3,
        hit_direction_rad=args.hit_direction_deg * DEG,
        sensor_gain_rel=args.sensor_gain_pct / 100,
        sensor_position_m=args.sensor_position_mm / 1e3,
        sensor_alignment_rad=args.sensor_alignment_deg * DEG,
    )
    doc = compute(
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
