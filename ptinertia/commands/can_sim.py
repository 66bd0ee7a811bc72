"""``ptinertia can-sim``: the simulated bench as a CAN DAQ, transmitting on a real or virtual bus.

The simulated source is encoded into the frames of the DBC (accelerometer,
pressure, tacho-edge and ECU frames; ``docs/can.md``) and sent paced to the wall
clock, so that ``ptinertia run --source can:INTERFACE:CHANNEL`` in another
process sees what a real bench would send. ``--drop``, ``--duplicate``,
``--reorder`` and ``--corrupt`` spoil a fraction of the data frames (never the
DAQ status frames) to exercise the receiver; ``--json`` prints what was done.
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from acquisition.can.bus import frame_to_message, open_bus
from acquisition.can.bus_load import bus_load
from acquisition.can.encoder import FrameEncoder, TxFrame
from acquisition.can.faults import FAULT_KINDS, FaultInjector, FaultRateError, FaultRates
from acquisition.can.frames import RawFrame
from acquisition.can.logs import FrameLogWriter
from acquisition.can.plan import CanPlan
from acquisition.sim.sweep import parse_sweep
from acquisition.stream import EdgeBlock, SampleBlock, StreamItem, StreamLayout
from ptinertia.commands.arg_types import finite_float
from ptinertia.commands.arg_types import seed as seed_type
from ptinertia.config import Bench, load_bench
from ptinertia.errors import UsageError
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.progress import work_bar
from ptinertia.sources import open_source
from ptinertia.to_can import can_plan, parse_bus_options


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("--bench", default=str(DEFAULT_BENCH), help="bench file (default: %(default)s)")
    p.add_argument("--dbc", default=None, help="DBC file (default: the bench file's [can] dbc)")
    p.add_argument(
        "--interface",
        default=None,
        help="python-can interface, or 'none' to only write --log (default: [can] interface)",
    )
    p.add_argument("--channel", default=None, help="bus channel (default: [can] channel)")
    p.add_argument(
        "--bus-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="interface-specific can.Bus argument (repeatable; beside [can] bus_options)",
    )
    p.add_argument(
        "--bitrate",
        type=int,
        default=None,
        help="arbitration bit rate, bit/s (default: [can] bitrate)",
    )
    p.add_argument(
        "--data-bitrate",
        type=int,
        default=None,
        help="CAN FD data bit rate, bit/s (default: [can] data_bitrate)",
    )
    p.add_argument(
        "--fd",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="CAN FD (default: [can] fd)",
    )
    p.add_argument(
        "--duration",
        type=finite_float,
        default=None,
        help="sweep duration, s (default: [simulation] duration_s)",
    )
    p.add_argument(
        "--sweep", default=None, metavar="RPM[:RPM]", help="rpm start:end (default: [simulation])"
    )
    p.add_argument(
        "--seed", type=seed_type, default=None, help="simulation seed (default: [simulation] seed)"
    )
    p.add_argument(
        "--noise-snr-db",
        type=finite_float,
        default=None,
        help="sensor noise, dB (default: [simulation])",
    )
    p.add_argument(
        "--pace",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="send in real time (default on a bus; a log alone is written as fast as possible)",
    )
    p.add_argument(
        "--start-delay",
        type=finite_float,
        default=0.0,
        help="wait this long before the first frame, s",
    )
    for fault, what in zip(
        FAULT_KINDS, ("drop", "send twice", "delay by 1-3 frames", "corrupt"), strict=True
    ):
        p.add_argument(
            f"--{fault}",
            type=finite_float,
            default=0.0,
            metavar="FRACTION",
            help=f"{what} this fraction of the data frames",
        )
    p.add_argument("--fault-seed", type=seed_type, default=0, help="seed of the fault draws")
    p.add_argument(
        "--log",
        default=None,
        help="also write the frames to a CAN log (.blf, .asc, .trc, .log, .mf4)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of a text one")
    return p


# -- transmission ----------------------------------------------------------------------------------


class _Sender:
    """Paces frames to the wall clock and hands them to the bus and the log."""

    def __init__(self, bus: Any, logger: Any, pace: bool, t0_wall: float, t0_mono: float) -> None:
        self.bus = bus
        self.logger = logger
        self.pace = pace
        self.t0_wall = t0_wall
        self.t0_mono = t0_mono
        self.sent: Counter[str] = Counter()
        self.max_late_s = 0.0

    def send(self, f: TxFrame) -> None:
        if self.pace:
            wait = self.t0_mono + f.time_s - time.monotonic()
            if wait > 0.001:
                time.sleep(wait)
            else:
                self.max_late_s = max(self.max_late_s, -wait)
        m = f.message
        frame = RawFrame(
            round((self.t0_wall + f.time_s) * 1e9), m.frame_id, m.is_extended_id, f.data, m.is_fd
        )
        if self.bus is not None:
            self.bus.send(frame_to_message(frame))
        if self.logger is not None:
            self.logger(frame)
        self.sent[m.name] += 1


def simulate_to_bus(
    bench: Bench,
    plan: CanPlan,
    *,
    bus: Any,
    log_frame: Callable[[RawFrame], None] | None = None,
    pace: bool = True,
    faults: FaultInjector | None = None,
    start_delay_s: float = 0.0,
    sim_overrides: dict[str, Any] | None = None,
    bitrate: int | None = None,
    data_bitrate: int | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Run the simulated DAQ on ``bus`` (and/or ``log_frame``); return the summary.

    ``progress``: a bar on stderr by seconds of sweep (a log of a long sweep takes a
    while even unpaced; a paced run takes its duration).
    """
    source = open_source("sim", bench, block_s=0.02, **(sim_overrides or {}))
    encoder = FrameEncoder(plan, source.layout)
    profile = getattr(source, "profile", None)
    duration = (
        float(profile.duration_s) if profile is not None else float(bench.simulation.duration_s)
    )
    t_start = time.monotonic() + start_delay_s
    sender = _Sender(bus, log_frame, pace, time.time() + start_delay_s, t_start)
    if start_delay_s > 0:
        time.sleep(start_delay_s)
    heap: list[tuple[float, int, int, TxFrame]] = []
    seq = 0

    def push(frames: list[TxFrame]) -> None:
        nonlocal seq
        for f in frames:
            heapq.heappush(heap, (f.time_s, f.message.frame_id, seq, f))
            seq += 1

    def pop_until(t: float) -> None:
        ready = []
        while heap and heap[0][0] <= t:
            ready.append(heapq.heappop(heap)[3])
        if faults is not None:
            ready = faults.apply(ready)
        for f in ready:
            sender.send(f)

    bar = work_bar(duration, "can-sim") if progress else None
    with source:
        for item in source:
            push(encoder.encode(item))
            t_item = _start_time(item, source.layout)
            if t_item is not None:
                push(encoder.status(t_item))
                pop_until(t_item)
                if bar is not None and t_item > bar.n:
                    bar.update(min(t_item, duration) - bar.n)
    if bar is not None:
        bar.close()
    push(encoder.finish(duration))
    pop_until(float("inf"))
    if faults is not None:
        for f in faults.flush():
            sender.send(f)
    t = bench.tacho
    edges_per_rev = {"wheel": t.teeth - t.missing, "pulses": t.teeth}.get(t.kind, 1)
    rpm_max = profile.rpm_max if profile is not None else bench.simulation.rpm_end
    rates = {
        "bitrate": bitrate or bench.can.bitrate,
        "data_bitrate": data_bitrate or bench.can.data_bitrate,
    }
    load = [
        bus_load(plan, **rates, edge_rate_hz=edges_per_rev * rpm_max / 60, stuffing=stuffing)
        for stuffing in (False, True)
    ]
    return {
        "duration_s": duration,
        "frames_sent": dict(sender.sent),
        "frames_total": int(sum(sender.sent.values())),
        "clipped_samples": encoder.clipped,
        "max_late_s": sender.max_late_s,
        "bus_load_at_rpm_max": {"unstuffed": load[0], "worst_case_stuffing": load[1], **rates},
        "faults": faults.log.as_dict() if faults is not None else {},
    }


def _start_time(item: StreamItem, layout: StreamLayout) -> float | None:
    if isinstance(item, SampleBlock):
        return item.first_index / layout.group(item.group).rate_hz
    if isinstance(item, EdgeBlock) and item.times_s.size:
        return float(item.times_s[0])
    return None


def run(args: argparse.Namespace) -> int:
    bench = load_bench(args.bench)
    cfg = bench.can
    plan = can_plan(bench, args.dbc)
    interface = args.interface or cfg.interface
    channel = args.channel or cfg.channel
    fd = cfg.fd if args.fd is None else args.fd
    if not fd:
        fd_msgs = [m.name for m in plan.messages if m.is_fd]
        if fd_msgs:
            raise UsageError(
                f"the DBC's {fd_msgs[0]} is a CAN FD frame: it cannot go on a classic CAN bus (--no-fd)"
            )
    if interface == "none" and not args.log:
        raise UsageError("--interface none sends nothing: give --log PATH")
    if args.duration is not None and not args.duration > 0:
        raise UsageError(f"--duration: expected a positive time in s, got {args.duration:g}")
    try:
        rates = FaultRates(args.drop, args.duplicate, args.reorder, args.corrupt)
    except FaultRateError as err:  # a fraction is named by its option here
        raise UsageError(f"--{err.kind}: {err.reason}" if err.kind else err.reason) from None
    faults = FaultInjector(rates, plan, args.fault_seed) if rates.any else None
    overrides: dict[str, Any] = {}
    if args.duration is not None:
        overrides["duration_s"] = args.duration
    if args.sweep is not None:
        overrides["rpm_start"], overrides["rpm_end"] = parse_sweep(args.sweep)
    if args.seed is not None:
        overrides["seed"] = args.seed
    if args.noise_snr_db is not None:
        overrides["noise_snr_db"] = args.noise_snr_db
    bus = None
    if interface != "none":
        kwargs: dict[str, Any] = {"fd": fd, "bitrate": args.bitrate or cfg.bitrate}
        if fd:
            kwargs["data_bitrate"] = args.data_bitrate or cfg.data_bitrate
        kwargs.update(cfg.bus_options)
        kwargs.update(parse_bus_options(args.bus_option))
        bus = open_bus(interface, channel, **kwargs)
    writer = FrameLogWriter(args.log) if args.log else None
    try:
        summary = simulate_to_bus(
            bench,
            plan,
            bus=bus,
            log_frame=writer.write if writer is not None else None,
            pace=args.pace if args.pace is not None else bus is not None,
            faults=faults,
            start_delay_s=args.start_delay,
            sim_overrides=overrides,
            bitrate=args.bitrate,
            data_bitrate=args.data_bitrate,
            progress=True,
        )
    finally:
        if writer is not None:
            writer.close()
        if bus is not None:
            bus.shutdown()
    summary.update(
        {"interface": interface, "channel": channel, "dbc": plan.dbc_path, "log": args.log}
    )
    if args.json:
        json.dump(summary, sys.stdout, indent=2)
        print()
    else:
        where = f"{interface}:{channel}" if interface != "none" else args.log
        load = summary["bus_load_at_rpm_max"]
        print(
            f"can-sim: {summary['frames_total']} frames in {summary['duration_s']:g} s of sweep to {where}; "
            f"bus load at the top speed {100 * load['unstuffed']:.0f}-{100 * load['worst_case_stuffing']:.0f} % "
            f"({load['bitrate'] / 1e3:g} k / {load['data_bitrate'] / 1e6:g} M; unstuffed - worst-case stuffing)"
        )
        for line in plan.describe():
            print(f"  {line}")
        if summary["clipped_samples"]:
            print(
                f"  warning: {summary['clipped_samples']} samples beyond the DBC's range were clipped"
            )
        if summary["max_late_s"] > 0.05:
            print(f"  warning: fell up to {summary['max_late_s']:.3f} s behind the wall clock")
        if faults is not None:
            print(f"  faults: {json.dumps(summary['faults'])}")
    return 0
