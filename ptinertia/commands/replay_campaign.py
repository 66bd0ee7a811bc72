"""``ptinertia replay DIR|FILES...``: a campaign of logs, replayed on a Dask cluster.

Parses the campaign options of ``replay``, finds the logs, runs
:func:`ptinertia.batch.campaign.run_campaign` and prints one line per log. Exit code 0
when every log gave an estimate, 1 when some did not (their rows say why), 2 for
a bad command line (no logs, a bad scheduler address).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ptinertia.batch.campaign import PLOT_NAME, TABLE_NAME, ReplayJob, print_summary, run_campaign
from ptinertia.batch.cluster import add_cluster_arguments, spec_from_args
from ptinertia.commands.run import parse_orders
from ptinertia.config import load_bench
from ptinertia.errors import UsageError
from replay.reader import find_logs


def add_campaign_arguments(p: argparse.ArgumentParser) -> None:
    group: Any = p.add_argument_group("campaigns (a directory or several logs, on Dask)")
    group.add_argument(
        "--out",
        metavar="DIR",
        help="results, campaign.csv and campaign.png go here "
        "(default: --json, else the directory given, else the first log's)",
    )
    add_cluster_arguments(group)


def campaign_logs(targets: list[str]) -> list[Path]:
    """The logs named: each directory's ``*.mcap`` (sorted), each file as given."""
    logs: list[Path] = []
    for target in targets:
        path = Path(target)
        if not path.exists():
            raise UsageError(f"{path}: no such file or directory")
        logs.extend(p.resolve() for p in find_logs(path))
    stems = [p.stem for p in logs]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        raise UsageError(f"two logs named {twice[0]!r}: their results would overwrite each other")
    return logs


def replay_campaign(args: argparse.Namespace) -> int:
    for flag, value, ok in (
        ("--record", args.record, None),
        ("--dbc", args.dbc, None),
        ("--rerun", args.rerun, "off"),
        ("--speed", args.speed, "max"),
    ):
        if value != ok:
            raise UsageError(f"{flag}: not available for a campaign of logs; replay one log")
    logs = campaign_logs(args.log)
    first = Path(args.log[0])
    out_dir = Path(args.out or args.json or (first if first.is_dir() else logs[0].parent))
    if args.bench:
        load_bench(args.bench)  # a bad bench file is one line here, not one row per log
    job = ReplayJob(
        bench_path=str(Path(args.bench).resolve()) if args.bench else None,
        orders=parse_orders(args.orders),
        corrections_off=tuple(args.no),
        mount_scale=args.mount_scale,
    )
    results = run_campaign(logs, job, out_dir, spec_from_args(args), progress=not args.quiet)
    print_summary(results)
    print(f"campaign table {out_dir / TABLE_NAME}, plot {out_dir / PLOT_NAME}")
    failed = sum(r.doc is None for r in results)
    if failed:
        print(f"{failed} of {len(results)} logs without estimate", file=sys.stderr)
    return 1 if failed else 0
