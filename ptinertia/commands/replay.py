"""``ptinertia replay``: re-run dsp and estimator on a recorded MCAP log.

With unchanged settings the estimates are bit-identical to those of the live
run (the log keeps the exact float32 samples the live dsp stage saw); with
``--bench``, ``--orders`` or ``--no`` it re-estimates. A directory or several
logs are a campaign on Dask (:mod:`ptinertia.commands.replay_campaign`): one
result per log, a table and a plot.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path
from typing import Any

from acquisition.can.source import CanFrameSource
from ptinertia.commands.replay_campaign import add_campaign_arguments, replay_campaign
from ptinertia.commands.run import (
    CORRECTIONS,
    add_force_flag,
    add_mount_scale_flag,
    check_outputs,
    parse_orders,
    recorder_sinks,
    viewer_sinks,
)
from ptinertia.errors import UsageError
from ptinertia.no_estimate import no_estimate_reason
from ptinertia.outputs import input_files
from ptinertia.recorded_bench import replay_bench
from ptinertia.recorded_run import run_recording
from ptinertia.runner import RunOptions, print_table, write_json
from ptinertia.to_can import can_plan
from replay.reader import find_logs, open_log
from replay.schemas import TOPIC_CAN
from replay.source import McapSource


def add_parser(sub: Any, name: str, help_text: str) -> None:
    p = sub.add_parser(name, help=help_text, description=__doc__)
    p.add_argument("log", nargs="+", help="an MCAP recording, several, or a directory of them")
    p.add_argument("--bench", help="bench TOML overriding the one stored in the log")
    p.add_argument("--json", metavar="PATH", help="result document (a directory: one file per log)")
    p.add_argument("--record", metavar="PATH", help="record the replay again (single log only)")
    add_force_flag(p)
    p.add_argument(
        "--rerun",
        metavar="MODE",
        default="off",
        help="spawn | connect[=ADDR] | save=PATH | serve | off (default off)",
    )
    p.add_argument("--speed", default="max", help="max (default) or realtime, or a factor like 10")
    p.add_argument(
        "--dbc",
        metavar="PATH",
        help="decode the recorded raw CAN frames again with this DBC (a corrected one) "
        "instead of replaying the samples decoded live",
    )
    p.add_argument("--orders", help="orders to track (default: the bench's [dsp] orders)")
    p.add_argument("--no", action="append", default=[], choices=CORRECTIONS, metavar="CORRECTION")
    add_mount_scale_flag(p)
    p.add_argument("--quiet", action="store_true")
    add_campaign_arguments(p)


MIN_SPEED = 1e-3


def parse_speed(text: str) -> float | None:
    if text == "max":
        return None
    if text == "realtime":
        return 1.0
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    # below 1e-3 a second of log would take over 15 minutes: a typo, not a wish
    if not (math.isfinite(value) and MIN_SPEED <= value):
        raise UsageError(
            f"--speed: expected max, realtime or a finite factor >= {MIN_SPEED:g}, got {text!r}"
        )
    return value


def replay_one(log_path: Path, args: argparse.Namespace, json_path: Path | None) -> int:
    log = open_log(log_path, check_later=True)  # the data CRC beside the set-up
    bench, bench_text = replay_bench(log, log_path, args.bench, args.mount_scale)
    source: Any = McapSource(log, speed=parse_speed(args.speed))
    if args.dbc:
        source = redecoded_can(log, bench, args.dbc, log_path)
    # a damaged log stops here, before a sink creates its output (--record, --rerun save)
    log.verify()
    sinks = recorder_sinks(args.record) + viewer_sinks(args.rerun, args.record)
    options = RunOptions(
        orders=parse_orders(args.orders),
        corrections_off=tuple(args.no),
        quiet=args.quiet,
        live=getattr(source, "speed", None) is not None,
        sinks=tuple(sinks),
    )
    summary, doc = run_recording(log, str(log_path), bench, bench_text, options, source, args.dbc)
    for line in log.report.lines():
        print(f"{log_path}: {line}", file=sys.stderr)
    if doc is None or summary.estimate is None:
        print(
            f"{log_path}: no estimate: {no_estimate_reason(summary.rejected, summary.orders_rejected)}",
            file=sys.stderr,
        )
        return 1
    print(f"== {log_path}")
    print_table(summary.estimate, doc)
    if json_path is not None:
        write_json(doc, json_path)
        print(f"result written to {json_path}")
    return 0


def redecoded_can(log: Any, bench: Any, dbc: str, log_path: Path) -> Any:
    """A source decoding the log's raw CAN frames again with ``dbc``."""
    batches = iter(log.can_frames())
    first = next(batches, None) if TOPIC_CAN in log.topics else None
    if first is None:
        raise UsageError(
            f"--dbc: {log_path} holds no raw CAN frames (it was not recorded from a CAN bus)"
        )
    plan = can_plan(bench, dbc)
    return CanFrameSource(plan, itertools.chain([first], batches))


def run(args: argparse.Namespace) -> int:
    if len(args.log) > 1 or Path(args.log[0]).is_dir():
        return replay_campaign(args)
    logs = find_logs(Path(args.log[0]))
    check_outputs(args, input_files(logs[0], args.bench, args.dbc))
    parse_speed(args.speed)  # a bad --speed fails before the log is read
    return replay_one(logs[0], args, Path(args.json) if args.json else None)
