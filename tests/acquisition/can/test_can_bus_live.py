"""The CAN source on a live bus: bus errors and controller states reported, a bus that
disappears reopened with the gap flagged, a close from another thread, a silent bus that
ends at its start timeout (split from test_can_source.py; fixtures in conftest.py)."""

from __future__ import annotations

import threading

import can
import numpy as np
from support.can_streams import (
    VirtualClock,
    assemble,
    quantum,
)

from acquisition.can.bus import CanBusSource, frame_to_message
from acquisition.stream import SourceEvent

# -- the live bus: errors, outages, the end ------------------------------------------------------


class _StubBus:
    """A bus that plays back a list of messages, then nothing (``exhausted``); reports a
    controller state. It never waits: the source's virtual clock stands for the time."""

    def __init__(self, messages, state=can.BusState.ACTIVE, fail_at=None):
        self.messages = list(messages)
        self.state = state
        self.fail_at = fail_at  # raise (the adapter unplugged) after this many messages
        self.given = 0
        self.exhausted = False

    def recv(self, timeout):
        if self.fail_at is not None and self.given == self.fail_at:
            raise can.CanOperationError("adapter unplugged")
        if self.messages:
            self.given += 1
            return self.messages.pop(0)
        self.exhausted = True  # the previous message is in the source's queue by now
        return None

    def shutdown(self):
        pass


def _messages(frames):
    return [frame_to_message(f) for f in frames]


def test_bus_errors_and_controller_state_are_reported(plan, clean_frames):
    msgs = _messages(clean_frames[:400])
    msgs.insert(100, can.Message(is_error_frame=True, arbitration_id=0x40))  # bus off
    msgs.insert(
        200,
        can.Message(
            is_error_frame=True, arbitration_id=0x04, data=bytes([0, 0x20, 0, 0, 0, 0, 0, 0])
        ),
    )
    msgs.insert(300, can.Message(is_error_frame=True, arbitration_id=0x02))
    bus = _StubBus(msgs, can.BusState.PASSIVE)
    with CanBusSource(
        plan,
        interface="stub",
        channel="0",
        bus_factory=lambda: bus,
        idle_timeout_s=0.3,
        clock=VirtualClock(lambda: bus.exhausted),
    ) as src:
        items = list(src)
    kinds = [e.kind for e in items if isinstance(e, SourceEvent)]
    assert {"bus_off", "error_passive", "bus_error", "idle", "can_stats"} <= set(kinds)
    assert src.stats.bus_errors == 3
    assert "3 bus errors" in items[-1].message


def test_a_bus_that_disappears_is_reopened_and_the_gap_flagged(plan, reference, clean_frames):
    msgs = _messages(clean_frames)
    outage = 300  # frames sent while the adapter was away: lost
    made = []

    def factory():
        if not made:
            made.append(_StubBus(msgs, fail_at=1500))
        else:
            made.append(_StubBus(msgs[1500 + outage :]))
        return made[-1]

    clock = VirtualClock(lambda: len(made) == 2 and made[-1].exhausted)
    src = CanBusSource(
        plan,
        interface="stub",
        channel="0",
        bus_factory=factory,
        backoff_s=(0.05, 0.2),
        idle_timeout_s=3.0,
        clock=clock,
    )
    items = list(src)
    src.close()
    kinds = [e.kind for e in items if isinstance(e, SourceEvent)]
    assert kinds.index("bus_lost") < kinds.index("bus_reopened") and len(made) == 2
    stats = src.stats
    data_frames = sum(1 for f in clean_frames if f.arbitration_id != 0x7F0)
    lost_data = sum(1 for f in clean_frames[1500 : 1500 + outage] if f.arbitration_id != 0x7F0)
    # every frame that did not arrive is counted lost (the edge frames' tail aside: an edge
    # stream cannot tell frames lost from edges not yet due), and placed samples are right
    assert lost_data - 2 <= stats.total("lost") <= lost_data
    assert stats.total("frames") + stats.total("lost") == data_frames
    got = assemble(items, plan.layout)[0]["accel"]
    ref = assemble(reference[1], reference[0])[0]["accel"]
    ok = ~np.isnan(got)
    assert np.abs(got[ok] - ref[:, : got.shape[1]][ok]).max() <= quantum(plan, "accel") * (1 + 1e-9)
    assert "gap" in kinds


def test_close_from_another_thread_ends_a_silent_source(plan):
    # the consumer waits for frames that never come (the clock never advances); a close
    # from another thread must wake it
    bus = _StubBus([])
    src = CanBusSource(
        plan,
        interface="stub",
        channel="0",
        bus_factory=lambda: bus,
        idle_timeout_s=None,
        clock=VirtualClock(lambda: False),
    )
    threading.Thread(target=src.close).start()
    assert list(src) == []


def test_a_silent_bus_ends_at_the_start_timeout_and_says_what_to_check(plan):
    bus = _StubBus([])
    src = CanBusSource(
        plan,
        interface="remote",
        channel="ws://127.0.0.1:54701/",
        bus_factory=lambda: bus,
        start_timeout_s=5.0,
        clock=VirtualClock(lambda: bus.exhausted),
    )
    with src:
        items = list(src)
    events = {e.kind: e.message for e in items if isinstance(e, SourceEvent)}
    assert "waiting" in events and "no_data" in events
    assert src.no_data_reason == events["no_data"]
    assert "no CAN frame on remote:ws://127.0.0.1:54701/ within 5 s" in src.no_data_reason
    assert "can_remote server" in src.no_data_reason
