"""Order tracking: throughput, memory over an hour, latency, and rota-order side by side.

Run: ``/work/venv/bin/python benchmarks/bench_order_tracking.py [--quick]``

Prints figures; asserts nothing. Times are CPU seconds of this process with
BLAS pinned to one thread, so a busy machine does not flatter or penalise
the figures much (wall-clock is printed beside them).

1. Throughput (numpy path, and the compiled segment sums of dsp.kernels beside it when
   numba is installed): 10 channels at 25.6 kHz, orders 1, 1.5, 2 (plus the internal
   orders of the leakage correction), a 1500 -> 4500 rpm sweep, 60-2 wheel
   as edge timestamps and as a 200 kHz square wave, blocks of 0.1 s, 0.5 s
   and 1 s (best of five runs: on a shared machine other work only ever adds
   time); and the live pipeline's load: 9 accelerometers and a cylinder
   pressure that gives the 720 deg cycle, edges, 0.5 s blocks, without and with
   the pressure's half-order spectrum (orders 0 .. 6) in every frame.
2. Memory: one hour of the same 10 channels at 3000 rpm, RSS after the first
   minute and at the end (a block generator repeats one exact second: the
   signal is periodic, so the tracker sees an ordinary hour of data).
3. Latency: worst time from a sample to the first frame that holds it, and to
   the frame whose window starts with it.
4. rota-order (PyPI) on the same signals, the simulated i3 bench sweep at
   50 rpm/s (9 channels, 5120 Hz): angle-domain resampling + one-cycle DFT,
   phase-locked tracked harmonics, Vold-Kalman; accuracy against the exact
   amplitudes at each frame's rpm, and time.
5. Side by side: issue 24's load (10 channels at 25.6 kHz, orders 1, 1.5, 2, edges, 0.5 s
   blocks; :func:`issue_load`, which bench_pipeline.py also prints) with the numpy and the
   compiled sums, and rota-order's best figure from 4., with the load average.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from acquisition.stream import EdgeBlock, SampleBlock
from dsp import kernels
from dsp.config import OrderTrackerConfig
from dsp.orders import OrderTracker
from dsp.synthetic import OrderContent, Ramp, SyntheticBench
from dsp.tacho import TachoConfig

ROOT = Path(__file__).resolve().parents[1]
ORDERS = (1.0, 1.5, 2.0)
TDC = 84.0


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return math.nan


def _contents(n_ch: int) -> list[OrderContent]:
    rng = np.random.default_rng(0)
    orders = (0.5, 1.0, 1.5, 2.0, 3.0, 4.5, 6.0)
    return [
        OrderContent(
            orders,
            tuple((1 + rng.random(len(orders))) * np.exp(2j * np.pi * rng.random(len(orders)))),
            tuple(rng.uniform(0, 2, len(orders))),
        )
        for _ in range(n_ch)
    ]


def _config(delivery: str = "edges", **kw) -> OrderTrackerConfig:
    return OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=TDC, delivery=delivery),
        orders=ORDERS,
        rpm_max=6000.0,
        **kw,
    )


def _timed(
    layout, config, items, repeat: int = 1, compiled: bool = False
) -> tuple[float, float, list]:
    """Best CPU and wall time over ``repeat`` fresh trackers (a shared machine only adds time).

    ``compiled``: the segment sums by the numba kernel (dsp.kernels), warmed up first so
    that its one-off compile or cache load is not counted; else the numpy path.
    """
    kernels.USE = compiled and kernels.AVAILABLE
    if kernels.USE:
        tracker = OrderTracker.from_layout(layout, config)
        for item in items[:20]:
            tracker.process(item)
    best_cpu, best_wall, frames = math.inf, math.inf, []
    for _ in range(repeat):
        tracker = OrderTracker.from_layout(layout, config)
        frames = []
        cpu0, wall0 = time.process_time(), time.perf_counter()
        for item in items:
            frames += tracker.process(item)[0]
        best_cpu = min(best_cpu, time.process_time() - cpu0)
        best_wall = min(best_wall, time.perf_counter() - wall0)
    return best_cpu, best_wall, frames


def throughput(duration: float) -> None:
    print(
        f"\n1. Throughput: 10 channels at 25.6 kHz, orders {ORDERS}, 1500 -> 4500 rpm in {duration:g} s"
    )
    bench = SyntheticBench(
        Ramp(1500.0, 4500.0, duration), _contents(10), rate_hz=25_600.0, tdc_after_gap_deg=TDC
    )
    for delivery in ("edges", "sampled"):
        bench.tacho = delivery
        for block in (0.1, 0.5, 1.0):
            items = list(bench.items(duration, block_s=block))  # generated before the clock starts
            cpu, wall, frames = _timed(bench.layout, _config(delivery), items, repeat=5)
            cpu_c, _, _ = _timed(bench.layout, _config(delivery), items, repeat=5, compiled=True)
            print(
                f"   tacho {delivery:7s} block {block:3.1f} s: {duration / cpu:6.0f}x real time "
                f"(CPU {cpu:5.3f} s, wall {wall:5.3f} s, best of 5), {len(frames)} frames; "
                f"compiled sums {_factor(duration, cpu_c)}"
            )
            del items
    # the live pipeline: 9 accelerometers + the cylinder pressure as the cycle reference
    bench = SyntheticBench(
        Ramp(1500.0, 4500.0, duration), _contents(9), rate_hz=25_600.0, tdc_after_gap_deg=TDC,
        pressure=True,
    )  # fmt: skip
    items = list(bench.items(duration, block_s=0.5))
    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=TDC, phase_reference="pressure"),
        orders=ORDERS,
        channels=tuple(bench.channel_names),
        rpm_max=6000.0,
    )
    cpu, wall, frames = _timed(bench.layout, config, items, repeat=5)
    cpu_c, _, _ = _timed(bench.layout, config, items, repeat=5, compiled=True)
    print(
        f"   9 accel + pressure reference, edges, block 0.5 s: {duration / cpu:6.0f}x real time "
        f"(CPU {cpu:5.3f} s, wall {wall:5.3f} s, best of 5), {len(frames)} frames; "
        f"compiled sums {_factor(duration, cpu_c)}"
    )
    # the same, with the pressure's full half-order spectrum (orders 0 .. 6) in every frame
    spectrum = replace(config, spectrum_channel="p_cyl1", spectrum_max_order=6.0)
    cpu_s, wall_s, frames = _timed(bench.layout, spectrum, items, repeat=5)
    cpu_sc, _, _ = _timed(bench.layout, spectrum, items, repeat=5, compiled=True)
    print(
        f"   ... + pressure spectrum 0 .. 6 (+2 internal): {duration / cpu_s:6.0f}x real time "
        f"(CPU {cpu_s:5.3f} s, wall {wall_s:5.3f} s, best of 5; {100 * (cpu_s / cpu - 1):+.0f} % "
        f"CPU), {len(frames)} frames; compiled sums {_factor(duration, cpu_sc)}"
    )


def issue_load(duration: float = 30.0, repeat: int = 5) -> tuple[float, float | None]:
    """CPU seconds (best of ``repeat``) of issue 24's load: 10 channels at 25.6 kHz, orders 1,
    1.5, 2, tacho edges, a 1500 -> 4500 rpm sweep in ``duration`` s, 0.5 s blocks; with the
    numpy sums and with the compiled ones (None without numba)."""
    bench = SyntheticBench(
        Ramp(1500.0, 4500.0, duration), _contents(10), rate_hz=25_600.0, tdc_after_gap_deg=TDC
    )
    items = list(bench.items(duration, block_s=0.5))
    cpu, _, _ = _timed(bench.layout, _config(), items, repeat=repeat)
    if not kernels.AVAILABLE:
        return cpu, None
    cpu_c, _, _ = _timed(bench.layout, _config(), items, repeat=repeat, compiled=True)
    kernels.USE = False
    return cpu, cpu_c


def _factor(duration: float, cpu: float) -> str:
    return f"{duration / cpu:.0f}x" if kernels.AVAILABLE else "n/a (numba not installed)"


def memory(minutes: float) -> None:
    print(f"\n2. Memory: {minutes:g} min of 10 channels at 25.6 kHz, 3000 rpm, 1 s blocks")
    bench = SyntheticBench(
        Ramp(3000.0, 3000.0, 1.0), _contents(10), rate_hz=25_600.0, tdc_after_gap_deg=TDC
    )
    one = list(bench.items(1.0, block_s=1.0))
    edges = np.concatenate([i.times_s for i in one if isinstance(i, EdgeBlock)])
    data = np.concatenate([i.data for i in one if isinstance(i, SampleBlock)], axis=1)
    # edges within [0, 1) repeat every second exactly (50 revolutions per second)
    edges = edges[edges < 1.0]
    tracker = OrderTracker.from_layout(bench.layout, _config())
    n_blocks = int(minutes * 60)
    rss = {}
    cpu0 = time.process_time()
    frames = 0
    for k in range(n_blocks):
        frames += len(tracker.process(SampleBlock("accel", k * 25_600, data))[0])
        frames += len(tracker.process(EdgeBlock("tacho", edges + k))[0])
        if k + 1 in (60, n_blocks):
            rss[k + 1] = _rss_mb()
    cpu = time.process_time() - cpu0
    growth = rss[n_blocks] - rss[60]
    print(
        f"   RSS after 1 min {rss[60]:.1f} MB, after {minutes:g} min {rss[n_blocks]:.1f} MB "
        f"(growth {growth:+.1f} MB); {frames} frames, {n_blocks / cpu:.0f}x real time"
    )


def latency() -> None:
    print(
        "\n3. Latency at 3000 rpm, one-sample blocks (stream time between a sample and its frame)"
    )
    bench = SyntheticBench(Ramp(3000.0, 3000.0, 1.0), _contents(2), tdc_after_gap_deg=TDC)
    config = _config()
    tracker = OrderTracker.from_layout(bench.layout, config)
    first_hold, window_start = [], []
    rev = 60.0 / 3000.0
    half = math.radians(360 + config.taper_deg / 2)
    for item in bench.items(1.0, block_s=1 / 5120):
        now = (
            (item.first_index + item.n_samples) / 5120
            if isinstance(item, SampleBlock)
            else item.times_s[-1]
        )
        for f in tracker.process(item)[0]:
            window_start.append(now - bench.ramp.t_of_phi(f.crank_angle_rad - half))
            # the newest sample that no earlier frame held: the window's last revolution
            first_hold.append(now - bench.ramp.t_of_phi(f.crank_angle_rad + 2 * math.pi - half))
    print(
        f"   oldest sample of a frame: {max(window_start) / rev:.3f} rev; every sample is first "
        f"held by a frame {max(first_hold) / rev:.3f} rev after it (+ the block that carries it)"
    )


def _sim_sweep():
    from acquisition.sim.sweep import RpmProfile, ramp
    from ptinertia.config import load_bench
    from ptinertia.sources import open_source

    bench = load_bench(ROOT / "examples" / "i3-bench.toml")
    src = open_source("sim", bench, profile=RpmProfile([ramp(1500.0, 4500.0, 60.0)]), block_s=0.1)
    return bench, src, list(src)


def _errors(x: np.ndarray, exact: np.ndarray) -> tuple[float, float, float]:
    """Worst amplitude (relative, floored at -60 dB of the channel) and phase (deg) errors, and
    the median amplitude error."""
    floor = 1e-3 * np.abs(exact).max(axis=1, keepdims=True)
    amp = np.abs(np.abs(x) - np.abs(exact)) / np.maximum(np.abs(exact), floor)
    phase = np.where(np.abs(exact) >= floor, np.degrees(np.abs(np.angle(x / exact))), 0.0)
    return float(np.nanmax(amp)), float(np.nanmax(phase)), float(np.nanmedian(amp))


def _regroup(items, block_s: float):
    """The simulated stream's accel blocks and edges merged into ``block_s`` blocks."""
    fs = 5120.0
    data = np.concatenate(
        [i.data for i in items if isinstance(i, SampleBlock) and i.group == "accel"], 1
    )
    edges = np.concatenate([i.times_s for i in items if isinstance(i, EdgeBlock)])
    out = []
    step = int(block_s * fs)
    for k in range(0, data.shape[1], step):
        t_end = (k + step) / fs
        out.append(EdgeBlock("tacho", edges[(edges >= k / fs) & (edges < t_end)]))
        out.append(SampleBlock("accel", k, data[:, k : k + step]))
    return out


def _envelope_at(env: np.ndarray, t: np.ndarray, t_frames: np.ndarray) -> np.ndarray:
    """rota envelopes (n, K, ch) at the frame times: (n_frames, K, ch)."""
    re = np.stack(
        [
            [np.interp(t_frames, t, env[:, k, c].real) for c in range(env.shape[2])]
            for k in range(env.shape[1])
        ]
    )
    im = np.stack(
        [
            [np.interp(t_frames, t, env[:, k, c].imag) for c in range(env.shape[2])]
            for k in range(env.shape[1])
        ]
    )
    return (re + 1j * im).transpose(2, 0, 1)


def comparison() -> str:
    """Section 4; returns rota-order's best real-time factor (or why there is none)."""
    print(
        "\n4. Accuracy and time on the simulated i3 sweep, 1500 -> 4500 rpm at 50 rpm/s, 9 ch, 5120 Hz"
    )
    bench, src, items = _sim_sweep()
    from ptinertia.to_dsp import tracker_config

    config = tracker_config(bench, ORDERS)
    cpu_live, _, frames = _timed(src.layout, config, items, repeat=3)
    cpu_1s, _, _ = _timed(src.layout, config, _regroup(items, 1.0), repeat=3)
    cpu_c, _, frames_c = _timed(src.layout, config, items, repeat=3, compiled=kernels.AVAILABLE)
    frames = [f for f in frames if not f.flags - {"cycle_ambiguous"}]
    t_frames = np.array([f.time_s for f in frames])
    # offline methods have edge effects: every method is judged 1 s away from both ends
    keep = (t_frames > 1.0) & (t_frames < 59.0)
    frames = [f for f, k in zip(frames, keep, strict=True) if k]
    t_frames = t_frames[keep]
    exact = src.exact_amplitudes([f.rpm for f in frames], ORDERS)
    ours = np.array([f.amplitudes for f in frames])
    rows = [
        ("ptinertia dsp, 0.1 s blocks as streamed", *_errors(ours, exact), cpu_live),
        ("ptinertia dsp, 1 s blocks", *_errors(ours, exact), cpu_1s),
    ]
    if kernels.AVAILABLE:
        kept = [f for f in frames_c if not f.flags - {"cycle_ambiguous"}]
        ours_c = np.array([f.amplitudes for f in kept])[keep]
        rows.append(("ptinertia dsp, 0.1 s blocks, compiled sums", *_errors(ours_c, exact), cpu_c))
    try:
        from rota import angle as rangle
        from rota import extract as rextract
    except ImportError:
        print("   rota-order is not installed (pip install rota-order): comparison skipped")
        _table(rows)
        return "not installed (pip install rota-order)"
    fs = 5120.0
    x = np.concatenate(
        [i.data for i in items if isinstance(i, SampleBlock) and i.group == "accel"], axis=1
    ).T
    t = np.arange(x.shape[0]) / fs
    rpm_t = src.profile.rpm(t)  # rota gets the exact speed: its best case
    # (a) computed order tracking: resample to 64 samples/rev, DFT over each 2-revolution cycle
    cpu0 = time.process_time()
    ang = rangle.angular_resample(x, fs, rpm_t, samples_per_rev=64, max_order=12.0)
    spr = ang.samples_per_rev
    js = np.round(np.array([f.crank_angle_rad for f in frames]) / (2 * math.pi)).astype(int)
    k2 = np.array([round(2 * h) for h in ORDERS])
    res = np.full(ours.shape, np.nan + 0j)
    basis = np.exp(-1j * np.pi * np.outer(np.arange(2 * spr) / spr, k2))  # exp(-i h 2 pi rev)
    for i, j in enumerate(js):
        a0 = (j - 1) * spr
        if a0 < 0 or a0 + 2 * spr > ang.x.shape[0]:
            continue
        seg = ang.x[a0 : a0 + 2 * spr]  # rev j-1 .. j+1; its phase origin rev j-1
        res[i] = 2.0 / (2 * spr) * (basis.T @ seg) * np.exp(-1j * np.pi * k2 * (j - 1))[:, None]
    cpu_a = time.process_time() - cpu0
    rows.append(("rota angular_resample + 720 deg DFT", *_errors(res, exact), cpu_a))
    # (b) phase-locked tracked harmonics, Hann over 4 revolutions (nulls 0.5 order away)
    cpu0 = time.process_time()
    th = rextract.tracked_harmonics(x, fs, rpm_t, list(ORDERS), window_revs=4.0, overlap=0.75)
    cpu_b = time.process_time() - cpu0
    rows.append(
        (
            "rota tracked_harmonics (Hann, 4 rev)",
            *_errors(_envelope_at(th.envelopes, t, t_frames), exact),
            cpu_b,
        )
    )
    # (c) Vold-Kalman, 2 Hz envelope bandwidth, the three orders jointly
    cpu0 = time.process_time()
    vk = rextract.order_waveform(x, fs, rpm_t, list(ORDERS), bandwidth=2.0)
    cpu_vk = time.process_time() - cpu0
    rows.append(
        (
            "rota order_waveform (Vold-Kalman, 2 Hz)",
            *_errors(_envelope_at(vk.envelopes, t, t_frames), exact),
            cpu_vk,
        )
    )
    _table(rows)
    ours_x = 60.0 / min(cpu_live, cpu_1s)
    rota_x = 60.0 / min(cpu_a, cpu_b, cpu_vk)
    return f"{rota_x:.0f}x at best, ptinertia {ours_x:.0f}x on the same 9 ch x 5120 Hz sweep (CPU)"


def _table(rows) -> None:
    print(
        f"   {'method':42s} {'amp max':>9s} {'amp median':>10s} {'phase max':>10s} {'CPU':>7s} {'x real time':>11s}"
    )
    for name, a, p, med, cpu in rows:
        print(f"   {name:42s} {a:9.2e} {med:10.2e} {p:6.3f} deg {cpu:6.2f}s {60.0 / cpu:9.0f}x")
    print("   (errors over frames 1 s to 59 s, 9 channels, H1/H1.5/H2; amplitude relative to")
    print(
        "    max(|X|, 1e-3 of the channel's strongest order), exact amplitude at the frame's rpm)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s sweep, 6 min of memory test")
    args = parser.parse_args(argv)
    print(
        f"python {sys.version.split()[0]}, numpy {np.__version__}, BLAS threads {os.environ['OPENBLAS_NUM_THREADS']}"
    )
    throughput(10.0 if args.quick else 30.0)
    memory(6.0 if args.quick else 60.0)
    latency()
    rota = comparison()
    load = os.getloadavg()[0]
    duration = 10.0 if args.quick else 30.0
    cpu, cpu_c = issue_load(duration)
    print(
        f"\nSide by side (issue 24; load average {load:.1f} -> {os.getloadavg()[0]:.1f} on 2 cores):"
    )
    print(
        f"   order tracking, 10 ch x 25.6 kHz, orders 1, 1.5, 2, 0.5 s blocks: {duration / cpu:.0f}x "
        f"numpy sums, {_factor(duration, cpu_c) if cpu_c else 'n/a'} compiled sums "
        "(CPU, one core; target >= 500x)"
    )
    print(f"   rota-order on the simulated i3 (section 4): {rota}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
