"""``ptinertia study``: how good can this set-up be? A Monte Carlo study on Dask.

N simulated sweeps of the bench, each with sensor, model-input and noise errors
drawn from the bench file's declared tolerances (``--vary``, see
:mod:`ptinertia.batch.study`), each through the real dsp and estimator. Prints per term
the bias, spread, worst error and how often the 95 % interval held the truth;
writes ``study.csv``, ``runs.csv``, ``layouts.csv`` and ``study.png`` to ``--out``.
``--layouts L.toml`` compares candidate sensor layouts on the same draws and ranks
them. The same ``--seed`` gives the same numbers whatever the number of workers.

Cost (i3 example, 9 channels at 5120 Hz, measured on the 2-core development
machine): one 20 s sweep (simulation, dsp, estimator) costs 0.5 s of one core when
the machine is quiet, 1.1 s when it is shared (load 14); 1000 such runs on two cores
take 4 to 9 minutes (``benchmarks/bench_campaign.py`` prints the figure).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, TextIO

from ptinertia.batch.cluster import add_cluster_arguments, spec_from_args
from ptinertia.batch.study import load_layouts, parse_vary, run_study
from ptinertia.batch.study_stats import TermStats
from ptinertia.commands.arg_types import positive_float
from ptinertia.config import load_bench
from ptinertia.paths import DEFAULT_BENCH

SCALE = {"kgm2": (1.0, "kg m^2"), "m": (1e3, "mm"), "kg": (1.0, "kg")}


def add_parser(sub: Any, name: str, help_text: str) -> None:
    p = sub.add_parser(
        name,
        help=help_text,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--bench", default=str(DEFAULT_BENCH), help="bench TOML (default: the i3 example)"
    )
    p.add_argument(
        "--runs", type=int, default=100, metavar="N", help="simulated sweeps (default 100)"
    )
    p.add_argument(
        "--vary",
        metavar="ERRORS",
        help="errors to draw, comma-separated: noise, gain, alignment, position, unbalance, gas, "
        "spin_inertia, masses, mounts (the model inputs from [estimator]'s declared "
        "tolerances); default noise,gain,alignment,position,unbalance",
    )
    p.add_argument("--layouts", metavar="L.toml", help="candidate sensor layouts to compare")
    p.add_argument("--seed", type=int, default=0, help="the study's seed (default 0)")
    p.add_argument(
        "--duration",
        type=positive_float,
        metavar="S",
        help="sweep duration in s (default: the bench's)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="tables and plot go here")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_cluster_arguments(p)


def run(args: argparse.Namespace) -> int:
    vary = parse_vary(args.vary)
    bench = load_bench(args.bench)
    layouts = load_layouts(args.layouts, bench)
    out_dir = Path(args.out)
    outcome = run_study(
        str(Path(args.bench).resolve()),
        args.runs,
        vary,
        layouts,
        args.seed,
        args.duration,
        out_dir,
        spec_from_args(args),
        progress=not args.quiet,
    )
    print(f"== {args.runs} runs, varying {', '.join(vary) or 'nothing'}, seed {args.seed}")
    for name, per_term in outcome.stats.items():
        failed = sum(r.error is not None for r in outcome.results[name])
        print(f"-- layout {name}: {args.runs - failed} runs with an estimate, {failed} without")
        print_stats(per_term)
    if len(outcome.ranking) > 1:
        print("== layouts ranked by inertia RMS error (% of the mean principal moment)")
        for k, (name, score, cog, n) in enumerate(outcome.ranking, 1):
            print(f"{k}. {name:20} inertia {score:6.2f} %  cog {cog:6.2f} mm  ({n} runs)")
    print(f"tables and plot written to {out_dir}")
    return 0 if all(n for *_, n in outcome.ranking) else 1


def print_stats(stats: dict[str, TermStats], out: TextIO | None = None) -> None:
    """One line per term: truth, bias, spread, worst error, coverage, claimed interval (to
    ``out``, default the standard output at call time)."""
    out = sys.stdout if out is None else out
    print(
        f"{'term':5} {'truth':>9} {'bias':>9} {'spread':>9} {'worst':>9} {'95%+-':>9} "
        f"{'covered':>8}  unit",
        file=out,
    )
    for s in stats.values():
        scale, unit = SCALE[s.unit]
        cells = [s.truth, s.bias, s.spread, s.worst, s.mean_ci95]
        text = " ".join(f"{scale * v:9.4f}" for v in cells)
        print(f"{s.term:5} {text} {100 * s.coverage:7.0f}%  {unit}", file=out)
