"""A recording opened for reading: what it holds, and its messages decoded.

:func:`replay.reader.open_log` scans the file once and returns a
:class:`RecordedLog` (bench, layout, settings, truth, the topics found) with a
:class:`ReadReport` of what was recovered and skipped. Its iterators then walk
the messages in file order, which for the raw topics is the order the live dsp
stage saw them, and stop cleanly at the truncation point of an unfinished log.
A message that does not fit (wrong schema, a block that disagrees with the
recorded layout) is skipped and counted in the report.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from google.protobuf.message import DecodeError
from mcap.reader import NonSeekingReader, SeekingReader

from acquisition.can.frames import RawFrame
from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from dsp.frames import OrderFrame
from estimator.outcome import FrameOutcome
from estimator.result import Estimate, EstimateUpdate
from replay import results_codec, stream_codec
from replay.chunks import READ_ERRORS, Skipped, walk_messages
from replay.errors import BadMessage, LogError, describe
from replay.integrity import DataCheck
from replay.raw_decoder import RawDecoder
from replay.schemas import (
    TOPIC_CAN,
    TOPIC_ESTIMATE,
    TOPIC_EVENTS,
    TOPIC_GATING,
    TOPIC_ORDERS,
    full_name,
    stream_topics,
)

# What decoding one recorded message can raise: the message is skipped and counted.
DECODE_ERRORS = (BadMessage, ValueError, DecodeError)


@dataclass
class ReadReport:
    """What was recovered and what was skipped.

    Attributes
    ----------
    finished : the writer finished the file (footer present).
    file_bytes : size of the file.
    readable_bytes : bytes up to the end of the last complete record.
    chunks : complete chunks found.
    recorded_until_s : stream time of the last message of the last complete chunk.
    skipped : messages skipped per topic (unknown topic, wrong schema, bad content).
    notes : one line per problem, for the user.
    damaged : damaged chunks or records skipped, by byte offset.
    data_complete : the file is unfinished but its data section is whole.
    time_origin_ns : log time of stream time 0 (for the times of what was skipped).
    """

    finished: bool
    file_bytes: int
    readable_bytes: int
    chunks: int = 0
    recorded_until_s: float | None = None
    skipped: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)
    damaged: dict[int, Skipped] = field(default_factory=dict)  # byte offset -> what was skipped
    data_complete: bool = False  # an unfinished file whose data section is whole
    time_origin_ns: int = 0

    def note(self, line: str) -> None:
        if line not in self.notes:
            self.notes.append(line)

    def skip(self, skipped: Skipped) -> None:
        """A damaged chunk or record, skipped (each walk over the file finds it again)."""
        known = self.damaged.setdefault(skipped.offset, skipped)
        if known is not skipped and known.before_ns is None:
            self.damaged[skipped.offset] = skipped  # this walk may get further

    def span_s(self, skipped: Skipped) -> tuple[float | None, float | None]:
        """Stream times (s) of the messages read just before and just after ``skipped``."""
        after, before = skipped.after_ns, skipped.before_ns
        return (
            None if after is None else (after - self.time_origin_ns) / 1e9,
            None if before is None else (before - self.time_origin_ns) / 1e9,
        )

    def lines(self) -> list[str]:
        """Everything the user should hear about, one line each."""
        out = list(self.notes)
        if self.damaged:
            spans = []
            for skipped in self.damaged.values():
                lo, hi = self.span_s(skipped)
                where = (
                    f"t = {'start' if lo is None else f'{lo:.2f}'}"
                    f"-{'end' if hi is None else f'{hi:.2f}'} s"
                )
                spans.append(f"{where} ({skipped.reason}, byte {skipped.offset})")
            out.append(f"skipped {len(spans)} damaged chunk(s): " + "; ".join(spans))
        for topic, n in sorted(self.skipped.items()):
            out.append(f"skipped {n} message(s) on {topic}")
        return out

    def skipped_document(self) -> list[dict[str, Any]]:
        """What was not read, for the result document (``recording_skipped``).

        One entry per damaged chunk (``damaged``, the stream times around it),
        one for the lost tail of an unfinished recording (``truncated``), one
        per topic with messages that could not be decoded (``messages``).
        """
        out: list[dict[str, Any]] = []
        for skipped in self.damaged.values():
            lo, hi = self.span_s(skipped)
            out.append(
                {
                    "kind": "damaged",
                    "from_s": lo,
                    "to_s": hi,
                    "byte": skipped.offset,
                    "reason": skipped.reason,
                }
            )
        if not (self.finished or self.data_complete) and self.readable_bytes < self.file_bytes:
            out.append(
                {
                    "kind": "truncated",
                    "from_s": self.recorded_until_s,
                    "to_s": None,
                    "byte": self.readable_bytes,
                    "reason": f"{self.file_bytes - self.readable_bytes} byte(s) after the last "
                    "complete record not read",
                }
            )
        for topic, n in sorted(self.skipped.items()):
            out.append({"kind": "messages", "topic": topic, "count": n})
        return out


@dataclass(frozen=True)
class RecordedLog:
    """A recording opened for reading.

    Attributes
    ----------
    path : the file.
    bench_text : the bench file as recorded (None if the log has none).
    attachments : every attachment, name -> bytes (``bench.toml``, a DBC ...).
    metadata : every metadata record, name -> {key: value}.
    truth : the simulated truth, or None for real data.
    settings : the dsp/estimator settings of the live run (empty for a raw-only log).
    layout : the recorded source's channels and rates.
    source : the source spec of the live run.
    time_origin_ns : log time of stream time 0.
    result : the final result document of the live run (finished logs of a run only).
    topics : topic -> schema name, as found.
    message_counts : topic -> messages (finished logs only; None otherwise).
    report : what was recovered and skipped (updated while iterating).
    channels : channel id -> (topic, schema name), as the scan found them.
    chunk_records : (byte offset, length) of each chunk record, from the
        checked summary of a finished log (None: read front to back).
    data_verified : the data section's CRC matched when the log was opened, which
        vouches for every chunk (the walk skips their CRCs).
    data_check : the same check still running (``open_log(check_later=True)``);
        :meth:`verify` waits for it.
    """

    path: Path
    bench_text: str | None
    attachments: dict[str, bytes]
    metadata: dict[str, dict[str, str]]
    truth: Any
    settings: dict[str, Any]
    layout: StreamLayout
    source: str
    time_origin_ns: int
    result: dict[str, Any] | None
    topics: dict[str, str]
    message_counts: dict[str, int] | None
    report: ReadReport
    channels: dict[int, tuple[str, str]] = field(default_factory=dict)
    chunk_records: list[tuple[int, int]] | None = None
    data_verified: bool = False
    data_check: DataCheck | None = None

    @property
    def finished(self) -> bool:
        return self.report.finished

    @property
    def raw_topics(self) -> dict[str, str]:
        """Raw topic -> message type, from the layout."""
        return stream_topics(self.layout)

    def verify(self) -> bool:
        """Whether the data section's CRC matched; raises :class:`LogError` when it failed
        and no damaged chunk explains it (waits for a check still running)."""
        return self.data_check.result() if self.data_check is not None else self.data_verified

    # -- iteration ------------------------------------------------------------------------
    def messages(
        self, topics: Iterable[str], reference: bool = False, views: bool = False
    ) -> Iterator[tuple[str, str, int, Any]]:
        """``(topic, schema name, log_time ns, data)`` of ``topics``, in file order.

        Stops cleanly at the truncation point of an unfinished log (already
        noted in :attr:`report` by :func:`replay.reader.open_log`); a finished log that
        fails to read raises :class:`LogError`. ``reference=True`` reads with
        the mcap library's own readers (seeking for a finished log,
        non-seeking for an unfinished one) instead of :mod:`replay.chunks`:
        slower, same messages. ``views=True``: the data as memoryviews of the chunks
        (:class:`replay.chunks.MessageWalk`), not bytes.
        """
        wanted = {t for t in topics if t in self.topics}
        verified = self.verify()

        def stop(err: BaseException) -> None:
            if self.report.finished:
                raise LogError(f"{self.path}: damaged recording ({describe(err)})")
            # the unfinished chunk of a killed writer: expected

        source = (
            self._reference(wanted, stop)
            if reference
            else walk_messages(
                self.path,
                wanted,
                stop,
                self.report.skip,
                self.chunk_records,
                self.channels,
                check_crcs=not verified,
                views=views,
            )
        )
        for topic, name, log_time, data in source:
            if name != self.topics.get(topic):
                self.report.skipped[topic] += 1
                continue
            yield topic, name, log_time, data

    def _reference(self, wanted: set[str], stop: Any) -> Iterator[tuple[str, str, int, bytes]]:
        with open(self.path, "rb") as fh:
            reader: Any = SeekingReader(fh) if self.report.finished else NonSeekingReader(fh)
            it = reader.iter_messages(topics=sorted(wanted), log_time_order=False)
            while True:
                try:
                    schema, channel, message = next(it)
                except StopIteration:
                    return
                except READ_ERRORS as err:
                    stop(err)
                    return
                name = schema.name if schema is not None else ""
                yield channel.topic, name, message.log_time, message.data

    def items(self) -> Iterator[StreamItem]:
        """The raw stream (sample blocks, edge blocks, source events) in its original order."""
        decoder = RawDecoder(self.layout)
        sample_block, edge_block = full_name("SampleBlock"), full_name("EdgeBlock")
        for topic, name, _, data in self.messages(self.raw_topics, views=True):
            try:
                if name == sample_block:
                    yield decoder.samples(data)
                elif name == edge_block:
                    yield decoder.edges(data)
                else:
                    origin, event = stream_codec.decode_event(data)
                    if origin != "dsp":
                        yield event
            except DECODE_ERRORS as err:
                self.report.skipped[topic] += 1
                self.report.note(f"{topic}: {err}")

    def frames(self) -> Iterator[OrderFrame]:
        """The recorded order frames (``dsp.frames.OrderFrame``)."""
        yield from self._decoded(TOPIC_ORDERS, results_codec.decode_frame)

    def outcomes(self) -> Iterator[FrameOutcome]:
        """The recorded gating decisions (``estimator.streaming.FrameOutcome``, no motion)."""
        yield from self._decoded(TOPIC_GATING, results_codec.decode_outcome)

    def estimates(self) -> Iterator[EstimateUpdate]:
        """The estimate after each used frame, as :class:`estimator.result.EstimateUpdate`."""
        for time_s, rpm, estimate, final in self._decoded(
            TOPIC_ESTIMATE, results_codec.decode_estimate
        ):
            if not final:
                yield EstimateUpdate(time_s, rpm, estimate)

    def can_frames(self) -> Iterator[list[RawFrame]]:
        """The raw CAN frames as received, in batches of ``acquisition.can.frames.RawFrame``.

        Empty unless the source was a CAN bus. ``CanFrameSource(plan, log.can_frames())``
        decodes them again (with the recorded DBC, ``attachments``, or a new one).
        """
        yield from self._decoded(TOPIC_CAN, stream_codec.decode_can)

    def events(self) -> Iterator[tuple[str, SourceEvent]]:
        """Every recorded event as ``(origin, SourceEvent)``; origin ``source`` or ``dsp``."""
        yield from self._decoded(TOPIC_EVENTS, stream_codec.decode_event)

    def _decoded(self, topic: str, decode: Callable[[bytes], Any]) -> Iterator[Any]:
        for _, _, _, data in self.messages([topic]):
            try:
                yield decode(data)
            except DECODE_ERRORS as err:
                self.report.skipped[topic] += 1
                self.report.note(f"{topic}: {err}")

    def final_estimate(self) -> Estimate | None:
        """The run's final ``estimator.result.Estimate`` (None if the run was cut short or had none).

        It differs from the last update when frames were rejected after the last used one.
        """
        for _, _, estimate, final in self._decoded(TOPIC_ESTIMATE, results_codec.decode_estimate):
            if final:
                return estimate
        return None
