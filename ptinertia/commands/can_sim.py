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
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from acquisition.can.codec import CanPlan, RawFrame, TxFrame, frame_crc
from ptinertia.errors import UsageError
from ptinertia.paths import DEFAULT_BENCH

CORRUPTIONS = ("length", "crc", "id", "counter")
_FRAME_SIZES = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


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
        type=float,
        default=None,
        help="sweep duration, s (default: [simulation] duration_s)",
    )
    p.add_argument(
        "--sweep", default=None, metavar="RPM[:RPM]", help="rpm start:end (default: [simulation])"
    )
    p.add_argument(
        "--seed", type=int, default=None, help="simulation seed (default: [simulation] seed)"
    )
    p.add_argument(
        "--noise-snr-db", type=float, default=None, help="sensor noise, dB (default: [simulation])"
    )
    p.add_argument(
        "--pace",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="send in real time (default on a bus; a log alone is written as fast as possible)",
    )
    p.add_argument(
        "--start-delay", type=float, default=0.0, help="wait this long before the first frame, s"
    )
    for fault, what in (
        ("drop", "drop"),
        ("duplicate", "send twice"),
        ("reorder", "delay by 1-3 frames"),
        ("corrupt", "corrupt"),
    ):
        p.add_argument(
            f"--{fault}",
            type=float,
            default=0.0,
            metavar="FRACTION",
            help=f"{what} this fraction of the data frames",
        )
    p.add_argument("--fault-seed", type=int, default=0, help="seed of the fault draws")
    p.add_argument(
        "--log",
        default=None,
        help="also write the frames to a CAN log (.blf, .asc, .trc, .log, .mf4)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of a text one")
    return p


# -- fault injection -------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultRates:
    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "reorder", "corrupt"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise UsageError(f"--{name}: expected a fraction in [0, 1], got {v:g}")
        total = self.drop + self.duplicate + self.reorder + self.corrupt
        if total > 1.0:
            raise UsageError(f"the fault fractions add up to {total:g} > 1")


@dataclass
class FaultLog:
    """What the injector did, per DBC message (``corrupted`` by kind)."""

    dropped: Counter[str] = field(default_factory=Counter)
    duplicated: Counter[str] = field(default_factory=Counter)
    reordered: Counter[str] = field(default_factory=Counter)
    corrupted: dict[str, Counter[str]] = field(default_factory=dict)
    spoiled: dict[str, set[int]] = field(default_factory=dict)  # frame numbers dropped or corrupted

    def as_dict(self) -> dict[str, Any]:
        return {
            "dropped": dict(self.dropped),
            "duplicated": dict(self.duplicated),
            "reordered": dict(self.reordered),
            "corrupted": {k: dict(v) for k, v in self.corrupted.items()},
        }


class FaultInjector:
    """Drops, duplicates, delays and corrupts data frames; status frames pass untouched.

    Each frame draws one fate: dropped, duplicated (the copy follows 0-2 frames
    later), reordered (sent 1-3 frames later) or corrupted (wrong length, a bit
    flipped under the CRC, an id the DBC does not know, or a counter moved far
    off with a valid CRC), with the given probabilities.
    """

    def __init__(self, rates: FaultRates, plan: CanPlan, seed: int = 0) -> None:
        self.rates = rates
        self.rng = np.random.default_rng(seed)
        self.log = FaultLog()
        self._known = set(plan.dbc_ids) | {m.key for m in plan.messages}
        self._delayed: list[list[Any]] = []  # [frames still to pass, TxFrame]

    def apply(self, frames: list[TxFrame]) -> list[TxFrame]:
        out: list[TxFrame] = []
        r = self.rates
        cuts = np.cumsum([r.drop, r.duplicate, r.reorder, r.corrupt])
        for f in frames:
            self._release(out)
            if f.message.kind == "status":
                out.append(f)
                continue
            u = self.rng.random()
            name = f.message.name
            if u < cuts[0]:
                self.log.dropped[name] += 1
                self.log.spoiled.setdefault(name, set()).add(f.frame_no)
            elif u < cuts[1]:
                self.log.duplicated[name] += 1
                out.append(f)
                self._delayed.append([int(self.rng.integers(0, 3)), f])
            elif u < cuts[2]:
                self.log.reordered[name] += 1
                self._delayed.append([int(self.rng.integers(1, 4)), f])
            elif u < cuts[3]:
                kind = CORRUPTIONS[int(self.rng.integers(len(CORRUPTIONS)))]
                if kind == "crc" and f.message.crc is None:
                    kind = "length"
                self.log.corrupted.setdefault(name, Counter())[kind] += 1
                self.log.spoiled.setdefault(name, set()).add(f.frame_no)
                out.append(self._corrupt(f, kind))
            else:
                out.append(f)
        return out

    def flush(self) -> list[TxFrame]:
        out = [d[1] for d in self._delayed]
        self._delayed.clear()
        return out

    def _release(self, out: list[TxFrame]) -> None:
        keep = []
        for d in self._delayed:
            if d[0] <= 0:
                out.append(d[1])
            else:
                d[0] -= 1
                keep.append(d)
        self._delayed = keep

    def _corrupt(self, f: TxFrame, kind: str) -> TxFrame:
        m = f.message
        data = bytearray(f.data)
        if kind == "length":
            # the next shorter length a CAN (FD) frame can have
            shorter = max(n for n in _FRAME_SIZES if n < len(data))
            return f._replace(data=bytes(data[:shorter]))
        if kind == "crc":
            assert m.crc is not None
            skip = set(range(m.crc.byte, m.crc.byte + m.crc.n_bytes))
            byte = int(self.rng.choice([i for i in range(len(data)) if i not in skip]))
            data[byte] ^= 1 << int(self.rng.integers(8))
            return f._replace(data=bytes(data))
        if kind == "id":
            unknown = next(
                i for i in range(0x7FF, 0, -1) if (i, m.is_extended_id) not in self._known
            )
            return f._replace(message=_with_id(m, unknown))
        # a counter far off (a random quarter to half of its range), CRC made valid again
        c = m.counter
        assert c is not None
        raw = int(np.frombuffer(bytes(data[c.byte : c.byte + c.n_bytes]), c.dtype)[0])
        shift = int(self.rng.integers(1 << (c.bits - 2), 1 << (c.bits - 1)))
        data[c.byte : c.byte + c.n_bytes] = np.array(
            [(raw + shift) % (1 << c.bits)], c.dtype
        ).tobytes()
        if m.crc is not None:
            data[m.crc.byte : m.crc.byte + 2] = np.array(
                [frame_crc(bytes(data), m.crc)], m.crc.dtype
            ).tobytes()
        return f._replace(data=bytes(data))


def _with_id(m: Any, frame_id: int) -> Any:
    from dataclasses import replace

    return replace(m, frame_id=frame_id)


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
        import can

        if self.pace:
            wait = self.t0_mono + f.time_s - time.monotonic()
            if wait > 0.001:
                time.sleep(wait)
            else:
                self.max_late_s = max(self.max_late_s, -wait)
        m = f.message
        msg = can.Message(
            timestamp=self.t0_wall + f.time_s,
            arbitration_id=m.frame_id,
            is_extended_id=m.is_extended_id,
            is_fd=m.is_fd,
            bitrate_switch=m.is_fd,
            data=f.data,
        )
        if self.bus is not None:
            self.bus.send(msg)
        if self.logger is not None:
            self.logger(
                RawFrame(round(msg.timestamp * 1e9), m.frame_id, m.is_extended_id, f.data, m.is_fd)
            )
        self.sent[m.name] += 1


def simulate_to_bus(
    bench: Any,
    plan: CanPlan,
    *,
    bus: Any,
    log_frame: Any = None,
    pace: bool = True,
    faults: FaultInjector | None = None,
    start_delay_s: float = 0.0,
    sim_overrides: dict[str, Any] | None = None,
    bitrate: int | None = None,
    data_bitrate: int | None = None,
) -> dict[str, Any]:
    """Run the simulated DAQ on ``bus`` (and/or ``log_frame``); return the summary."""
    from acquisition.can.codec import FrameEncoder, bus_load
    from ptinertia.sources import open_source

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

    with source:
        for item in source:
            push(encoder.encode(item))
            t_item = _start_time(item, source.layout)
            if t_item is not None:
                push(encoder.status(t_item))
                pop_until(t_item)
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


def _start_time(item: Any, layout: Any) -> float | None:
    from acquisition.stream import EdgeBlock, SampleBlock

    if isinstance(item, SampleBlock):
        return item.first_index / layout.group(item.group).rate_hz
    if isinstance(item, EdgeBlock) and item.times_s.size:
        return float(item.times_s[0])
    return None


def run(args: argparse.Namespace) -> int:
    from acquisition.can.codec import load_plan
    from acquisition.can.logs import FrameLogWriter
    from acquisition.can.source import open_bus
    from acquisition.sim.sweep import parse_sweep
    from ptinertia.config import load_bench

    bench = load_bench(args.bench)
    cfg = bench.can
    plan = load_plan(bench, args.dbc)
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
    rates = FaultRates(args.drop, args.duplicate, args.reorder, args.corrupt)
    faults = (
        FaultInjector(rates, plan, args.fault_seed)
        if any((rates.drop, rates.duplicate, rates.reorder, rates.corrupt))
        else None
    )
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
