"""Record a run to MCAP: raw stream, order frames, gating, estimates, bench and truth.

One channel per topic (see ``docs/recording-format.md``):

* ``/raw/<group>`` (SampleBlock), ``/raw/edges/<channel>`` (EdgeBlock), and the
  source's events on ``/events`` with ``origin = "source"``: the raw stream,
  in the order the dsp stage saw it, which is all a replay needs;
* ``/raw/can`` (CanFrames): the CAN frames as received, when the source is a
  CAN bus (:meth:`McapRecorder.on_can_frames` as its ``frame_listener``);
* ``/orders`` (OrderFrame), ``/gating`` (Gating), ``/estimate`` (Estimate), and
  ``/events`` with ``origin = "dsp"``: what the live run computed from it;
* ``/foxglove/log`` (``foxglove.Log``): every event and every change of the
  gating, for Foxglove's log panel; ``/foxglove/scene`` and ``/foxglove/tf``
  (the 3D view) come from a scene sink through :meth:`McapRecorder.write_view`
  (:mod:`replay.foxglove`).

Times. Both times of a message are on one clock, the run's stream clock
placed at ``time_origin_ns`` (the wall clock at ``start``, kept in the
metadata), so Foxglove shows the run at its real date and replays it at its
real pace, paced or not. The log time is when the data the message describes
was measured: ``time_origin_ns`` plus the stream time of the block's first
sample, the frame's centre, the gating decision, the estimate's last frame.
The publish time is when the message existed: ``time_origin_ns`` plus the
newest stream time the recorder had seen when it came, so ``publish >= log``
and the difference is the message's latency in stream time (about one dsp
block for order frames). The wall clock of writing is not used: on an unpaced
run it ran 48 s behind the stream clock, and it made every file different.

Crash safety. The file is written in place from the start: header,
metadata (layout, settings, truth, version, source) and attachments (bench
file, DBC) first (:mod:`replay.recording_head`), then ZSTD-compressed chunks,
one per ``chunk_s`` (0.5 s) slice of stream time (:mod:`replay.time_chunks`:
chunks do not overlap in time, so readers seek by time). A slice is closed
once the stream is ``late_s`` (0.25 s) past its end, or it has been open
``chunk_s + late_s`` of wall time, and is in the file, flushed to the OS, a
few milliseconds later, so a process killed with SIGKILL loses at most the
open slices: 0.75 s of data plus the item that was being written. (The
wall-time bound is checked when a message arrives; a stalled stream adds
nothing to lose.) The page cache survives the process, so there is no fsync:
a power cut is a different matter.

Cost to the processing thread. The writer thread packs the closed slices' records, casts
the sample blocks to float32 (``stream_codec.LateSamples``), compresses and writes; a block's
frames are encoded together (``prepare_frames``), the gating from a layout per structure
(``results_codec.encode_outcome``). The hooks cost the caller 0.036 s of CPU a minute of
9 x 25.6 kHz (0.075 s before; rec_whole.py). :mod:`replay.raw_writer` records a raw stream alone.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from acquisition.can.frames import RawFrame
from acquisition.stream import EdgeBlock, SampleBlock, SourceEvent, StreamItem, StreamLayout
from dsp.frames import OrderFrame
from estimator.outcome import FrameOutcome
from estimator.result import Estimate, EstimateUpdate
from replay import foxglove, results_codec, stream_codec
from replay.errors import LogError
from replay.mcap_output import Payload, check_level
from replay.mcapwriter import ThreadedWriter
from replay.recording_head import check_topics, end_metadata, ptinertia_version, write_head
from replay.schemas import (
    META_END,
    TOPIC_CAN,
    TOPIC_ESTIMATE,
    TOPIC_EVENTS,
    TOPIC_GATING,
    TOPIC_ORDERS,
    edge_topic,
    raw_topic,
)
from replay.time_chunks import Pending, TimeChunker

CHUNK_S = 0.5
LATE_S = 0.25  # how long a slice waits for late results (they lag ~0.04 s in the i3 run)
CHUNK_BYTES = 8 * 1024 * 1024  # a size bound too, for very wide streams
# zstd level of the chunks, chosen on measurement (docs/recording-format.md, "Size and speed"):
# float32 samples with noise hardly compress; level 3 saves 10 % of the file for 4x the CPU
# of level -1 (3 %), and 10x its decompression time in every replay
ZSTD_LEVEL = -1


@dataclass
class RecorderStats:
    """Messages per topic, chunks written, payload bytes (before compression)."""

    messages: Counter[str] = field(default_factory=Counter)
    payload_bytes: Counter[str] = field(default_factory=Counter)
    chunks: int = 0


def _discard(fh: IO[bytes]) -> None:
    """Close a file after a failure, which is what gets reported (a full disk fails again here)."""
    with contextlib.suppress(OSError):
        fh.close()


class McapRecorder:
    """A sink of the pipeline writing everything it is told to an MCAP file.

    It has every hook of the app's ``Sink`` protocol (replay does not import the app).

    Parameters
    ----------
    path : str or Path
        Output file, written in place (a killed run leaves a readable prefix).
    chunk_s : float
        Stream time of a chunk, s (:mod:`replay.time_chunks`).
    late_s : float
        How long past its end a chunk waits for late results, s of stream time.
    chunk_bytes : int
        Largest uncompressed chunk, bytes.
    time_origin_ns : int or None
        Log time of stream time 0, ns since the Unix epoch; None: the wall clock at ``start``.
    compression : ``"zstd"``, ``"lz4"`` or ``"none"``.
    level : int
        zstd level (:data:`ZSTD_LEVEL`; 3 for about 7 % smaller files at 4x the CPU).
    monotonic : callable returning seconds
        The clock of the wall-time bound on a chunk (``time.monotonic``; a test's fake clock).
    """

    def __init__(
        self,
        path: str | Path,
        chunk_s: float = CHUNK_S,
        chunk_bytes: int = CHUNK_BYTES,
        late_s: float | None = None,
        time_origin_ns: int | None = None,
        compression: str = "zstd",
        monotonic: Callable[[], float] = time.monotonic,
        level: int = ZSTD_LEVEL,
    ) -> None:
        if not (chunk_s > 0 and math.isfinite(chunk_s)):
            raise LogError(f"chunk_s: expected a positive time in s, got {chunk_s}")
        kinds = {"zstd": "zstd", "lz4": "lz4", "none": ""}  # option -> name in the chunk records
        if compression not in kinds:
            raise LogError(f"compression: expected one of {', '.join(kinds)}, got {compression!r}")
        self.path = Path(path)
        self.chunk_s = float(chunk_s)
        self.chunk_bytes = int(chunk_bytes)
        self.time_origin_ns = time_origin_ns
        self.compression = kinds[compression]
        try:
            self.level = check_level(level)
        except ValueError as err:
            raise LogError(str(err)) from None
        self._monotonic = monotonic
        self.stats = RecorderStats()
        self._file: IO[bytes] | None = None
        self._writer: ThreadedWriter | None = None
        self._channels: dict[str, int] = {}
        self._layout: StreamLayout | None = None
        self._origin_ns = 0
        self._t_last = 0.0  # latest stream time seen (for untimed events)
        late = LATE_S * self.chunk_s / CHUNK_S if late_s is None else float(late_s)
        self._chunker = TimeChunker(self.chunk_s, late, monotonic)
        self._last_source_event: SourceEvent | None = None
        self._gating_log = foxglove.GatingLog()
        self._encoded: dict[int, tuple[OrderFrame, bytes]] = {}  # prepare_frames' block
        self._closed = False
        self._failed = False  # a write failed: reported once, close() only closes the file
        # on_can_frames comes from the acquisition thread, everything else from the
        # processing thread: one lock around the writer
        self._lock = threading.Lock()

    @property
    def origin_ns(self) -> int:
        """Log time of stream time 0, ns (fixed by :meth:`start`)."""
        return self._origin_ns

    # -- lifecycle ------------------------------------------------------------------------
    def start(self, context: Any) -> None:
        """Open the file; write header, metadata, attachments and the channels."""
        layout: StreamLayout = context.layout
        self._layout = layout
        check_topics(layout)
        try:
            # unbuffered: after a failed write (a full disk) the writer cuts the file back
            # to its last complete chunk, which a buffer holding the failed bytes would undo
            self._file = open(self.path, "wb", buffering=0)  # closed in close()
        except OSError as err:
            raise self._write_error(err) from None
        self._origin_ns = (
            time.time_ns() if self.time_origin_ns is None else int(self.time_origin_ns)
        )
        writer = ThreadedWriter(
            self._file, chunk_size=self.chunk_bytes, compression=self.compression, level=self.level
        )
        self._writer = writer
        try:
            writer.start(profile="", library=f"ptinertia {ptinertia_version()}")
            self._channels = write_head(writer, context, self._origin_ns)
            writer.sync()  # header, metadata and attachments are in the file
        except BaseException as err:
            self._abandon()
            if isinstance(err, OSError):
                raise self._write_error(err) from err
            raise

    def close(self, final: Estimate | None = None) -> None:
        """Write the final estimate, the end metadata and the summary; close the file. Idempotent."""
        with self._lock:
            self._close(final)

    def _close(self, final: Estimate | None) -> None:
        if self._closed or self._writer is None or self._file is None:
            self._closed = True
            return
        if self._failed:  # the file was cut and closed by the writer; nothing more to add
            self._abandon()
            return
        try:
            try:
                if final is not None:
                    # the final estimate also counts the frames rejected after the last used one
                    data = results_codec.encode_estimate(self._t_last, math.nan, final, final=True)
                    self._add_locked(TOPIC_ESTIMATE, self._t_last, data, "result")
                self._write_chunks(self._chunker.drain())
                self._writer.add_metadata(META_END, end_metadata(self.stats.messages, final))
                self._writer.finish()
                self.stats.chunks = self._writer.chunks
            finally:
                self._closed = True
                self._writer.stop()  # done by finish(), unless something failed before it
            self._file.close()
        except OSError as err:
            _discard(self._file)
            raise self._write_error(err) from err
        except BaseException:
            _discard(self._file)
            raise

    # -- sink hooks -----------------------------------------------------------------------
    def on_item(self, item: StreamItem) -> None:
        layout = self._require_started()
        if isinstance(item, SampleBlock):
            group = layout.group(item.group)
            t = stream_codec.sample_time(item, group)
            data = stream_codec.encode_samples_late(item, group)  # cast on the writer thread
            self._add(raw_topic(item.group), t, data, "raw")
        elif isinstance(item, EdgeBlock):
            t = float(item.times_s[0]) if len(item.times_s) else self._t_last
            self._add(edge_topic(item.channel), t, stream_codec.encode_edges(item, t), "raw")
        elif isinstance(item, SourceEvent):
            self._last_source_event = item
            t = self._t_last if item.time_s is None else item.time_s
            self._add(TOPIC_EVENTS, t, stream_codec.encode_event(item, "source", t), "raw")
            self._log_event(item, "source", t)
        else:
            raise TypeError(f"not a stream item: {type(item).__name__}")

    def on_event(self, event: SourceEvent) -> None:
        # The pipeline reports a source's own events twice (as an item, then as an
        # event); the item is the one that belongs to the raw stream.
        if event is self._last_source_event:
            return
        self._require_started()
        t = self._t_last if event.time_s is None else event.time_s
        self._add(TOPIC_EVENTS, t, stream_codec.encode_event(event, "dsp", t), "result")
        self._log_event(event, "dsp", t)

    def prepare_frames(self, frames: Sequence[OrderFrame]) -> None:
        """Encode a block's frames together; their :meth:`on_frame` calls take the bytes."""
        encoded = results_codec.encode_frames(frames)
        self._encoded = {id(f): (f, data) for f, data in zip(frames, encoded, strict=True)}

    def on_frame(self, frame: OrderFrame, outcome: FrameOutcome) -> None:
        self._require_started()
        held = self._encoded.pop(id(frame), (None, b""))  # (held: the id stays the frame's)
        data = held[1] if held[0] is frame else results_codec.encode_frame(frame)
        self._add(TOPIC_ORDERS, frame.time_s, data, "result")
        self._add(TOPIC_GATING, outcome.time_s, results_codec.encode_outcome(outcome), "result")
        change = self._gating_log.update(outcome.reason, outcome.rpm)
        if change is not None:
            self._log(outcome.time_s, *change, "gating")

    def on_estimate(self, update: EstimateUpdate) -> None:
        self._require_started()
        data = results_codec.encode_estimate(update.time_s, update.rpm, update.estimate)
        self._add(TOPIC_ESTIMATE, update.time_s, data, "result")

    def write_view(self, topic: str, t: float, data: bytes) -> None:
        """A message on one of the Foxglove view topics (``replay.foxglove.TOPICS``) at stream
        time ``t`` (s): what a scene sink running beside the recorder draws."""
        if topic not in foxglove.TOPICS:
            known = ", ".join(foxglove.TOPICS)
            raise ValueError(f"write_view: {topic} is not a view topic ({known})")
        self._require_started()
        self._add(topic, t, bytes(data), "result")  # (free for bytes: the data must not change)

    def _log_event(self, event: SourceEvent, origin: str, t: float) -> None:
        repeat = f" (x{event.count})" if event.count > 1 else ""
        level = "info" if event.kind in foxglove.INFO_EVENTS else "warning"
        self._log(t, level, f"{event.kind}: {event.message}{repeat}", origin)

    def _log(self, t: float, level: str, message: str, name: str) -> None:
        t = t if math.isfinite(t) else self._t_last
        t_ns = max(0, self._origin_ns + round(t * 1e9))
        self._add(foxglove.TOPIC_LOG, t, foxglove.log_line(t_ns, level, message, name), "result")

    def on_backlog(self, seconds: float) -> None:
        """Not recorded: the backlog says how the live run kept up, not what it measured."""

    def on_can_frames(self, frames: Sequence[RawFrame]) -> None:
        """A batch of raw CAN frames (``acquisition.can.frames.RawFrame``) as received.

        Pass this method as the CAN source's ``frame_listener``: it is called on
        the acquisition thread, and it is safe to.
        """
        if not frames or self._writer is None:
            return
        t = self._t_last  # frames carry host/log clock times; stream time is what we know
        # a late batch after close (the acquisition thread stops last) is dropped, not an error
        self._add(TOPIC_CAN, t, stream_codec.encode_can(frames, t), "raw", late_ok=True)

    # -- internals ------------------------------------------------------------------------
    def _require_started(self) -> StreamLayout:
        if self._layout is None or self._writer is None:
            raise RuntimeError("McapRecorder: start() must come before the first message")
        if self._closed:
            raise RuntimeError("McapRecorder: message after close()")
        return self._layout

    def _add(self, topic: str, t: float, data: Payload, kind: str, late_ok: bool = False) -> None:
        with self._lock:
            if self._closed:
                if late_ok:
                    return
                raise RuntimeError("McapRecorder: message after close()")
            self._add_locked(topic, t, data, kind)

    def _add_locked(self, topic: str, t: float, data: Payload, kind: str) -> None:
        """File a message in its stream-time chunk; write the chunks that are complete.

        ``kind`` is ``"raw"`` (the stream, kept in its order) or ``"result"``. (Comparisons,
        not max(): 6554 messages a minute pass here.)
        """
        t_last, origin = self._t_last, self._origin_ns
        if not math.isfinite(t):
            t = t_last
        elif t > t_last:
            self._t_last = t_last = t
        log_time = max(0, origin + round(t * 1e9))
        publish_time = origin + round(t_last * 1e9)
        publish_time = publish_time if publish_time > log_time else log_time
        self.stats.messages[topic] += 1
        self.stats.payload_bytes[topic] += len(data)
        message = (self._channels[topic], log_time, data, publish_time)
        if ready := self._chunker.add(kind, log_time - origin, message):
            self._write_chunks(ready)

    def _write_chunks(self, chunks: list[list[Pending]]) -> None:
        """Hand complete chunks to the writer, which compresses and writes them on its thread."""
        assert self._writer is not None
        for chunk in chunks:
            try:
                self._writer.add_chunk(chunk)  # raises what the writer thread met, if anything
            except OSError as err:
                raise self._write_error(err) from err
        if chunks:
            self.stats.chunks = self._writer.chunks

    def flush(self) -> None:
        """Write every open chunk and wait until everything is in the file, flushed to the OS."""
        with self._lock:
            if self._writer is not None and not self._closed:
                self._write_chunks(self._chunker.drain())
                try:
                    self._writer.sync()
                except OSError as err:
                    raise self._write_error(err) from err

    def _abandon(self) -> None:
        """Stop the writer and close the file as it stands (after a failure)."""
        assert self._writer is not None and self._file is not None
        self._closed = True
        self._writer.stop()
        _discard(self._file)

    def _write_error(self, err: OSError) -> LogError:
        self._failed = True
        cut = self._writer is not None and self._writer.cut_end_ns() is not None
        kept = "; the recording is closed readable after its last complete chunk" if cut else ""
        return LogError(f"cannot write the recording {self.path}: {err.strerror or err}{kept}")

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close(None)
