"""Record a run to MCAP: raw stream, order frames, gating, estimates, bench and truth.

One channel per topic (see ``docs/recording-format.md``):

* ``/raw/<group>`` (SampleBlock), ``/raw/edges/<channel>`` (EdgeBlock), and the
  source's events on ``/events`` with ``origin = "source"``: the raw stream,
  in the order the dsp stage saw it, which is all a replay needs;
* ``/raw/can`` (CanFrames): the CAN frames as received, when the source is a
  CAN bus (:meth:`McapRecorder.on_can_frames` as its ``frame_listener``);
* ``/orders`` (OrderFrame), ``/gating`` (Gating), ``/estimate`` (Estimate), and
  ``/events`` with ``origin = "dsp"``: what the live run computed from it.

Log times are ``time_origin_ns`` (the wall clock at ``start``, kept in the
metadata) plus the stream time, so Foxglove shows the run at its real date
and replays it at its real pace; publish times are the wall clock when the
message was written.

Crash safety. The file is written in place from the start: header,
metadata (layout, settings, truth, version, source) and attachments (bench
file, DBC) first (:mod:`replay.recording_head`), then ZSTD-compressed chunks. A chunk is closed as soon as
it spans ``chunk_s`` (0.5 s) of stream time or of wall time, whichever comes
first, and is in the file, flushed to the OS, a few milliseconds later, so a
process killed with SIGKILL loses at most the open chunk: 0.5 s of data plus
the item that was being written. (The wall-time bound is checked when a
message arrives; a stalled stream adds nothing to lose.) The page cache
survives the process, so there is no fsync: a power cut is a different
matter.

Cost to the processing thread. Chunks are compressed and written by
:class:`replay.mcapwriter.ThreadedWriter` on its own thread (compression
releases the GIL), and order frames and sample blocks are encoded without
the protobuf classes (:mod:`replay.wire`): the hooks take about 0.16 s of
the caller's CPU per minute of a 10-channel 25.6 kHz stream with one order
frame per revolution at 3000 rpm (``benchmarks/bench_mcap.py``), a third of
what they took with ``mcap.writer.Writer`` inline.

A source's raw stream alone (``ptinertia simulate --out x.mcap``) is written
through the same recorder by :mod:`replay.raw_writer`.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from acquisition.can.frames import RawFrame
from acquisition.stream import EdgeBlock, SampleBlock, SourceEvent, StreamItem, StreamLayout
from dsp.frames import OrderFrame
from estimator.result import Estimate, EstimateUpdate
from estimator.streaming import FrameOutcome
from replay import results_codec, stream_codec
from replay.errors import LogError
from replay.mcap_output import check_level
from replay.mcapwriter import ThreadedWriter
from replay.recording_head import check_topics, ptinertia_version, write_head
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

CHUNK_S = 0.5
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
    try:
        fh.close()
    except OSError:
        pass


class McapRecorder:
    """A sink of the pipeline writing everything it is told to an MCAP file.

    It has every hook of the app's ``Sink`` protocol (``start``, ``on_item``,
    ``on_frame``, ``on_estimate``, ``on_event``, ``on_backlog``, ``close``),
    so the app takes it as one; replay does not import the app.

    Parameters
    ----------
    path : str or Path
        Output file, written in place (a killed run leaves a readable prefix).
    chunk_s : float
        Longest span of a chunk, s of stream time and of wall time.
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
        self._chunk_wall: float | None = None  # monotonic time of the open chunk's first message
        self._chunk_t0 = 0.0  # stream time of the open chunk's first message
        self._last_source_event: SourceEvent | None = None
        self._closed = False
        # on_can_frames comes from the acquisition thread, everything else from the
        # processing thread: one lock around the writer
        self._lock = threading.Lock()

    # -- lifecycle ------------------------------------------------------------------------
    def start(self, context: Any) -> None:
        """Open the file; write header, metadata, attachments and the channels."""
        layout: StreamLayout = context.layout
        self._layout = layout
        check_topics(layout)
        try:
            self._file = open(self.path, "wb")  # closed in close()
        except OSError as err:
            raise LogError(f"cannot write the recording {self.path}: {err.strerror}") from None
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
            writer.stop()
            _discard(self._file)
            self._closed = True
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
        try:
            try:
                if final is not None:
                    # the final estimate also counts the frames rejected after the last used one
                    data = results_codec.encode_estimate(self._t_last, math.nan, final, final=True)
                    self._add_locked(TOPIC_ESTIMATE, self._t_last, data)
                end = {
                    "status": "finished",
                    "closed_utc": datetime.now(UTC).isoformat(timespec="seconds"),
                    "messages": json.dumps(dict(self.stats.messages)),
                    "result": json.dumps(final.to_json() if final is not None else None),
                }
                self._writer.add_metadata(META_END, end)
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
            self._add(raw_topic(item.group), t, stream_codec.encode_samples(item, group))
        elif isinstance(item, EdgeBlock):
            t = float(item.times_s[0]) if len(item.times_s) else self._t_last
            self._add(edge_topic(item.channel), t, stream_codec.encode_edges(item, t))
        elif isinstance(item, SourceEvent):
            self._last_source_event = item
            t = self._t_last if item.time_s is None else item.time_s
            self._add(TOPIC_EVENTS, t, stream_codec.encode_event(item, "source", t))
        else:
            raise TypeError(f"not a stream item: {type(item).__name__}")

    def on_event(self, event: SourceEvent) -> None:
        # The pipeline reports a source's own events twice (as an item, then as an
        # event); the item is the one that belongs to the raw stream.
        if event is self._last_source_event:
            return
        self._require_started()
        t = self._t_last if event.time_s is None else event.time_s
        self._add(TOPIC_EVENTS, t, stream_codec.encode_event(event, "dsp", t))

    def on_frame(self, frame: OrderFrame, outcome: FrameOutcome) -> None:
        self._require_started()
        self._add(TOPIC_ORDERS, frame.time_s, results_codec.encode_frame(frame))
        self._add(TOPIC_GATING, outcome.time_s, results_codec.encode_outcome(outcome))

    def on_estimate(self, update: EstimateUpdate) -> None:
        self._require_started()
        data = results_codec.encode_estimate(update.time_s, update.rpm, update.estimate)
        self._add(TOPIC_ESTIMATE, update.time_s, data)

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
        self._add(TOPIC_CAN, t, stream_codec.encode_can(frames, t), late_ok=True)

    # -- internals ------------------------------------------------------------------------
    def _require_started(self) -> StreamLayout:
        if self._layout is None or self._writer is None:
            raise RuntimeError("McapRecorder: start() must come before the first message")
        if self._closed:
            raise RuntimeError("McapRecorder: message after close()")
        return self._layout

    def _add(self, topic: str, t: float, data: bytes, late_ok: bool = False) -> None:
        with self._lock:
            if self._closed:
                if late_ok:
                    return
                raise RuntimeError("McapRecorder: message after close()")
            self._add_locked(topic, t, data)

    def _add_locked(self, topic: str, t: float, data: bytes) -> None:
        assert self._writer is not None
        if not math.isfinite(t):
            t = self._t_last
        self._t_last = max(self._t_last, t)
        log_time = max(0, self._origin_ns + round(t * 1e9))
        self._writer.add_message(self._channels[topic], log_time, data, time.time_ns())
        self.stats.messages[topic] += 1
        self.stats.payload_bytes[topic] += len(data)
        wall = self._monotonic()
        if self._chunk_wall is None:
            self._chunk_wall, self._chunk_t0 = wall, t
        elif wall - self._chunk_wall >= self.chunk_s or t - self._chunk_t0 >= self.chunk_s:
            self._flush_locked()

    def flush(self) -> None:
        """Close the open chunk and wait until everything is in the file, flushed to the OS."""
        with self._lock:
            self._flush_locked()
            if self._writer is not None and not self._closed:
                try:
                    self._writer.sync()
                except OSError as err:
                    raise self._write_error(err) from err

    def _flush_locked(self) -> None:
        """Close the open chunk; the writer thread compresses and writes it."""
        if self._writer is not None and not self._closed and self._chunk_wall is not None:
            self._chunk_wall = None
            try:
                self._writer.flush()  # raises what the writer thread met, if anything
            except OSError as err:
                raise self._write_error(err) from err
            self.stats.chunks = self._writer.chunks

    def _write_error(self, err: OSError) -> LogError:
        return LogError(f"cannot write the recording {self.path}: {err.strerror or err}")

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close(None)
