"""``ptinertia report`` on a 60 s sweep: time to a finished HTML file, its size, the re-simulation check.

Input: the realistic simulated i3 sweep (``ptinertia run --realistic``, 1500 ->
4500 rpm in 60 s, recorded to MCAP; made once, before any clock starts, or given
with ``--log``). Measured:

* the whole command as a user runs it (``python -m ptinertia report LOG --out X``
  in a fresh process: imports, reading the log, the re-simulation, the mode
  intervals, every figure, writing the file), wall clock, best of ``--repeat``;
* the same in process, split into load / render / write;
* the HTML size and the figures' share of it;
* the re-simulation check's figures (worst 95th-percentile dB and deg over the
  judged channels).

    /work/venv/bin/python benchmarks/bench_report.py [--seconds 60] [--repeat 3] [--log run.mcap]

Target (issue 7): under 5 s and under 5 MB for a 60 s sweep.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def make_log(path: Path, seconds: float) -> None:
    from ptinertia.cli import main

    argv = ["run", "--duration", f"{seconds:g}", "--rerun", "off", "--quiet", "--realistic"]
    code = main([*argv, "--record", str(path)])
    if code != 0:
        raise SystemExit(f"the simulated run failed (exit {code})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="sweep duration of the made log")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--log", help="an existing run recording (default: simulate one)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        log = Path(args.log) if args.log else Path(tmp) / "run.mcap"
        if not args.log:
            t0 = time.perf_counter()
            make_log(log, args.seconds)
            print(
                f"made {log.name}: {args.seconds:g} s realistic i3 sweep in {time.perf_counter() - t0:.1f} s"
            )
        out = Path(tmp) / "report.html"

        cli = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            subprocess.run(
                [sys.executable, "-m", "ptinertia", "report", str(log), "--out", str(out)],
                check=True,
                capture_output=True,
            )
            cli.append(time.perf_counter() - t0)

        from ptinertia.report.build import build_report, write_report
        from ptinertia.report.data import load

        split = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            data = load(log)
            t1 = time.perf_counter()
            report = build_report(data)
            t2 = time.perf_counter()
            write_report(report, out)
            t3 = time.perf_counter()
            split.append((t3 - t0, t1 - t0, t2 - t1, t3 - t2))
        best = min(split)
        size = out.stat().st_size
        figures = sum(len(v) for v in report.figures.values())
        frames = 0 if data.frames is None else len(data.frames)
        print(f"log: {log.stat().st_size / 1e6:.1f} MB, {frames} order frames")
        print(
            f"report command (fresh process, wall): best {min(cli):.2f} s of {len(cli)} (all: "
            + ", ".join(f"{t:.2f}" for t in cli)
            + ")"
        )
        print(
            f"in process: {best[0]:.2f} s = load {best[1]:.2f} + render {best[2]:.2f} + write {best[3]:.3f}"
        )
        print(
            f"html: {size / 1e6:.2f} MB, of which {len(report.figures)} figures {figures / 1e6:.2f} MB (PNG, before base64)"
        )
        check = report.check
        if check is not None:
            print(
                f"re-simulation: {'PASS' if check.passed else 'FAIL'}: worst 95th percentile "
                f"{check.worst_db:.3f} dB, {check.worst_deg:.3f} deg on {int(check.assessable.sum())} "
                f"of {check.assessable.size} order-channel pairs"
            )


if __name__ == "__main__":
    main()
