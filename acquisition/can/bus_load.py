"""Bus timing: the time one frame occupies a CAN(-FD) bus, and the load a plan's frames make.

Kept apart from the payload codecs because it is arithmetic about bits on the wire,
not about what they mean; ``can-sim`` uses it to check that a bench fits the bus.
"""

from __future__ import annotations

import math

from acquisition.can.plan import CanPlan


def frame_time_s(
    n_bytes: int,
    *,
    fd: bool,
    bitrate: float,
    data_bitrate: float,
    extended: bool = False,
    stuffing: bool = True,
) -> float:
    """Time (s) one data frame occupies the bus, inter-frame space included.

    ``stuffing`` adds the worst-case dynamic stuff bits (one per four bits of the
    stuffed region); without it the result is the unstuffed minimum. CAN FD: the
    arbitration phase, CRC delimiter, ACK and EOF run at ``bitrate``, the rest at
    ``data_bitrate`` (bit rate switch on).
    """
    tail = 1 + 1 + 1 + 7 + 3  # CRC delimiter, ACK, ACK delimiter, EOF, IFS (at the nominal rate)
    if not fd:
        # SOF, 11-bit id, RTR, IDE, r0, DLC (an extended id adds SRR, 18 id bits and r1)
        head = 19 + (20 if extended else 0)
        stuffed = head + 8 * n_bytes + 15  # SOF .. CRC
        extra = (stuffed - 1) // 4 if stuffing else 0
        return (stuffed + tail + extra) / bitrate
    # SOF, 11-bit id, RRS, IDE, FDF, res, BRS (an extended id adds SRR and 18 id bits)
    arb = 17 + (19 if extended else 0)
    crc = 17 if n_bytes <= 16 else 21
    # ESI, DLC, data, stuff count, CRC and its fixed stuff bits, all at the data rate
    data = 1 + 4 + 8 * n_bytes + 4 + crc + math.ceil((4 + crc) / 4)
    extra_arb = (arb - 1) // 4 if stuffing else 0
    extra_data = (1 + 4 + 8 * n_bytes) // 4 if stuffing else 0
    return (arb + extra_arb + tail) / bitrate + (data + extra_data) / data_bitrate


def bus_load(
    plan: CanPlan,
    *,
    bitrate: float,
    data_bitrate: float,
    edge_rate_hz: float = 0.0,
    stuffing: bool = True,
) -> float:
    """Fraction of the bus time the plan's periodic frames take (edge frames at ``edge_rate_hz`` edges/s)."""
    total = 0.0
    for m in plan.messages:
        ft = frame_time_s(
            m.length,
            fd=m.is_fd,
            bitrate=bitrate,
            data_bitrate=data_bitrate,
            extended=m.is_extended_id,
            stuffing=stuffing,
        )
        if m.kind == "samples":
            total += m.frame_rate_hz * ft
        elif m.kind == "edges" and edge_rate_hz > 0:
            total += edge_rate_hz / m.samples_per_frame * ft
    return total
