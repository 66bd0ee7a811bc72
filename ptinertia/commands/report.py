"""``ptinertia report``: a self-contained HTML report of a run, for CAE and mount design.

Input: a recording of a run (``run --record``, ``replay --record``), a raw-only
recording (``simulate --out x.mcap``: the chain is run on it first, with the bench
file stored in the log), or a result document (``run --json``; add ``--bench`` for
the modes). ``--png DIR`` also writes every figure as a PNG file.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ptinertia.errors import UsageError
from ptinertia.outputs import WARN, check_output, input_files
from ptinertia.report.build import make_report
from ptinertia.reprocess import reprocess_log


def add_parser(sub: Any, name: str, help_text: str) -> None:
    p = sub.add_parser(name, help=help_text, description=__doc__)
    p.add_argument("input", help="LOG.mcap (recording) or result.json (result document)")
    p.add_argument("--out", default=None, help="HTML file to write (default: INPUT with .html)")
    p.add_argument("--png", metavar="DIR", help="also write every figure as DIR/NAME.png")
    p.add_argument(
        "--bench",
        help="bench TOML: for a result document, enables modes; for a recording, re-estimates with it",
    )
    p.add_argument("--force", action="store_true", help="overwrite without the warning line")


def run(args: argparse.Namespace) -> int:
    src = Path(args.input)
    out = Path(args.out) if args.out else src.with_suffix(".html")
    check_output(out, "--out", input_files(src, args.bench), args.force, WARN)
    if args.png is not None and Path(args.png).exists() and not Path(args.png).is_dir():
        raise UsageError(f"--png {args.png}: not a directory")
    t0 = time.perf_counter()
    report = make_report(
        src, out, bench=args.bench, png_dir=args.png, reprocess=reprocess_log, progress=True
    )
    for line in report.headline:
        print(line)
    size = out.stat().st_size / 1e6
    print(
        f"report written to {out} ({size:.2f} MB, {time.perf_counter() - t0:.1f} s)",
        file=sys.stderr,
    )
    if args.png:
        print(f"{len(report.figures)} figures written to {args.png}", file=sys.stderr)
    return 0
