"""Open a recording, finished or not, and read its raw stream and recorded results.

A finished log (footer and summary present) is read with the mcap seeking
reader; a log whose writer died (SIGKILL, power cut, full disk) has no footer,
which the seeking reader refuses, so it is read front to back with the
non-seeking reader in file order (``log_time_order=False``) until the
truncation point: every closed chunk is recovered, the unfinished one is not.
Either way messages come back in the order they were written, which for the
raw topics is the order the live dsp stage saw them.

A message that does not fit (unknown topic, wrong schema, a block that
disagrees with the recorded layout) is skipped and counted in
:class:`ReadReport`; a file that cannot be a replayable recording at all
raises :class:`replay.errors.LogError` with one line saying why.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import NonSeekingReader, SeekingReader
from mcap.records import Attachment, Channel, Metadata, Schema

from acquisition.stream import StreamItem, StreamLayout
from estimator.result import EstimateUpdate
from replay import results_codec, stream_codec
from replay.chunks import (
    MAGIC,
    chunk_payload,
    chunk_records,
    chunk_times,
    parse_definition,
    read_at,
    records,
    walk_messages,
)
from replay.chunks import READ_ERRORS as _READ_ERRORS
from replay.errors import BadMessage, LogError
from replay.schemas import (
    BENCH_ATTACHMENT,
    FORMAT,
    META_END,
    META_RUN,
    SCHEMA_VERSION,
    TOPIC_CAN,
    TOPIC_ESTIMATE,
    TOPIC_EVENTS,
    TOPIC_GATING,
    TOPIC_ORDERS,
    edge_topic,
    full_name,
    raw_topic,
)


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
    """

    finished: bool
    file_bytes: int
    readable_bytes: int
    chunks: int = 0
    recorded_until_s: float | None = None
    skipped: Counter[str] = field(default_factory=Counter)
    notes: list[str] = field(default_factory=list)

    def note(self, line: str) -> None:
        if line not in self.notes:
            self.notes.append(line)

    def lines(self) -> list[str]:
        """Everything the user should hear about, one line each."""
        out = list(self.notes)
        for topic, n in sorted(self.skipped.items()):
            out.append(f"skipped {n} message(s) on {topic}")
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

    @property
    def finished(self) -> bool:
        return self.report.finished

    @property
    def raw_topics(self) -> dict[str, str]:
        """Raw topic -> message type, from the layout."""
        out = {raw_topic(g.name): "SampleBlock" for g in self.layout.groups}
        out.update({edge_topic(c): "EdgeBlock" for c in self.layout.edge_channels})
        out[TOPIC_EVENTS] = "SourceEvent"
        return out

    # -- iteration ------------------------------------------------------------------------
    def messages(
        self, topics: Iterable[str], reference: bool = False
    ) -> Iterator[tuple[str, str, int, bytes]]:
        """``(topic, schema name, log_time ns, data)`` of ``topics``, in file order.

        Stops cleanly at the truncation point of an unfinished log (already
        noted in :attr:`report` by :func:`open_log`); a finished log that
        fails to read raises :class:`LogError`. ``reference=True`` reads with
        the mcap library's own readers (seeking for a finished log,
        non-seeking for an unfinished one) instead of :mod:`replay.chunks`:
        slower, same messages.
        """
        wanted = {t for t in topics if t in self.topics}

        def stop(err: BaseException) -> None:
            if self.report.finished:
                raise LogError(f"{self.path}: damaged recording ({_describe(err)})")
            # the unfinished chunk of a killed writer: expected

        source = (
            self._reference(wanted, stop) if reference else walk_messages(self.path, wanted, stop)
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
                except _READ_ERRORS as err:
                    stop(err)
                    return
                name = schema.name if schema is not None else ""
                yield channel.topic, name, message.log_time, message.data

    def items(self) -> Iterator[StreamItem]:
        """The raw stream (sample blocks, edge blocks, source events) in its original order."""
        kinds = self.raw_topics
        for topic, name, _, data in self.messages(kinds):
            try:
                if name == full_name("SampleBlock"):
                    yield stream_codec.decode_samples(data, self.layout)
                elif name == full_name("EdgeBlock"):
                    yield stream_codec.decode_edges(data, self.layout)
                else:
                    origin, event = stream_codec.decode_event(data)
                    if origin != "dsp":
                        yield event
            except (BadMessage, ValueError) as err:
                self.report.skipped[topic] += 1
                self.report.note(f"{topic}: {err}")

    def frames(self) -> Iterator[Any]:
        """The recorded order frames (``dsp.frames.OrderFrame``)."""
        yield from self._decoded(TOPIC_ORDERS, results_codec.decode_frame)

    def outcomes(self) -> Iterator[Any]:
        """The recorded gating decisions (``estimator.streaming.FrameOutcome``, no motion)."""
        yield from self._decoded(TOPIC_GATING, results_codec.decode_outcome)

    def estimates(self) -> Iterator[EstimateUpdate]:
        """The estimate after each used frame, as :class:`estimator.result.EstimateUpdate`."""
        for time_s, rpm, estimate, final in self._decoded(
            TOPIC_ESTIMATE, results_codec.decode_estimate
        ):
            if not final:
                yield EstimateUpdate(time_s, rpm, estimate)

    def can_frames(self) -> Iterator[list[Any]]:
        """The raw CAN frames as received, in batches of ``acquisition.can.frames.RawFrame``.

        Empty unless the source was a CAN bus. ``CanFrameSource(plan, log.can_frames())``
        decodes them again (with the recorded DBC, ``attachments``, or a new one).
        """
        yield from self._decoded(TOPIC_CAN, stream_codec.decode_can)

    def events(self) -> Iterator[tuple[str, Any]]:
        """Every recorded event as ``(origin, SourceEvent)``; origin ``source`` or ``dsp``."""
        yield from self._decoded(TOPIC_EVENTS, stream_codec.decode_event)

    def _decoded(self, topic: str, decode: Any) -> Iterator[Any]:
        for _, _, _, data in self.messages([topic]):
            try:
                yield decode(data)
            except (BadMessage, ValueError) as err:
                self.report.skipped[topic] += 1
                self.report.note(f"{topic}: {err}")

    def final_estimate(self) -> Any:
        """The run's final ``estimator.result.Estimate`` (None if the run was cut short or had none).

        It differs from the last update when frames were rejected after the last used one.
        """
        for _, _, estimate, final in self._decoded(TOPIC_ESTIMATE, results_codec.decode_estimate):
            if final:
                return estimate
        return None


def _describe(err: BaseException) -> str:
    text = str(err).strip()
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


def find_logs(path: str | Path) -> list[Path]:
    """The recordings to replay: ``path`` itself, or the ``*.mcap`` files of a directory (sorted)."""
    path = Path(path)
    if path.is_dir():
        logs = sorted(p for p in path.iterdir() if p.suffix.lower() == ".mcap" and p.is_file())
        if not logs:
            raise LogError(f"{path}: no .mcap files in this directory")
        return logs
    return [path]


# -- opening -------------------------------------------------------------------------------------


@dataclass
class _Scan:
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[str, int] | None = None
    chunks: int = 0
    last_log_time: int | None = None
    readable: int = 0
    data_end: bool = False  # the data section was complete
    error: str | None = None


def open_log(path: str | Path) -> RecordedLog:
    """Open a recording; raises :class:`LogError` when nothing replayable is in it.

    Parameters
    ----------
    path : an ``.mcap`` file written by :class:`replay.recorder.McapRecorder`
        (or ``record_source``), finished or cut short.
    """
    path = Path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file")
    if path.is_dir():
        raise LogError(f"{path}: is a directory (replay a directory with find_logs)")
    size = path.stat().st_size
    if size == 0:
        raise LogError(f"{path}: empty file (0 bytes)")
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
        if head != MAGIC[: len(head)] or len(head) < len(MAGIC):
            if head == MAGIC[: len(head)]:
                raise LogError(f"{path}: truncated before any data ({size} bytes)")
            raise LogError(f"{path}: not an MCAP file (starts with {head[:8]!r})")
        fh.seek(max(0, size - len(MAGIC)))
        finished = fh.read(len(MAGIC)) == MAGIC and size > 2 * len(MAGIC)
    scan: _Scan | None = None
    report = ReadReport(finished=False, file_bytes=size, readable_bytes=0)
    if finished:
        try:
            scan = _scan_finished(path)
            report.finished = True
            report.readable_bytes = size
        except _READ_ERRORS as err:
            report.note(f"footer or summary damaged ({_describe(err)}): reading front to back")
            scan = None
    if scan is None:
        scan = _scan_stream(path)
        report.readable_bytes = scan.readable
        if scan.chunks == 0:
            raise LogError(
                f"{path}: truncated before any data ({size} bytes, no complete chunk"
                + (f"; {scan.error}" if scan.error else "")
                + ")"
            )
    report.chunks = scan.chunks
    log = _build(path, scan, report)
    if not report.finished:
        until = report.recorded_until_s
        where = f" up to t = {until:.2f} s" if until is not None else ""
        if scan.data_end:
            tail = "the writer stopped while finishing the file: no data lost"
        else:
            lost = size - scan.readable
            tail = f"the last {lost} byte(s), the chunk being written, are lost"
        report.note(
            f"unfinished recording (no footer): recovered {scan.chunks} chunk(s){where}; {tail}"
        )
    return log


def _scan_finished(path: Path) -> _Scan:
    scan = _Scan()
    with open(path, "rb") as fh:
        reader = SeekingReader(fh)
        summary = reader.get_summary()
        if summary is None:
            raise McapError("no summary section")
        scan.schemas = dict(summary.schemas)
        scan.channels = dict(summary.channels)
        scan.chunks = len(summary.chunk_indexes)
        if summary.chunk_indexes:
            scan.last_log_time = max(c.message_end_time for c in summary.chunk_indexes)
        if summary.statistics is not None:
            counts = summary.statistics.channel_message_counts
            scan.counts = {ch.topic: int(counts.get(cid, 0)) for cid, ch in scan.channels.items()}
        for meta in reader.iter_metadata():
            scan.metadata[meta.name] = dict(meta.metadata)
        for att in reader.iter_attachments():
            scan.attachments[att.name] = bytes(att.data)
    return scan


def _scan_stream(path: str | Path) -> _Scan:
    """Walk the records of an unfinished file, reading only metadata, attachments and the first chunk.

    A chunk is complete when its declared length fits in the file (see
    :func:`replay.chunks.records`), so the scan seeks past chunk contents.
    """
    scan = _Scan()
    with open(path, "rb") as fh:
        try:
            for opcode, offset, length in records(fh):
                if opcode == Opcode.CHUNK:
                    if not scan.channels:
                        payload = chunk_payload(read_at(fh, offset, length))
                        for op, content in chunk_records(payload):
                            if op in (Opcode.SCHEMA, Opcode.CHANNEL):
                                _define(scan, parse_definition(op, content))
                    scan.chunks += 1
                    scan.last_log_time = chunk_times(fh, offset)[1]
                elif opcode in (Opcode.METADATA, Opcode.ATTACHMENT):
                    stream = ReadDataStream(BytesIO(read_at(fh, offset, length)))
                    if opcode == Opcode.METADATA:
                        meta = Metadata.read(stream)
                        scan.metadata[meta.name] = dict(meta.metadata)
                    else:
                        att = Attachment.read(stream)
                        scan.attachments[att.name] = bytes(att.data)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    _define(scan, parse_definition(opcode, read_at(fh, offset, length)))
                scan.readable = offset + length
                if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    scan.data_end = True
                    break
        except _READ_ERRORS as err:
            scan.error = _describe(err)
    return scan


def _define(scan: _Scan, record: Schema | Channel) -> None:
    if isinstance(record, Schema):
        scan.schemas[record.id] = record
    else:
        scan.channels[record.id] = record


def _build(path: Path, scan: _Scan, report: ReadReport) -> RecordedLog:
    run = scan.metadata.get(META_RUN)
    if run is None or run.get("format") != FORMAT:
        found = ", ".join(sorted(scan.metadata)) or "none"
        raise LogError(
            f"{path}: not a ptinertia recording (no '{META_RUN}' metadata with format "
            f"'{FORMAT}'; metadata records: {found})"
        )
    try:
        version = int(run.get("schema_version", "0"))
    except ValueError:
        version = -1
    if not 1 <= version <= SCHEMA_VERSION:
        raise LogError(
            f"{path}: recording schema version {run.get('schema_version')!r}; this ptinertia "
            f"reads versions 1 to {SCHEMA_VERSION}"
        )
    try:
        layout = stream_codec.layout_from_json(run["layout"])
        settings = json.loads(run.get("settings") or "{}")
        truth = json.loads(run.get("truth") or "null")
        origin = int(run.get("time_origin_ns", "0"))
    except (KeyError, ValueError, TypeError) as err:
        raise LogError(f"{path}: unreadable run metadata ({_describe(err)})") from None

    topics: dict[str, str] = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        topics[channel.topic] = schema.name if schema is not None else ""
        del cid
    expected = {raw_topic(g.name): "SampleBlock" for g in layout.groups}
    expected.update({edge_topic(c): "EdgeBlock" for c in layout.edge_channels})
    expected[TOPIC_EVENTS] = "SourceEvent"
    missing = [t for t in expected if t not in topics]
    wrong = [t for t, kind in expected.items() if t in topics and topics[t] != full_name(kind)]
    if missing or wrong:
        what = [f"missing {t}" for t in missing] + [
            f"{t} has schema {topics[t]!r}, expected {full_name(expected[t])!r}" for t in wrong
        ]
        raise LogError(f"{path}: raw topics do not match the recorded layout: {'; '.join(what)}")
    known = {
        **expected,
        TOPIC_ORDERS: "OrderFrame",
        TOPIC_GATING: "Gating",
        TOPIC_ESTIMATE: "Estimate",
        TOPIC_CAN: "CanFrames",
    }
    for topic, name in topics.items():
        if topic not in known:
            report.note(f"unknown topic {topic} ({name or 'no schema'}): ignored")
        elif name != full_name(known[topic]):
            report.note(
                f"{topic} has schema {name!r}, expected {full_name(known[topic])!r}: ignored"
            )
    topics = {t: n for t, n in topics.items() if t in known and n == full_name(known[t])}
    if scan.last_log_time is not None:
        report.recorded_until_s = (scan.last_log_time - origin) / 1e9

    result = None
    end = scan.metadata.get(META_END)
    if end is not None:
        try:
            result = json.loads(end.get("result") or "null")
        except ValueError:
            report.note(f"unreadable '{META_END}' metadata: final result ignored")
    bench = scan.attachments.get(BENCH_ATTACHMENT)
    return RecordedLog(
        path=path,
        bench_text=bench.decode("utf-8", errors="replace") if bench is not None else None,
        attachments=scan.attachments,
        metadata=scan.metadata,
        truth=truth,
        settings=settings,
        layout=layout,
        source=run.get("source", ""),
        time_origin_ns=origin,
        result=result,
        topics=topics,
        message_counts=scan.counts,
        report=report,
    )
