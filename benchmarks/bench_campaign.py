"""Campaign replay and study speed on Dask against serial.

Prints:
1. 8 recorded realistic i3 sweeps (20 s each) replayed one after the other in this
   process, then as a campaign on a LocalCluster of 2 worker processes (started
   before the clock runs: a campaign pays that once); parallel efficiency =
   serial time / (2 x campaign time), goal >= 0.8 on the 2-core machine;
2. the cost of one simulated 20 s study run (simulate, dsp, estimator) and what
   1000 runs take on 2 workers at that rate.

Usage: python benchmarks/bench_campaign.py [--logs 8] [--workers 2] [--duration 20]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

from ptinertia.batch.campaign import ReplayJob, replay_log
from ptinertia.batch.cluster import ClusterSpec, open_client, run_tasks
from ptinertia.batch.study import DEFAULT_VARY, Layout, draw_run, run_seeds, simulate_run
from ptinertia.cli import main as cli
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR

I3 = EXAMPLES_DIR / "i3-bench.toml"


def record(folder: Path, n: int, duration_s: float) -> list[Path]:
    logs = []
    for seed in range(n):
        log = folder / f"run{seed}.mcap"
        argv = ["run", "--rerun", "off", "--quiet", "--realistic", "--seed", str(seed)]
        with contextlib.redirect_stdout(io.StringIO()):  # the run's table is not a figure here
            assert cli([*argv, "--duration", str(duration_s), "--record", str(log)]) == 0
        logs.append(log)
    return logs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--duration", type=float, default=20.0)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-campaign-") as tmp:
        logs = record(Path(tmp), a.logs, a.duration)
        job = ReplayJob()
        replay_log(str(logs[0]), job)  # warm the imports and caches, as the workers will be
        t0 = time.perf_counter()
        serial = [replay_log(str(p), job) for p in logs]
        t_serial = time.perf_counter() - t0
        with open_client(ClusterSpec(workers=a.workers)) as client:
            run_tasks(client, replay_log, [(str(logs[0]), job)] * a.workers)  # warm the workers
            t0 = time.perf_counter()
            parallel = run_tasks(client, replay_log, [(str(p), job) for p in logs])
            t_parallel = time.perf_counter() - t0
            bench = load_bench(I3)
            draws = [draw_run(bench, DEFAULT_VARY, s) for s in run_seeds(0, 5 * a.workers)]
            calls = [(str(I3), Layout("bench"), d, 20.0) for d in draws]
            run_tasks(client, simulate_run, calls[: a.workers])
            t0 = time.perf_counter()
            run_tasks(client, simulate_run, calls)
            t_study = time.perf_counter() - t0
    same = all(
        isinstance(p, type(s)) and p.doc == s.doc for p, s in zip(parallel, serial, strict=True)
    )
    eff = t_serial / (a.workers * t_parallel)
    print(
        f"== campaign: {a.logs} logs of {a.duration:g} s, serial {t_serial:.2f} s, "
        f"{a.workers} workers {t_parallel:.2f} s: speed-up {t_serial / t_parallel:.2f}, "
        f"parallel efficiency {eff:.2f} (goal >= 0.8); results identical to serial: {same}"
    )
    per_run = t_study * a.workers / len(calls)
    print(
        f"== study: one 20 s run costs {per_run:.2f} s of one core; 1000 runs on "
        f"{a.workers} workers take {1000 * per_run / a.workers / 60:.1f} min"
    )


if __name__ == "__main__":
    main()
