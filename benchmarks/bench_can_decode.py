"""CAN decoding throughput against the bus it must keep up with.

Prints:

1. decoding throughput (frames/s on one core) of :class:`FrameDecoder` on the
   example DBC's frames from a simulated i3 sweep, per batch size (a live source
   decodes what arrived in a 50 ms poll: ~150 frames on a busy bus), for the
   normal mix and for accelerometer or edge frames only;
2. the receive path through python-can's virtual bus and :class:`CanBusSource`
   (send + receive + decode in one process);
3. how many frames a saturated bus carries (CAN FD 64-byte and 8-byte frames at
   500 k / 2 M, classic CAN at 500 k), the decoding margin over each, and the
   per-channel sample rate the decoder could take for 9 accelerometer channels
   with 5x headroom;
4. the bus load of the example DBC's frames per accelerometer rate and bit rates,
   and why classic CAN cannot carry them.

Usage: python benchmarks/bench_can_decode.py [--seconds 10] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from acquisition.can.bus_load import frame_time_s
from acquisition.can.decoder import FrameDecoder
from acquisition.can.frames import RawFrame
from ptinertia.commands.can_sim import simulate_to_bus
from ptinertia.config import load_bench
from ptinertia.to_can import can_plan

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "examples" / "i3-bench.toml"
DBC = ROOT / "examples" / "bench.dbc"


def decode_rate(plan, frames: list[RawFrame], batch: int, repeat: int) -> float:
    """Best of ``repeat`` runs, frames/s."""
    best = np.inf
    for _ in range(repeat):
        dec = FrameDecoder(plan)
        t = time.perf_counter()
        for i in range(0, len(frames), batch):
            dec.feed(frames[i : i + batch])
        dec.finish()
        best = min(best, time.perf_counter() - t)
    return len(frames) / best


def bus_path_rate(bench, plan, seconds: float) -> tuple[float, int]:
    import threading

    import can

    from acquisition.can.bus import CanBusSource

    channel = "bench-can-decode"
    src = CanBusSource(plan, interface="virtual", channel=channel, idle_timeout_s=5.0)
    tx = can.Bus(interface="virtual", channel=channel)
    frames: list[RawFrame] = []
    simulate_to_bus(
        bench,
        plan,
        bus=None,
        log_frame=frames.append,
        pace=False,
        sim_overrides={"duration_s": seconds},
    )
    msgs = [
        can.Message(
            arbitration_id=f.arbitration_id,
            data=f.data,
            is_fd=f.is_fd,
            is_extended_id=f.is_extended_id,
        )
        for f in frames
    ]
    t = time.perf_counter()
    th = threading.Thread(target=lambda: [tx.send(m) for m in msgs])
    th.start()
    n = sum(1 for _ in src)
    th.join()
    dt = time.perf_counter() - t
    src.close()
    tx.shutdown()
    return len(msgs) / dt, n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated sweep length (s)")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    bench = load_bench(BENCH)
    plan = can_plan(bench, DBC)
    frames: list[RawFrame] = []
    simulate_to_bus(
        bench,
        plan,
        bus=None,
        log_frame=frames.append,
        pace=False,
        sim_overrides={"duration_s": a.seconds},
    )
    acc_ids = {m.frame_id for m in plan.messages if m.group == "accel"}
    edge_ids = {m.frame_id for m in plan.messages if m.kind == "edges"}
    print(
        f"== decoding, {len(frames)} frames of a {a.seconds:g} s i3 sweep 1500 -> 4500 rpm (one core, best of {a.repeat})"
    )
    rates = {}
    for batch in (150, 1000, 20000):
        rates[batch] = decode_rate(plan, frames, batch, a.repeat)
        print(
            f"  mixed frames, batches of {batch:>5}: {rates[batch]:>9,.0f} frames/s  ({1e6 / rates[batch]:.1f} us/frame)"
        )
    acc = [f for f in frames if f.arbitration_id in acc_ids]
    edges = [f for f in frames if f.arbitration_id in edge_ids]
    r_acc = decode_rate(plan, acc, 150, a.repeat)
    r_edge = decode_rate(plan, edges, 150, a.repeat)
    print(f"  accelerometer frames only (27 samples each), batches of 150: {r_acc:>9,.0f} frames/s")
    print(
        f"  tacho edge frames only (up to 13 edges each), batches of 150: {r_edge:>9,.0f} frames/s"
    )
    live = min(rates[150], r_acc, r_edge)

    rate_bus, n_items = bus_path_rate(bench, plan, min(a.seconds, 5.0))
    print(
        f"== virtual bus, send + receive thread + decode in one process: {rate_bus:,.0f} frames/s ({n_items} items)"
    )

    print(
        "== saturated buses (frames/s at 100 % load; unstuffed / worst-case stuffing) and decoding margin"
    )
    cases = [
        ("CAN FD 64 B, 500 k / 2 M", 64, True, 500e3, 2e6),
        ("CAN FD 64 B, 1 M / 2 M", 64, True, 1e6, 2e6),
        ("CAN FD 8 B, 500 k / 2 M", 8, True, 500e3, 2e6),
        ("classic 8 B, 500 k", 8, False, 500e3, 500e3),
        ("classic 8 B, 1 M", 8, False, 1e6, 1e6),
    ]
    for label, n, fd, br, dbr in cases:
        best = 1 / frame_time_s(n, fd=fd, bitrate=br, data_bitrate=dbr, stuffing=False)
        worst = 1 / frame_time_s(n, fd=fd, bitrate=br, data_bitrate=dbr)
        print(
            f"  {label:<26} {worst:>7,.0f} - {best:>7,.0f} frames/s   margin {live / best:>5.1f}x"
        )
    fd64 = 1 / frame_time_s(64, fd=True, bitrate=500e3, data_bitrate=2e6, stuffing=False)
    fs_max = r_acc / 5 * 27 / 9
    print(
        f"  with 5x headroom the decoder takes {r_acc / 5:,.0f} accelerometer frames/s: "
        f"{fs_max:,.0f} samples/s per channel for 9 channels (the bus itself caps it far lower, below)"
    )
    print(
        f"  target: 5 x {fd64:,.0f} = {5 * fd64:,.0f} frames/s (saturated CAN FD at 2 Mbit/s, 64-byte frames)"
    )

    print(
        "== bus load of the example DBC's frames (9 accelerometer channels, 9 samples x 3 axes per frame,"
    )
    print(
        "   tacho edges of a 60-2 wheel at 4500 rpm, 13 per frame; ECU speed 100 Hz; no pressure)"
    )
    edge_fps = 58 * 4500 / 60 / 13
    acc_msgs = [m for m in plan.messages if m.group == "accel"]
    ecu = next(m for m in plan.messages if m.group == "rpm")
    tacho = next(m for m in plan.messages if m.kind == "edges")
    for br, dbr in ((500e3, 2e6), (1e6, 2e6), (1e6, 5e6)):
        cells = []
        for fs in (2560.0, 5120.0, 10240.0, 20480.0):
            loads = []
            for stuffing in (False, True):
                load = sum(
                    fs
                    / m.samples_per_frame
                    * frame_time_s(64, fd=True, bitrate=br, data_bitrate=dbr, stuffing=stuffing)
                    for m in acc_msgs
                )
                load += edge_fps * frame_time_s(
                    tacho.length, fd=True, bitrate=br, data_bitrate=dbr, stuffing=stuffing
                )
                load += 100 * frame_time_s(
                    ecu.length, fd=False, bitrate=br, data_bitrate=br, stuffing=stuffing
                )
                loads.append(load)
            cells.append(f"{fs:>6.0f} Hz {100 * loads[0]:>3.0f}-{100 * loads[1]:>3.0f} %")
        print(f"  {br / 1e3:>5.0f} k / {dbr / 1e6:.0f} M: " + "   ".join(cells))
    need = 9 * 5120 / 3  # classic frames of 3 int16 samples + a 16-bit counter
    cap = 1 / frame_time_s(8, fd=False, bitrate=500e3, data_bitrate=500e3, stuffing=False)
    print(
        f"  classic CAN at 500 k: 9 x 5120 samples/s in 8-byte frames of 3 samples + counter = {need:,.0f} frames/s, "
        f"the bus carries at most {cap:,.0f} ({need / cap:.1f}x over); the payload alone is "
        f"{9 * 5120 * 16 / 1e3:.0f} kbit/s"
    )


if __name__ == "__main__":
    main()
