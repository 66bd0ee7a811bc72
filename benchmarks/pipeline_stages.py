"""Each stage of the pipeline alone (benchmarks/bench_pipeline.py, items 4 and 8): the
simulator, the MCAP reader, the dsp (numpy and compiled), the estimator (blocks and single
frames), the issue's order-tracking load and one run of a study, in CPU seconds."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

from pipeline_cases import FIGURES, I3, ROOT, _bench, _cpu_s, _load


def stage_budget(log: Path) -> None:
    """Each stage alone on the 60 s log: what the targets leave no room for."""
    from acquisition.stream import SourceEvent
    from ptinertia.runner import processing_chain
    from replay.source import McapSource

    bench, source, _ = _bench(25600.0, 60.0)
    sim, sim_compiled = simulator_alone()
    # as the pipeline reads a recording: its samples are float32 already, not rounded again
    reader, items = _cpu_s(lambda: list(McapSource(log)))
    # as run_source sets it up (once a run, before the first item: in series with the rest)
    setup = min(_cpu_s(lambda: processing_chain(bench, source.layout))[0] for _ in range(3))
    tracker, estimator = processing_chain(bench, source.layout)
    batches = []

    def track() -> None:
        for item in items:
            if not isinstance(item, SourceEvent):
                batches.append(tracker.feed(item)[0])
        batches.append(tracker.finish()[0])

    dsp, _ = _cpu_s(track)
    dsp_compiled = _compiled_dsp(bench, source.layout, items)

    # as the pipeline does as fast as possible: an estimate every 0.5 s of stream
    est, _ = _cpu_s(lambda: _feed(estimator, batches, single=False))
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
        f" ({1e3 * est / max(used, 1):.2f} ms per used frame, {used} frames); set-up of dsp "
        f"and estimator {setup:.3f} (once a run)"
    )
    # The stages' CPU shared perfectly over two cores is the bound for any arrangement
    # of these stages (threads, processes). The pipeline runs source, dsp and estimator
    # on three threads (ptinertia.pipeline): with no GIL, the busiest stage would bound it;
    # with the GIL, the time each stage holds it adds up (the estimator holds it most of
    # its time, the dsp about half of its time: perf samples, see the docstring).
    live_cores = 60 / (setup + max(sim, dsp, est, (sim + dsp + est) / 2))
    replay_cores = 60 / (setup + max(reader, dsp, est, (reader + dsp + est) / 2))
    live_serial = 60 / (setup + max(sim, dsp + est))
    replay_serial = 60 / (setup + max(reader, dsp + est))
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
    was, kernels.USE = kernels.USE, True
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
        kernels.USE = was


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


def estimator_alone(log: Path, repeat: int = 3) -> None:
    """The estimator on the frames of the 60 s log: CPU per used frame, blocks and single
    frames, best of ``repeat`` (each run from a fresh estimator, published as the pipeline
    does as fast as possible: an estimate every 0.5 s of stream), with the numpy rows and,
    numba installed, the compiled ones (estimator.row_kernels).

    Measured (issue 24, load average 9-10 on the 2 cores, 1498 used frames): in blocks
    160-166 us per used frame with the numpy rows (row assembly and RLS sums 80-82; 163-183
    and 83-93 before the rows' rework), 117-120 compiled (39-40); one frame at a time
    376-387 numpy (88-89; 371-406 and 89-103 before), 315-328 compiled (42-43).
    2026-11-26 (load 0.7), with the fitted runs, gates and channel noise compiled too: in
    blocks 116 us numpy (71), 62 compiled (31); one frame at a time 282 numpy, 145 compiled.
    With the tail's sums scaled from theta's (estimator/compiled_sums.py) and the row
    covariance from 2/3 of its products (same bits), side by side with 0142dad, best of 5,
    load 6-7: in blocks compiled 66 -> 60-62 us (32-33 -> 28-29), numpy 120-121 / 121-123
    (unchanged code); one frame at a time (load 14-15) 155 / 155 compiled. The afternoon's
    build on a quiet machine (load 0.9-1.1, two rounds interleaved with 0142dad's): in blocks
    compiled 62-65 -> 59-60 us, numpy 120-128 -> 119-121; one frame at a time 141 -> 140
    compiled, 290 -> 289 numpy. Issue 24's eighth round (est8: the model inputs' excitation
    derivatives gathered in the compiled loop, the compiled rows' constants kept across
    relinearisations, per-frame records made faster), three rounds interleaved with d450fdd,
    best of 5, load 2.3-2.5: in blocks compiled 63.5-67.2 -> 57.8-59.6 us; as a quiet
    replay runs it (no running estimates, /tmp/prof/stage_prof.py est) 0.080-0.083 ->
    0.073-0.078 s of CPU a minute (load 2.5-2.6); callgrind, the same feed on pickled
    blocks (two runs' difference, halved): 1171.9 -> 1113.1 M instructions a minute.
    The ninth round (estk9: the compiled whitening in eight lanes, complex-by-real products
    part by part; the same bits), side by side with 4adcb8f: this function, best of 5, load
    3.5-3.7, in blocks compiled 54 -> 50 us (row assembly and RLS sums 24 -> 19), one frame
    at a time 137 -> 134; as a quiet replay runs it (/tmp/prof/stage_prof.py est, best of 7,
    three rounds, load 2.7-2.9) 0.0674-0.0689 -> 0.0597-0.0601 s of CPU a minute."""
    from acquisition.stream import SourceEvent
    from estimator import row_kernels
    from ptinertia.runner import processing_chain
    from ptinertia.stage_threads import as_recorded
    from replay.source import McapSource

    bench, source, _ = _bench(25600.0, 60.0)
    tracker, _ = processing_chain(bench, source.layout)
    blocks = []
    for item in McapSource(log):
        if not isinstance(item := as_recorded(item), SourceEvent):
            blocks.append(tracker.feed(item)[0])
    blocks.append(tracker.finish()[0])

    def once(single: bool, compiled: bool) -> tuple[float, float, int]:
        # every estimator kernel (PTINERTIA_NUMBA=1's switch: the rows, the fitted runs'
        # fit, gates and channel noise), the estimator built and fed with it
        saved, row_kernels.USE = row_kernels.USE, compiled
        try:
            return _once(single, compiled)
        finally:
            row_kernels.USE = saved

    def _once(single: bool, compiled: bool) -> tuple[float, float, int]:
        estimator = processing_chain(bench, source.layout)[1]
        estimator.rows.compiled = compiled  # the row assembly's kernels (estimator.row_kernels)
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
    for compiled in (False, True) if row_kernels.AVAILABLE else (False,):
        if compiled:
            once(False, True)  # numba's import and its cached machine code, once per process
        for single in (False, True):
            best = min((once(single, compiled) for _ in range(repeat)), key=lambda r: r[0])
            cpu, rows, used = best
            how = "one frame at a time (live)" if single else "in blocks (replay, studies)"
            rows_how = "compiled" if compiled else "numpy"
            print(
                f"estimator alone, {how}, {rows_how}: {1e6 * cpu / used:.0f} us per used frame "
                f"(CPU, best of {repeat}, {used} frames), of which row assembly and RLS sums "
                f"{1e6 * rows / used:.0f} us"
            )
            if not single:
                FIGURES[f"estimator alone, blocks, {rows_how}"] = (
                    f"{1e6 * cpu / used:.0f} us per used frame (CPU)"
                )


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
