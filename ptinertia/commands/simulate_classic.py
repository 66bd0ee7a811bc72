"""``ptinertia simulate-pendulum`` and ``simulate-frf``: classical test data of a bench's powertrain.

``simulate-pendulum --bench B.toml --out test.toml``: a pendulum (or
rolling-plate) test file of the bench's ``[powertrain]``: seven swing axes
(X, Y, Z, three face diagonals, one body diagonal), plumb lines from the
mounts' positions, the errors asked for drawn into the readings and declared
as the file's uncertainties, the truth in ``[truth]``.

``simulate-frf --bench B.toml --out frf.uff``: accelerance FRFs of the
powertrain hung on a soft suspension (modes up to ``--suspension-hz``) with
one elastic mode, at the bench's sensors, for two hits beside each sensor;
written as UFF: units (164), nodes (2411: sensors 1.., hits 101..) and one
dataset 58 per FRF, so ``ptinertia massline frf.uff --bench B.toml`` reads it
without a set-up file.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.classical.classic_sim import (
    ElasticModeSpec,
    PendulumNoise,
    default_hits,
    simulate_frfs,
    simulate_pendulum_test,
    soft_suspension,
)
from acquisition.classical.frf_matrix import frfs_from_matrix
from acquisition.classical.pendulum_file import dumps_pendulum_test
from acquisition.classical.uff import write_uff
from powertrain.mounted import MountedPowertrain
from ptinertia.commands.arg_types import finite_float
from ptinertia.commands.arg_types import seed as seed_type
from ptinertia.config import load_bench
from ptinertia.errors import UsageError
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.to_physics import build_model

HIT_NODE0 = 101


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("--bench", default=str(DEFAULT_BENCH), help="bench file (default: %(default)s)")
    p.add_argument("--out", required=True, help="file to write")
    p.add_argument("--seed", type=seed_type, default=0, help="noise seed (default: %(default)s)")
    if name == "simulate-pendulum":
        p.add_argument("--method", choices=("pendulum", "rolling_plate"), default="pendulum")
        p.add_argument(
            "--stiffness-nm-per-rad", type=finite_float, default=40.0, help="suspension stiffness"
        )
        p.add_argument("--period-noise-pct", type=finite_float, default=0.0)
        p.add_argument("--stiffness-noise-pct", type=finite_float, default=0.0)
        p.add_argument("--stiffness-calibration-pct", type=finite_float, default=0.0)
        p.add_argument("--axis-noise-deg", type=finite_float, default=0.0)
        p.add_argument("--line-noise-mm", type=finite_float, default=0.0)
        p.add_argument("--line-angle-noise-deg", type=finite_float, default=0.0)
        p.add_argument("--plate-inertia-kgm2", type=finite_float, default=0.8)
    else:
        p.add_argument(
            "--snr-db",
            type=finite_float,
            default=40.0,
            help="relative noise per line (default: %(default)s)",
        )
        p.add_argument("--exact", action="store_true", help="no noise")
        p.add_argument(
            "--suspension-hz", type=finite_float, default=5.0, help="highest suspension mode"
        )
        p.add_argument("--elastic-hz", type=finite_float, default=250.0, help="first elastic mode")
        p.add_argument("--no-elastic", action="store_true", help="a rigid test article")
        p.add_argument("--df-hz", type=finite_float, default=0.25, help="frequency resolution")
        p.add_argument("--fmax-hz", type=finite_float, default=400.0, help="highest frequency")
        p.add_argument("--binary", action="store_true", help="binary 58b datasets")
    return p


def simulate_pendulum(args: argparse.Namespace) -> str:

    for option in (
        "period_noise_pct",
        "stiffness_noise_pct",
        "stiffness_calibration_pct",
        "axis_noise_deg",
        "line_noise_mm",
        "line_angle_noise_deg",
    ):
        if not getattr(args, option) >= 0:
            raise UsageError(
                f"--{option.replace('_', '-')}: expected >= 0, got {getattr(args, option):g}"
            )
    if not args.stiffness_nm_per_rad > 0:
        raise UsageError(f"--stiffness-nm-per-rad: expected > 0, got {args.stiffness_nm_per_rad:g}")
    bench = load_bench(args.bench)
    body = build_model(bench).body
    points = [m.position_m for m in bench.mounts] or [s.position_m for s in bench.sensors]
    noise = PendulumNoise(
        period_pct=args.period_noise_pct,
        stiffness_pct=args.stiffness_noise_pct,
        stiffness_calibration_pct=args.stiffness_calibration_pct,
        axis_deg=args.axis_noise_deg,
        line_position_m=args.line_noise_mm / 1e3,
        line_angle_deg=args.line_angle_noise_deg,
    )
    test = simulate_pendulum_test(
        body,
        stiffness=args.stiffness_nm_per_rad,
        suspension_points=np.array(points),
        method=args.method,
        plate_inertia=args.plate_inertia_kgm2,
        noise=noise,
        seed=args.seed,
        name=f"{bench.meta.name} {args.method.replace('_', ' ')} (simulated)",
    )
    header = (
        f"Simulated by ptinertia simulate-pendulum from {args.bench} (seed {args.seed}).\n"
        "Format: docs/classical-methods.md. Evaluate with: ptinertia pendulum THIS.toml"
    )
    text = dumps_pendulum_test(test, header)
    Path(args.out).write_text(text, encoding="utf-8")
    return f"wrote {args.out}: {len(test.configurations)} configurations, {len(test.lines)} plumb lines"


def simulate_frf(args: argparse.Namespace) -> str:

    if not (args.df_hz > 0 and args.fmax_hz > 2 * args.df_hz):
        raise UsageError(
            f"--df-hz {args.df_hz:g} and --fmax-hz {args.fmax_hz:g}: need 0 < 2 df < fmax"
        )
    if not args.suspension_hz > 0 or not args.elastic_hz > 0:
        raise UsageError("--suspension-hz and --elastic-hz must be > 0")
    bench = load_bench(args.bench)
    model = build_model(bench)
    body = model.body
    sensor_pos = np.array([s.position_m for s in bench.sensors])
    hits = default_hits(sensor_pos)
    mounts = soft_suspension(body, top_hz=args.suspension_hz)
    modes = MountedPowertrain(body, mounts).modes().frequency_hz
    s = bench.engine.crank_axis
    elastic = (
        None
        if args.no_elastic
        else ElasticModeSpec(frequency_hz=args.elastic_hz, axis=(s[0], s[1], s[2]))
    )
    freq = np.arange(2 * args.df_hz, args.fmax_hz + 0.5 * args.df_hz, args.df_hz)
    h = simulate_frfs(
        body,
        model.channel_positions,
        model.channel_directions,
        hits,
        freq,
        mounts,
        elastic,
        None if args.exact else args.snr_db,
        args.seed,
    )
    codes = [(i, k + 1) for i, s in enumerate(bench.sensors) for k, c in enumerate(s.channels) if c]
    response_nodes = list(range(1, len(bench.sensors) + 1))
    excitations = []
    nodes = {n: np.array(s.position_m) for n, s in zip(response_nodes, bench.sensors, strict=True)}
    for j, hit in enumerate(hits):
        node = HIT_NODE0 + j
        nodes[node] = hit.position
        excitations.append((node, int(np.argmax(np.abs(hit.direction))) + 1))
    frfs = frfs_from_matrix(freq, h, response_nodes, codes, excitations)
    write_uff(args.out, frfs, nodes, f"ptinertia simulate-frf {bench.meta.name}", args.binary)
    return (
        f"wrote {args.out}: {len(frfs)} FRFs ({len(codes)} channels x {len(hits)} hits), "
        f"{len(freq)} lines {freq[0]:g} to {freq[-1]:g} Hz; suspension modes "
        f"{np.round(modes, 2).tolist()} Hz; elastic mode "
        + ("none" if elastic is None else f"{elastic.frequency_hz:g} Hz")
        + ("" if args.exact else f"; noise {args.snr_db:g} dB")
    )


def run(args: argparse.Namespace) -> int:
    message = simulate_pendulum(args) if args.command == "simulate-pendulum" else simulate_frf(args)
    print(message)
    return 0
