"""``ptinertia orders``: order amplitude and phase vs rpm of a recording (paper Fig. 11).

``FILE`` is opened with ``open_source("file:" + FILE, bench)`` (CSV, MF4, CAN
log, MCAP replay), or ``sim`` for the simulated bench of the bench file. The
recording runs through the streaming order tracker (``dsp``, configured from
the bench's ``[tacho]`` and ``[dsp]``); every frame becomes a CSV row, and the
PNG shows, per order, the amplitude in dB re 1 m/s^2 and the phase (deg)
against rpm, one line per channel (frames a flag marks as unusable are left
out of the plot, kept in the CSV with their flags).

CSV columns: ``time_s, rpm, crank_angle_deg, rpm_change, flags``, then per
channel and order ``<channel>_H<order>_amp_mps2`` (peak amplitude, m/s^2) and
``<channel>_H<order>_phase_deg`` (of ``x = Re{X exp(i h phi)}``, phi the crank
angle of cylinder 1 from its firing TDC), then ``<channel>_ok``.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from dsp.orders import OrderTracker
from ptinertia.config import load_bench
from ptinertia.errors import UsageError
from ptinertia.outputs import WARN, atomic_output, check_output, input_files
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.sources import open_source
from ptinertia.to_dsp import tracker_config

# Flags that leave a frame's amplitudes trustworthy for the plot: the cycle may be off by
# 360 deg (half-order signs) and the angle rebased, but the magnitudes are right.
PLOTTABLE = frozenset({"cycle_ambiguous", "angle_ambiguous", "angle_rebased"})


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument(
        "file", metavar="FILE", help="recording to analyse, or 'sim' for the simulated bench"
    )
    p.add_argument(
        "--bench",
        default=None,
        help=f"bench file the data was measured on (required for a recording; 'sim' defaults "
        f"to {DEFAULT_BENCH.name})",
    )
    p.add_argument(
        "--orders", help="comma-separated engine orders, multiples of 0.5 (default: [dsp] orders)"
    )
    p.add_argument("--out", help="CSV of every frame (default: none)")
    p.add_argument("--png", help="plot of amplitude and phase vs rpm (default: none)")
    return p


def parse_orders(text: str | None) -> tuple[float, ...] | None:
    """``"1,1.5,2"`` -> (1.0, 1.5, 2.0); None stays None."""
    if text is None:
        return None
    try:
        orders = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise UsageError(
            f"--orders {text!r}: expected comma-separated numbers like 1,1.5,2"
        ) from None
    if not orders or any(not math.isfinite(h) for h in orders):
        raise UsageError(f"--orders {text!r}: expected comma-separated numbers like 1,1.5,2")
    return orders


def run(args: argparse.Namespace) -> int:
    orders = parse_orders(args.orders)
    if args.bench is None and args.file != "sim":
        # a recording tracked with the example bench's tacho and channels would give
        # confident, wrong orders: as ``run``, the bench must be named
        raise UsageError(f"{args.file}: needs --bench B.toml, the bench the data was measured on")
    args.bench = str(DEFAULT_BENCH) if args.bench is None else args.bench
    bench = load_bench(args.bench)
    if args.file != "sim" and not Path(args.file).exists():
        raise UsageError(f"{args.file}: no such file")
    spec = "sim" if args.file == "sim" else "file:" + args.file
    inputs = input_files(args.bench, None if args.file == "sim" else args.file)
    for option in ("out", "png"):
        if getattr(args, option) is not None:
            check_output(getattr(args, option), f"--{option}", inputs, False, WARN)
    config = tracker_config(bench, orders)
    frames = []
    events: Counter[str] = Counter()
    with open_source(spec, bench) as source:
        tracker = OrderTracker.from_layout(source.layout, config)
        for item in source:
            new, evs = tracker.process(item)
            frames += new
            for e in evs:
                events[e.kind] += 1
                if e.kind not in ("tacho_sync",):
                    print(f"ptinertia orders: {e.kind}: {e.message}", file=sys.stderr)
    if not frames:
        raise UsageError(
            f"{args.file}: no order frame (is the tacho channel {config.tacho.channel!r} "
            "carrying edges, and the recording longer than four revolutions?)"
        )
    if args.out is not None:
        with atomic_output(args.out) as tmp:
            write_csv(tmp, frames)
    if args.png is not None:
        with atomic_output(args.png) as tmp:
            plot(tmp, frames, title=f"{Path(args.file).name} - {bench.meta.name}")
    flags = Counter(flag for f in frames for flag in f.flags)
    rpm = [f.rpm for f in frames]
    print(
        f"{len(frames)} frames, {min(rpm):.0f}..{max(rpm):.0f} rpm, orders "
        f"{', '.join(f'{h:g}' for h in frames[0].orders)}, {len(frames[0].channels)} channels"
        + (f"; flags: {', '.join(f'{k} {v}' for k, v in sorted(flags.items()))}" if flags else "")
        + (
            f"; events: {', '.join(f'{k} {v}' for k, v in sorted(events.items()))}"
            if events
            else ""
        )
    )
    for path in (args.out, args.png):
        if path:
            print(f"wrote {path}")
    return 0


def _columns(frames: list[Any]) -> list[str]:
    f0 = frames[0]
    cols = ["time_s", "rpm", "crank_angle_deg", "rpm_change", "flags"]
    for ch in f0.channels:
        for h in f0.orders:
            cols += [f"{ch}_H{h:g}_amp_mps2", f"{ch}_H{h:g}_phase_deg"]
    cols += [f"{ch}_ok" for ch in f0.channels]
    return cols


def write_csv(path: Path, frames: list[Any]) -> None:
    """One row per frame (see the module docstring for the columns)."""
    try:
        fh = path.open("w", newline="", encoding="utf-8")
    except OSError as err:
        raise UsageError(f"{path}: cannot write ({err.strerror})") from None
    with fh:
        w = csv.writer(fh)
        w.writerow(_columns(frames))
        for f in frames:
            row: list[object] = [
                f"{f.time_s:.6f}",
                f"{f.rpm:.3f}",
                f"{math.degrees(f.crank_angle_rad):.3f}",
                f"{f.rpm_change:.6g}",
                ";".join(sorted(f.flags)),
            ]
            for c in range(len(f.channels)):
                for o in range(len(f.orders)):
                    x = complex(f.amplitudes[o, c])
                    row += [f"{abs(x):.9g}", f"{math.degrees(np.angle(x)):.5f}"]
            row += [int(ok) for ok in f.channel_ok]
            w.writerow(row)


def plot(path: Path, frames: list[Any], title: str = "") -> None:
    """Amplitude (dB re 1 m/s^2) above phase (deg) vs rpm, one column per order."""
    # matplotlib here, not at the top: it takes a second to import and only --plot needs it
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    good = [f for f in frames if f.flags <= PLOTTABLE]
    f0 = frames[0]
    n_o = len(f0.orders)
    fig, axes = plt.subplots(2, n_o, figsize=(4.2 * n_o, 6.5), sharex=True, squeeze=False)
    rpm = np.array([f.rpm for f in good])
    x = np.array([f.amplitudes for f in good]) if good else np.zeros((0, n_o, len(f0.channels)))
    ok = np.array([f.channel_ok for f in good]) if good else np.zeros((0, len(f0.channels)), bool)
    for o, h in enumerate(f0.orders):
        amp_ax, ph_ax = axes[0, o], axes[1, o]
        for c, ch in enumerate(f0.channels):
            xc = np.where(ok[:, c], x[:, o, c], np.nan)
            with np.errstate(divide="ignore", invalid="ignore"):
                amp_ax.plot(rpm, 20 * np.log10(np.abs(xc)), lw=0.9, label=ch)
            ph_ax.plot(rpm, np.degrees(np.angle(xc)), ".", ms=1.5)
        amp_ax.set_title(f"H{h:g}")
        amp_ax.grid(True, alpha=0.3)
        ph_ax.grid(True, alpha=0.3)
        ph_ax.set_ylim(-180, 180)
        ph_ax.set_yticks([-180, -90, 0, 90, 180])
        ph_ax.set_xlabel("rpm")
    axes[0, 0].set_ylabel("amplitude, dB re 1 m/s^2")
    axes[1, 0].set_ylabel("phase, deg")
    axes[0, -1].legend(fontsize=7, ncol=max(1, len(f0.channels) // 9), loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=110, format="png")  # the temporary name has no .png suffix
    except OSError as err:
        raise UsageError(f"{path}: cannot write ({err.strerror})") from None
    finally:
        plt.close(fig)
