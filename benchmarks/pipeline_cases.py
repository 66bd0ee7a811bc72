"""What the pipeline benchmark's parts share (benchmarks/bench_pipeline.py): the simulated
i3 source, CPU and memory readings, and the figures printed side by side at the end."""

from __future__ import annotations

import os
import resource
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

# as the CLI does: BLAS threads only spin for matrices this small, and steal the core
# the acquisition and MCAP writer threads need
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent
I3 = ROOT / "examples" / "i3-bench.toml"


def _bench(fs: float, duration: float, paced: bool = False) -> tuple[Any, Any, str]:
    from ptinertia.config import load_bench
    from ptinertia.sources import open_source

    bench = load_bench(I3)
    bench = bench.model_copy(
        update={"tacho": bench.tacho.model_copy(update={"phase_reference": "pressure"})}
    )
    text = I3.read_text()
    source = open_source(
        "sim",
        bench,
        accel_rate_hz=fs,
        duration_s=duration,
        tacho={"phase_reference": "pressure"},
        block_s=0.1 if paced else 0.5,
        paced=paced,
        bench_text=text,
    )
    return bench, source, text


FIGURES: dict[str, str] = {}  # name -> figure, printed side by side at the end


def _cpu_s(work: Callable[[], Any]) -> tuple[float, Any]:
    """Process CPU seconds of ``work()`` (the stage runs alone: its threads count too)."""
    t0 = time.process_time()
    out = work()
    return time.process_time() - t0, out


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return pages * resource.getpagesize() / 1e6
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
