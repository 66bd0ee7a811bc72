"""The live CAN(-FD) bus: :class:`CanBusSource`, its receive thread and python-can glue.

Everything that touches python-can is here, imported on use: a replay or a CAN log
never loads a bus driver. The receive thread only moves frames to a queue (and
re-opens a bus that died); decoding happens in the consumer, in batches.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from acquisition.can.decoder import FrameDecoder
from acquisition.can.frames import RawFrame
from acquisition.can.plan import CanPlan
from acquisition.can.reorder import DecoderOptions
from acquisition.can.stats import DecoderStats
from acquisition.stream import Source, SourceError, SourceEvent, StreamItem, StreamLayout


def message_to_frame(msg: Any) -> RawFrame:
    """A python-can ``Message`` as a :class:`RawFrame`."""
    return RawFrame(
        round(msg.timestamp * 1e9),
        msg.arbitration_id,
        bool(msg.is_extended_id),
        bytes(msg.data),
        bool(msg.is_fd),
    )


def frame_to_message(frame: RawFrame, channel: Any = None) -> Any:
    """A :class:`RawFrame` as a python-can ``Message`` (the inverse of :func:`message_to_frame`;
    an FD frame switches its bit rate, as the simulated DAQ sends it)."""
    import can  # on use, as in open_bus

    return can.Message(
        timestamp=frame.timestamp_ns * 1e-9,
        arbitration_id=frame.arbitration_id,
        is_extended_id=frame.is_extended_id,
        is_fd=frame.is_fd,
        bitrate_switch=frame.is_fd,
        data=frame.data,
        channel=channel,
    )


def bus_error_kind(msg: Any) -> str:
    """``bus_off``, ``error_passive`` or ``bus_error`` from an error frame (SocketCAN error classes)."""
    if msg.arbitration_id & 0x40:
        return "bus_off"
    if msg.arbitration_id & 0x04 and len(msg.data) > 1 and msg.data[1] & 0x30:
        return "error_passive"
    return "bus_error"


def open_bus(interface: str, channel: str, **kwargs: Any) -> Any:
    """``can.Bus`` with errors turned into one-line :class:`SourceError` messages."""
    import can  # on use: python-can loads its interfaces; a replay never needs it

    if interface not in can.interfaces.VALID_INTERFACES:
        raise SourceError(
            f"unknown CAN interface {interface!r}; python-can knows: {', '.join(sorted(can.interfaces.VALID_INTERFACES))}"
        )
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, TypeError) as err:
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        if interface == "remote" and isinstance(err, OSError):
            # the demo bus of docs/can.md: its server is a process of its own
            text += (
                " (is the bus server running? python -m can_remote --interface virtual "
                "--channel 0 --host 127.0.0.1)"
            )
        raise SourceError(f"cannot open CAN bus {interface}:{channel}: {text}") from None


class Clock:
    """Real time, as the live source waits: the receive thread's back-off, the consumer's
    wait for frames, the idle, start and stop-grace timeouts. Tests pass a virtual clock
    (the same three methods) so that nothing in them sleeps or reads the wall clock."""

    def now(self) -> float:
        """Seconds, monotonic."""
        return time.monotonic()

    def sleep(self, seconds: float, stop: threading.Event) -> bool:
        """Wait ``seconds`` or until ``stop`` is set; True if it was."""
        return stop.wait(seconds)

    def get(self, q: queue.SimpleQueue[Any], timeout: float) -> Any:
        """The next queue item, waiting at most ``timeout`` s (:class:`queue.Empty` if none)."""
        return q.get(timeout=timeout)


_LOST = "lost"
_REOPENED = "reopened"
_STATE = "state"
_ERRORS = "errors"


class _Receiver(threading.Thread):
    """Reads the bus into a queue so that processing never stalls it; re-opens a bus that died."""

    def __init__(
        self,
        factory: Callable[[], Any],
        bus: Any,
        q: queue.SimpleQueue[Any],
        backoff: tuple[float, float],
        max_outage_s: float,
        clock: Clock,
    ) -> None:
        super().__init__(name="can-rx", daemon=True)
        self.clock = clock
        self.factory = factory
        self.bus = bus
        self.q = q
        self.backoff = backoff
        self.max_outage_s = max_outage_s
        self.stop = threading.Event()

    def run(self) -> None:
        import can  # on use, as in open_bus

        last_state = None
        next_poll = 0.0
        while not self.stop.is_set():
            try:
                msg = self.bus.recv(0.05)
                now = self.clock.now()
                if now >= next_poll:
                    next_poll = now + 0.5
                    state = _bus_state(self.bus)
                    if state != last_state and state is not None:
                        if last_state is not None or state != "ACTIVE":
                            self.q.put((_STATE, state, time.time()))
                        last_state = state
            except (can.CanError, OSError, ValueError) as err:
                if self.stop.is_set():
                    return
                self.q.put(
                    (
                        _LOST,
                        str(err).strip().splitlines()[0]
                        if str(err).strip()
                        else type(err).__name__,
                        time.time(),
                    )
                )
                if not self._reopen():
                    return
                continue
            if msg is None:
                continue
            if msg.is_error_frame:
                self.q.put((_ERRORS, bus_error_kind(msg), msg.timestamp))
            elif not msg.is_remote_frame:
                self.q.put(msg)

    def _reopen(self) -> bool:
        t0 = self.clock.now()
        delay = self.backoff[0]
        try:
            self.bus.shutdown()
        except Exception:  # a dead bus may fail to shut down; we are replacing it anyway
            pass
        while not self.stop.is_set():
            if self.clock.now() - t0 > self.max_outage_s:
                self.q.put((_LOST, f"gave up re-opening after {self.max_outage_s:g} s", None))
                self.q.put(None)
                return False
            if self.clock.sleep(delay, self.stop):
                return False
            try:
                self.bus = self.factory()
            except Exception:  # any driver error means "not back yet": keep trying with back-off
                delay = min(self.backoff[1], 2 * delay)
                continue
            self.q.put((_REOPENED, self.clock.now() - t0, time.time()))
            return True
        return False


def _bus_state(bus: Any) -> str | None:
    try:
        return str(bus.state.name)
    except (NotImplementedError, AttributeError):
        return None


class CanBusSource(Source):
    """Live CAN(-FD) source on any python-can interface.

    A receive thread moves frames to a queue; iteration decodes them in batches.
    The stream ends at the DAQ's stop frame (after ``stop_grace_s``), after
    ``idle_timeout_s`` without frames once data flowed, or at :meth:`close`.

    Parameters
    ----------
    plan : CanPlan
    interface, channel : python-can bus
    bus_kwargs : extra ``can.Bus`` arguments (bitrate, data_bitrate, fd, ...)
    bus_factory : builds the bus (default ``can.Bus``), also to re-open it
    options : DecoderOptions
    idle_timeout_s : end after this long without frames (None: never)
    stop_grace_s : keep reading this long after the stop frame (late frames)
    backoff_s : (first, longest) delay between re-open attempts
    max_outage_s : give up re-opening after this long
    frame_listener : called with every batch of raw frames (the recorder)
    start_timeout_s : end, saying what to check, when no frame came this long after opening
        (None: wait for ever)
    clock : Clock
        What the source waits with (a virtual one in tests).
    """

    def __init__(
        self,
        plan: CanPlan,
        *,
        interface: str,
        channel: str,
        bus_kwargs: dict[str, Any] | None = None,
        bus_factory: Callable[[], Any] | None = None,
        options: DecoderOptions | None = None,
        idle_timeout_s: float | None = 10.0,
        stop_grace_s: float = 0.2,
        backoff_s: tuple[float, float] = (0.1, 5.0),
        max_outage_s: float = 60.0,
        frame_listener: Callable[[list[RawFrame]], None] | None = None,
        poll_s: float = 0.05,
        start_timeout_s: float | None = None,
        clock: Clock | None = None,
    ) -> None:
        super().__init__()
        self.clock = clock or Clock()
        self.start_timeout_s = start_timeout_s
        self.where = f"{interface}:{channel}"
        #: why nothing was received, once the start timeout passed without a frame
        self.no_data_reason: str | None = None
        kwargs = dict(bus_kwargs or {})
        self._factory = bus_factory or (lambda: open_bus(interface, channel, **kwargs))
        self.decoder = FrameDecoder(plan, options)
        self.idle_timeout_s = idle_timeout_s
        self.stop_grace_s = stop_grace_s
        self.frame_listener = frame_listener
        self.poll_s = poll_s
        meta = dict(plan.layout.metadata)
        meta.update({"interface": interface, "channel": channel})
        self._layout = StreamLayout(plan.layout.groups, plan.layout.edge_channels, meta)
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        bus = self._factory()
        self._rx = _Receiver(self._factory, bus, self._q, backoff_s, max_outage_s, self.clock)
        self._rx.start()

    @property
    def layout(self) -> StreamLayout:
        return self._layout

    @property
    def stats(self) -> DecoderStats:
        return self.decoder.stats

    def _drain(self, timeout: float) -> tuple[list[RawFrame], list[SourceEvent], bool]:
        frames: list[RawFrame] = []
        events: list[SourceEvent] = []
        ended = False
        try:
            first = self.clock.get(self._q, timeout)
        except queue.Empty:
            return frames, events, ended
        item = first
        while True:
            if item is None:
                ended = True
            elif isinstance(item, tuple):
                events.append(self._control(item))
            else:
                frames.append(message_to_frame(item))
            if len(frames) >= 20000:
                break
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
        return frames, events, ended

    def _control(self, item: tuple[str, Any, float | None]) -> SourceEvent:
        kind, value, _ = item  # (kind, value, wall time)
        if kind == _ERRORS:
            self.decoder.stats.bus_errors += 1
            return SourceEvent(value, f"CAN {value.replace('_', ' ')} frame received", None)
        if kind == _STATE:
            what = {"PASSIVE": "error_passive", "ERROR": "bus_off", "ACTIVE": "bus_active"}.get(
                value, value.lower()
            )
            return SourceEvent(what, f"CAN controller state: {value.lower()}", None)
        if kind == _LOST:
            return SourceEvent(
                "bus_lost", f"CAN bus lost ({value}); re-opening, the gap will be flagged", None
            )
        return SourceEvent(
            "bus_reopened",
            f"CAN bus re-opened after {value:.2f} s; frames sent meanwhile are lost",
            None,
        )

    def _iter_items(self) -> Iterator[StreamItem]:
        last_frame = None
        stop_seen = None
        warned = False
        t_open = self.clock.now()
        while True:
            if self._closed:  # closed from another thread while nothing arrives
                return
            frames, events, ended = self._drain(self.poll_s)
            yield from events
            now = self.clock.now()
            if frames:
                last_frame = now
                if self.frame_listener is not None:
                    self.frame_listener(frames)
                yield from self.decoder.feed(frames)
            if ended:
                break
            if self.decoder.stopped_s is not None and stop_seen is None:
                stop_seen = now
            if stop_seen is not None and now - stop_seen >= self.stop_grace_s:
                break
            if (
                self.idle_timeout_s is not None
                and last_frame is not None
                and now - last_frame > self.idle_timeout_s
            ):
                yield SourceEvent(
                    "idle", f"no CAN frame for {self.idle_timeout_s:g} s: ending the acquisition"
                )
                break
            if last_frame is None and not warned and now - t_open > 2.0:
                warned = True
                yield SourceEvent("waiting", "no CAN frame yet; waiting for the DAQ to start")
            if (
                last_frame is None
                and self.start_timeout_s is not None
                and now - t_open > self.start_timeout_s
            ):
                self.no_data_reason = (
                    f"no CAN frame on {self.where} within {self.start_timeout_s:g} s: check that "
                    "the DAQ (or ptinertia can-sim) sends on this interface and channel, that "
                    "both name the same bus (for 'remote', that the python -m can_remote server "
                    "runs on that address), and the bit rates and CAN FD setting"
                )
                yield SourceEvent("no_data", self.no_data_reason)
                break
        yield from self.decoder.finish()
        yield SourceEvent(
            "can_stats", self.decoder.stats.summary(), None, self.decoder.stats.total("lost")
        )

    def _shutdown(self) -> None:
        self._rx.stop.set()
        self._q.put(None)  # wakes a consumer waiting for frames (closed from another thread)
        self._rx.join(timeout=2.0)
        try:
            self._rx.bus.shutdown()
        except Exception:  # shutting down a dead bus must not hide the caller's own error
            pass
