"""Where the decoder's frames are: the runs of received frames and the holes between them.

Split from :mod:`acquisition.can.decoder`: the decoder walks and allocates only what was
received, so an outage (or frames dated far ahead by a corrupt log timestamp) costs
nothing however long it is.
"""

from __future__ import annotations

from acquisition.can.reorder import GroupAssembler, MessageStream


def received_spans(g: GroupAssembler, i0: int, upto: int) -> list[tuple[int, int]]:
    """Sample ranges within ``[i0, upto)`` covered by a received frame of some member,
    adjacent and overlapping ones merged, in order."""
    spans = sorted(
        (max(i0, n * m.plan.samples_per_frame), min(upto, (n + 1) * m.plan.samples_per_frame))
        for m in g.members
        for n in m.received
    )
    merged: list[tuple[int, int]] = []
    for a, b in spans:
        if b <= a:
            continue
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return merged


def next_received(s: MessageStream, n: int) -> int:
    """The first frame number after ``n`` that ``s`` holds (a large number if none)."""
    return min((k for k in s.received if k > n), default=1 << 62)
