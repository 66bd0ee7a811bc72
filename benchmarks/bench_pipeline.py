"""The live pipeline's speed, latency and memory (issue 5 figures).

Prints:
1. ``run`` on the simulated i3, 10 channels (9 accelerometers + cylinder pressure) at 25.6 kHz,
   60 s sweep, MCAP recording on, viewer off: real-time factor, MCAP size per hour, and the CPU
   of each of the pipeline's threads (``RunSummary.thread_cpu_s``: source, dsp, estimator and
   sinks; the rest is the MCAP writer's and the set-up's);
2. ``replay`` of that log: real-time factor, whether the result is identical, CPU by thread.
   The busiest thread's CPU bounds what threading can give: "Nx with a free core per thread".
   The GIL lowers that bound. perf samples by thread (issue 24, 3 runs each, loaded machine):
   replay: processing thread (estimator, set-up) python 44 %, numpy 34 % (arrays too small
   to release the GIL), libc 10 %; dsp thread numpy 47 %, BLAS 9 %, python 34 %, libc 8 %;
   source python 33 %, libc 22 %, zstd/zlib 8 %. Counting the processing thread whole and
   the others' interpreter, libc and kernel time as held, the GIL is held for about 75 %
   of a replay's CPU (about 70 % live with recording): with these stages, no arrangement
   of threads passes about 1.3 busy cores, i.e. about 80x for replay, 55x live;
3. a paced (real-time) run, MCAP recording on: the largest delay from a block's arrival to the estimate it
   produced being in every sink;
4. each stage on its own, per minute of data (simulator, MCAP reader, dsp, estimator): CPU
   seconds (the simulator best of three, numpy and with its compiled kernels), and the best
   real-time factor live and replay could reach if the stages overlapped perfectly on two
   cores (the budget against the 100x / 300x targets); the issue's order-tracking
   load (10 ch at 25.6 kHz, orders 1, 1.5, 2: bench_order_tracking.issue_load), numpy and compiled;
   one run of a study (5120 Hz, realistic) with 0.1 s and 0.5 s blocks, and the simulator's share;
5. RSS over a long sweep (``--hours``, default 1 h at 5120 Hz, recording on): growth;
6. the cold start of a short CLI run, ``ptinertia run --duration 5``: wall and CPU, with the
   numpy segment sums (the default) and with the compiled ones (``PTINERTIA_NUMBA=1``), the
   latter with an empty numba cache (the first run after an install) and a filled one;
7. the figures side by side: order tracking, estimator, replay, live with recording, simulator,
   each with the load average when it was taken (CPU figures suffer less from other work than
   wall figures, but not nothing: the cores' caches are shared).
8. the estimator alone on the 60 s log's frames (issue 24: <= 60 us per used frame), best of
   three: fed as the blocks replay and studies hand it, and one frame at a time as a live
   run may, with the share of the row assembly (rows, sensitivities, RLS sums); and the
   replay of the log again, best of three (>= 300x).

Usage: python benchmarks/bench_pipeline.py [--hours 1.0] [--skip-long]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
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


def live_and_replay(tmp: Path) -> Path:
    from ptinertia.runner import RunOptions, run_source
    from replay.recorder import McapRecorder
    from replay.source import McapSource

    bench, source, text = _bench(25600.0, 60.0)
    channels = sum(len(g.channels) for g in source.layout.groups if g.rate_hz == 25600.0)
    log = tmp / "live.mcap"
    t0, c0 = time.perf_counter(), time.process_time()
    summary, doc = run_source(
        bench, text, source, "sim", RunOptions(quiet=True, sinks=(McapRecorder(log),))
    )
    # process CPU counts every thread (source, processing, MCAP writer): CPU / wall is how
    # many cores the run kept busy
    live, live_cpu = time.perf_counter() - t0, time.process_time() - c0
    size_h = log.stat().st_size * 60 / 1e9
    print(f"live run, {channels} ch at 25.6 kHz + tacho edges + rpm, 60 s, MCAP on, viewer off:")
    print(
        f"  {live:.1f} s = {60 / live:.0f}x real time (CPU {live_cpu:.1f} s: {live_cpu / live:.2f} "
        f"cores busy);  MCAP {log.stat().st_size / 1e6:.0f} MB per minute, {size_h:.2f} GB per hour"
    )
    print(f"  {_threads(summary.thread_cpu_s, live_cpu, 'MCAP writer, set-up')}")
    t0, c0 = time.perf_counter(), time.process_time()
    replayed, again = run_source(bench, text, McapSource(log), "sim", RunOptions(quiet=True))
    rep, rep_cpu = time.perf_counter() - t0, time.process_time() - c0
    same = json.dumps(doc, sort_keys=True) == json.dumps(again, sort_keys=True)
    print(
        f"replay: {rep:.1f} s = {60 / rep:.0f}x real time (CPU {rep_cpu:.1f} s, "
        f"{rep_cpu / rep:.2f} cores busy); result identical to the live run: {same}"
    )
    print(f"  {_threads(replayed.thread_cpu_s, rep_cpu, 'set-up, file scan')}")
    load = _load()
    FIGURES["live with recording"] = (
        f"{60 / live:.0f}x (wall; {live_cpu / live:.2f} cores busy; load {load}); "
        f"{_bound(summary.thread_cpu_s)}"
    )
    FIGURES["replay"] = f"{60 / rep:.0f}x (wall; load {load}), identical to live: {same}"
    return log


def _threads(cpu: dict[str, float], process_cpu: float, other: str) -> str:
    """The pipeline's threads' CPU seconds (``RunSummary.thread_cpu_s``), and the rest of
    the process's (``other``: what else ran)."""
    rest = process_cpu - sum(cpu.values())
    return (
        "CPU by thread: "
        + ", ".join(f"{name} {s:.2f} s" for name, s in cpu.items())
        + f", other ({other}) {rest:.2f} s"
    )


def _bound(cpu: dict[str, float]) -> str:
    """The real-time factor of the 60 s stream if each thread had a core to itself: the
    busiest thread's CPU (the GIL can only lower it: numpy releases it, Python holds it)."""
    name, busiest = max(cpu.items(), key=lambda kv: kv[1])
    return f"{60 / busiest:.0f}x with a free core per thread ({name} {busiest:.2f} s CPU)"


def _cpu_s(work: Callable[[], Any]) -> tuple[float, Any]:
    """Process CPU seconds of ``work()`` (the stage runs alone: its threads count too)."""
    t0 = time.process_time()
    out = work()
    return time.process_time() - t0, out


def stage_budget(log: Path) -> None:
    """Each stage alone on the 60 s log: what the targets leave no room for."""
    from acquisition.stream import SourceEvent
    from ptinertia.runner import processing_chain
    from replay.source import McapSource

    bench, source, _ = _bench(25600.0, 60.0)
    sim, sim_compiled = simulator_alone()
    # as the pipeline reads a recording: its samples are float32 already, not rounded again
    reader, items = _cpu_s(lambda: list(McapSource(log)))
    tracker, estimator = processing_chain(bench, source.layout)  # as run_source sets it up
    batches = []

    def track() -> None:
        for item in items:
            if not isinstance(item, SourceEvent):
                batches.append(tracker.feed(item)[0])
        batches.append(tracker.finish()[0])

    dsp, _ = _cpu_s(track)
    dsp_compiled = _compiled_dsp(bench, source.layout, items)

    def estimate() -> None:
        published = -float("inf")
        for frames in batches:
            outcomes = estimator.update_many(frames) if frames else []
            used = [f for f, o in zip(frames, outcomes, strict=True) if o.reason is None]
            # as the pipeline does as fast as possible: an estimate every 0.5 s of stream
            if used and used[-1].time_s - published >= 0.5:
                published = used[-1].time_s
                estimator.estimate(final=False)
        estimator.estimate()

    est, _ = _cpu_s(estimate)
    used = estimator.stats.used
    load = _load()
    FIGURES["dsp stage of this run"] = (
        f"{60 / dsp:.0f}x numpy"
        + ("" if dsp_compiled is None else f", {60 / dsp_compiled:.0f}x compiled sums")
        + f" (CPU, one core; 9 accel + pressure spectrum; load {load})"
    )
    FIGURES["estimator"] = f"{1e6 * est / max(used, 1):.0f} us per used frame (CPU; load {load})"
    FIGURES["simulator"] = (
        f"{60 / sim:.0f}x numpy"
        + ("" if sim_compiled is None else f", {60 / sim_compiled:.0f}x compiled")
        + f" (CPU, best of 3; load {load})"
    )
    print("each stage alone, CPU seconds per minute of data (10 ch at 25.6 kHz):")
    print(
        f"  simulator {sim:.2f}  MCAP reader {reader:.2f}  dsp {dsp:.2f}  estimator {est:.2f}"
        f" ({1e3 * est / max(used, 1):.2f} ms per used frame, {used} frames)"
    )
    # The stages' CPU shared perfectly over two cores is the bound for any arrangement
    # of these stages (threads, processes). The pipeline runs source, dsp and estimator
    # on three threads (ptinertia.pipeline): with no GIL, the busiest stage would bound it;
    # with the GIL, the time each stage holds it adds up (the estimator holds it most of
    # its time, the dsp about half of its time: perf samples, see the docstring).
    live_cores = 60 / max(sim, dsp, est, (sim + dsp + est) / 2)
    replay_cores = 60 / max(reader, dsp, est, (reader + dsp + est) / 2)
    live_serial = 60 / max(sim, dsp + est)
    replay_serial = 60 / max(reader, dsp + est)
    print(
        f"  best case on two cores, stages on their own threads, GIL aside: live "
        f"{live_cores:.0f}x, replay {replay_cores:.0f}x; with dsp and estimator one after the "
        f"other: live {live_serial:.0f}x, replay {replay_serial:.0f}x (targets 100x, 300x)"
    )


def simulator_alone(repeat: int = 3) -> tuple[float, float | None]:
    """CPU seconds of the simulator alone on the stage budget's load (the i3, 9 accelerometers
    + pressure at 25.6 kHz, rpm, tacho edges, 60 s in 0.5 s blocks; the source built before
    the clock starts), best of ``repeat``: the numpy path (the default), and the compiled
    kernels (``PTINERTIA_NUMBA=1``, acquisition.sim.kernels; warmed up), None without numba.

    Measured (issue 24, load average 11.6-12 on the 2 cores, interleaved runs, best of 3):
    main at 42d3d9f 0.27-0.28 s (215-223x); numpy now 0.225-0.23 s (261-267x: the angles
    computed once for accelerations and pressure, the pressure spline on its uniform grid);
    compiled 0.127-0.131 s (458-472x). The compiled path's time: the BLAS product about
    60 ms, carriers 14, Horner sums 10, pressure 9, angles and intervals 6, tacho edges 6,
    the per-block Python the rest. With --realistic's noise (9 channels of numpy's normal
    draws, 0.12 s a minute whichever path): main 0.40-0.44 s, numpy 0.37, compiled 0.27.
    """
    from acquisition.sim import kernels

    def best() -> float:
        times = []
        for _ in range(repeat):
            _, source, _ = _bench(25600.0, 60.0)
            times.append(_cpu_s(lambda: sum(1 for _ in source))[0])  # noqa: B023 - called at once
        return min(times)

    numpy_path = best()
    if not kernels.AVAILABLE:
        return numpy_path, None
    saved = kernels.USE
    kernels.USE = True
    try:
        _, warm, _ = _bench(25600.0, 1.0)
        sum(1 for _ in warm)  # loads (or compiles) the kernels
        return numpy_path, best()
    finally:
        kernels.USE = saved


def _compiled_dsp(bench: Any, layout: Any, items: list[Any]) -> float | None:
    """CPU seconds of the dsp stage with the compiled segment sums (warmed up), or None."""
    from acquisition.stream import SourceEvent
    from dsp import kernels
    from ptinertia.runner import processing_chain

    if not kernels.AVAILABLE:
        return None
    kernels.USE = True
    try:
        best = float("inf")
        for _ in range(3):  # the first loads (or compiles) the kernel: best of three
            tracker, _ = processing_chain(bench, layout)

            def track() -> None:
                for item in items:
                    if not isinstance(item, SourceEvent):
                        tracker.feed(item)  # noqa: B023 - called at once
                tracker.finish()  # noqa: B023

            best = min(best, _cpu_s(track)[0])
        return best
    finally:
        kernels.USE = False


def order_tracking() -> None:
    """The issue's order-tracking load (bench_order_tracking.issue_load), numpy and compiled."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_order_tracking import issue_load

    cpu, cpu_c = issue_load(30.0)
    compiled = "" if cpu_c is None else f", {30 / cpu_c:.0f}x compiled sums"
    FIGURES["order tracking, 10 ch, 1 1.5 2"] = (
        f"{30 / cpu:.0f}x numpy sums{compiled} (CPU, one core; load {_load()})"
    )


def study_run() -> None:
    """One run of a study (the i3 at 5120 Hz, realistic errors, 60 s): CPU of the whole run
    with the simulator's 0.1 s blocks and with 0.5 s blocks, and of the simulator alone."""
    from ptinertia.config import load_bench
    from ptinertia.runner import RunOptions, run_source
    from ptinertia.sources import REALISTIC_SIMULATION, open_source

    bench = load_bench(I3)
    text = I3.read_text()
    cpu: dict[float, float] = {}
    terms: dict[float, dict[str, Any]] = {}
    for block in (0.1, 0.5):
        source = open_source("sim", bench, **REALISTIC_SIMULATION, block_s=block)
        t0 = time.process_time()
        _, doc = run_source(bench, text, source, "sim", RunOptions(quiet=True))
        cpu[block] = time.process_time() - t0
        terms[block] = doc["inertia_kgm2"]["value"] if doc else {}
    source = open_source("sim", bench, **REALISTIC_SIMULATION, block_s=0.1)
    sim, _ = _cpu_s(lambda: sum(1 for _ in source))
    moved = max(
        (abs(terms[0.5][k] / v - 1) for k, v in terms[0.1].items() if v), default=float("nan")
    )
    print(
        f"study run (i3, 5120 Hz, realistic, 60 s): CPU {cpu[0.1]:.2f} s with 0.1 s blocks, of "
        f"which the simulator {sim:.2f} s ({100 * sim / cpu[0.1]:.0f} %); {cpu[0.5]:.2f} s with "
        f"0.5 s blocks (inertia terms moved by {moved:.1e} relative)"
    )
    FIGURES["study run, 5120 Hz realistic"] = (
        f"CPU {cpu[0.1]:.2f} s (simulator {100 * sim / cpu[0.1]:.0f} %), "
        f"{cpu[0.5]:.2f} s with 0.5 s blocks (load {_load()})"
    )


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def estimator_alone(log: Path, repeat: int = 3) -> None:
    """The estimator on the frames of the 60 s log: CPU per used frame, blocks and single
    frames, best of ``repeat`` (each run from a fresh estimator, published as the pipeline
    does as fast as possible: an estimate every 0.5 s of stream)."""
    from acquisition.stream import SourceEvent
    from ptinertia.pipeline import as_recorded
    from ptinertia.runner import processing_chain
    from replay.source import McapSource

    bench, source, _ = _bench(25600.0, 60.0)
    tracker, _ = processing_chain(bench, source.layout)
    blocks = []
    for item in McapSource(log):
        if not isinstance(item := as_recorded(item), SourceEvent):
            blocks.append(tracker.feed(item)[0])
    blocks.append(tracker.finish()[0])

    def once(single: bool) -> tuple[float, float, int]:
        estimator = processing_chain(bench, source.layout)[1]
        rows = [0.0]
        flush = estimator._flush

        def timed_flush() -> None:  # the row assembly and the RLS sums
            t0 = time.process_time()
            flush()
            rows[0] += time.process_time() - t0

        estimator._flush = timed_flush  # type: ignore[method-assign]
        t0 = time.process_time()
        _feed(estimator, blocks, single)
        return time.process_time() - t0, rows[0], estimator.stats.used

    print(f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    for single in (False, True):
        best = min((once(single) for _ in range(repeat)), key=lambda r: r[0])
        cpu, rows, used = best
        how = "one frame at a time (live)" if single else "in blocks (replay, studies)"
        print(
            f"estimator alone, {how}: {1e6 * cpu / used:.0f} us per used frame (CPU, best of "
            f"{repeat}, {used} frames), of which row assembly and RLS sums {1e6 * rows / used:.0f} us"
        )
        if not single:
            FIGURES["estimator alone, blocks"] = f"{1e6 * cpu / used:.0f} us per used frame (CPU)"


def _feed(estimator: Any, blocks: list[list[Any]], single: bool) -> None:
    published = -float("inf")
    for frames in blocks:
        if single:
            outcomes = [estimator.update(f) for f in frames]
        else:
            outcomes = estimator.update_many(frames) if frames else []
        used = [f for f, o in zip(frames, outcomes, strict=True) if o.reason is None]
        if used and used[-1].time_s - published >= 0.5:
            published = used[-1].time_s
            estimator.estimate(final=False)
    estimator.estimate()


def replay_repeated(log: Path, repeat: int = 3) -> None:
    """Replay of the 60 s log, best of ``repeat`` (wall and CPU): the replay figure on a
    shared machine."""
    from ptinertia.runner import RunOptions, run_source
    from replay.source import McapSource

    bench, _, text = _bench(25600.0, 60.0)
    walls, cpus, threads = [], [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        summary, _ = run_source(bench, text, McapSource(log), "sim", RunOptions(quiet=True))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        threads.append(summary.thread_cpu_s)
    best = min(threads, key=lambda cpu: max(cpu.values()))
    print(
        f"replay, best of {repeat}: {60 / min(walls):.0f}x real time (wall), "
        f"{60 / min(cpus):.0f}x per CPU second (all threads); "
        f"{_threads(best, min(cpus), 'set-up, file scan')}"
    )
    FIGURES["replay, best of 3"] = (
        f"{60 / min(walls):.0f}x (wall), {60 / min(cpus):.0f}x (CPU); {_bound(best)} "
        f"(load {_load()})"
    )


def cold_start(repeat: int = 3) -> None:
    """``ptinertia run --duration 5`` as a user starts it: wall and CPU of the whole process."""
    exe = Path(sys.executable).parent / "ptinertia"
    cmd = [str(exe), "run", "--duration", "5", "--rerun", "off", "--quiet"]

    def once(env: dict[str, str]) -> tuple[float, float]:
        t0 = time.perf_counter()
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, env={**os.environ, **env}, check=True, capture_output=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return time.perf_counter() - t0, cpu

    def best(env: dict[str, str]) -> str:
        runs = [once(env) for _ in range(repeat)]
        return f"wall {min(w for w, _ in runs):.2f} s, CPU {min(c for _, c in runs):.2f} s"

    print(f"cold start of `ptinertia run --duration 5` (best of {repeat}):")
    numpy_path = best({"PTINERTIA_NUMBA": "0"})
    print(f"  numpy segment sums (default): {numpy_path}")
    FIGURES["cold start, run --duration 5"] = f"{numpy_path} (numpy sums, the default)"
    load = _load()
    from dsp import kernels

    if not kernels.AVAILABLE:
        print("  numba is not installed: no compiled figure")
        return
    with tempfile.TemporaryDirectory() as cache:
        env = {"PTINERTIA_NUMBA": "1", "NUMBA_CACHE_DIR": cache}
        wall, cpu = once(env)
        print(
            f"  compiled sums, empty numba cache (first run after an install): wall {wall:.2f} s, CPU {cpu:.2f} s"
        )
        filled = best(env)
        print(f"  compiled sums, numba cache filled: {filled}")
        FIGURES["cold start, compiled sums"] = (
            f"{filled} (cache filled), wall {wall:.2f} s, CPU {cpu:.2f} s (empty cache; load {load})"
        )


def paced_latency(tmp: Path) -> None:
    from ptinertia.runner import RunOptions, run_source
    from replay.recorder import McapRecorder

    bench, source, text = _bench(25600.0, 15.0, paced=True)
    options = RunOptions(quiet=True, live=True, sinks=(McapRecorder(tmp / "paced.mcap"),))
    summary, _ = run_source(bench, text, source, "sim", options)
    print(
        "paced run (0.1 s blocks, 15 s, MCAP on): largest delay from a block's arrival to its "
        "estimate in every sink "
        f"{1e3 * summary.max_estimate_latency_s:.1f} ms; largest backlog "
        f"{1e3 * summary.max_backlog_s:.1f} ms"
    )


def long_run(tmp: Path, hours: float) -> None:
    from ptinertia.runner import RunOptions, run_source
    from replay.recorder import McapRecorder

    bench, source, text = _bench(5120.0, 3600.0 * hours)
    samples: list[tuple[float, float]] = []
    stop = threading.Event()

    def watch() -> None:
        t0 = time.perf_counter()
        while not stop.wait(2.0):
            samples.append((time.perf_counter() - t0, _rss_mb()))

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    log = tmp / "long.mcap"
    t0 = time.perf_counter()
    run_source(bench, text, source, "sim", RunOptions(quiet=True, sinks=(McapRecorder(log),)))
    stop.set()
    wall = time.perf_counter() - t0
    if len(samples) >= 4:
        early = max(rss for _, rss in samples[: len(samples) // 4])
        late = max(rss for _, rss in samples[-len(samples) // 4 :])
        print(
            f"{hours:g} h sweep at 5120 Hz, recording on: {wall:.0f} s; RSS after the first quarter "
            f"{early:.0f} MB, in the last quarter {late:.0f} MB (growth {late - early:+.0f} MB); "
            f"MCAP {log.stat().st_size / 1e9:.2f} GB"
        )


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[1])
        return pages * resource.getpagesize() / 1e6
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--skip-long", action="store_true")
    a = ap.parse_args()
    print(f"load average {_load()} on {os.cpu_count()} cores (a shared machine)")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        log = live_and_replay(tmp)
        paced_latency(tmp)
        stage_budget(log)
        order_tracking()
        study_run()
        estimator_alone(log)
        replay_repeated(log)
        cold_start()
        if not a.skip_long:
            long_run(tmp, a.hours)
    print("side by side (targets of issue 24: order tracking >= 500x on one core, estimator")
    print(
        "<= 60 us per used frame, replay >= 300x, live with recording >= 100x, simulator >= 500x;"
    )
    print(
        "rota-order's figure on the same kind of signal: benchmarks/bench_order_tracking.py, 4.):"
    )
    for name, figure in FIGURES.items():
        print(f"  {name:32s} {figure}")
    print(f"load average at the end {_load()}")


if __name__ == "__main__":
    main()
