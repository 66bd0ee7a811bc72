"""Open a recording, finished or not: scan it once, check it is replayable, build its log.

A finished log (footer and summary present) is read through its summary
(:mod:`replay.summary`); a log whose writer died (SIGKILL, power cut, full
disk) has no footer, which the mcap seeking reader refuses, so it is read
front to back in file order until the truncation point: every closed chunk
is recovered, the unfinished one is not.
Either way messages come back in the order they were written, which for the
raw topics is the order the live dsp stage saw them.

A message that does not fit (unknown topic, wrong schema, a block that
disagrees with the recorded layout) is skipped and counted in
:class:`replay.recorded_log.ReadReport`; a file that cannot be a replayable recording at all
raises :class:`replay.errors.LogError` with one line saying why.

The scan itself is :mod:`replay.log_scan`; the log, its report and its iterators are
:mod:`replay.recorded_log`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from acquisition.stream import StreamLayout
from replay import stream_codec
from replay.chunks import READ_ERRORS
from replay.errors import LogError, describe
from replay.integrity import DataCheck, check_data_crc
from replay.log_scan import NoSummary, Scan, scan_finished, scan_stream
from replay.mcap_records import MAGIC
from replay.recorded_log import ReadReport, RecordedLog
from replay.schemas import (
    BENCH_ATTACHMENT,
    FORMAT,
    META_END,
    META_RUN,
    SCHEMA_VERSION,
    TOPIC_TYPES,
    full_name,
    stream_topics,
)

# A sample rate no acquisition reaches (Hz): a larger one in a recording is damage.
MAX_RATE_HZ = 1e9


def find_logs(path: str | Path) -> list[Path]:
    """The recordings to replay: ``path`` itself, or the ``*.mcap`` files of a directory (sorted)."""
    path = Path(path)
    if path.is_dir():
        logs = sorted(p for p in path.iterdir() if p.suffix.lower() == ".mcap" and p.is_file())
        if not logs:
            raise LogError(f"{path}: no .mcap files in this directory")
        return logs
    return [path]


def open_log(path: str | Path, check_later: bool = False) -> RecordedLog:
    """Open a recording; raises :class:`LogError` when nothing replayable is in it.

    Parameters
    ----------
    path : an ``.mcap`` file written by :class:`replay.recorder.McapRecorder`
        (or :func:`replay.raw_writer.record_source`), finished or cut short.
    check_later : check the data section's CRC on a thread of its own
        (:class:`replay.integrity.DataCheck`): the first message read, or
        :meth:`RecordedLog.verify`, waits for it and raises its error. For a replay,
        whose set-up does not depend on a damaged byte being found first.
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
    scan: Scan | None = None
    report = ReadReport(finished=False, file_bytes=size, readable_bytes=0)
    closed_early = damaged_summary = no_summary = False
    if finished:
        try:
            scan = scan_finished(path)
            report.finished = True
            report.readable_bytes = size
        except NoSummary as end:
            # a valid end, read front to back as MCAP's readers do; our recorder's cut
            # writes no footer CRC, a writer that meant to leave the summary out one
            closed_early, no_summary = not end.crc, end.crc
        except READ_ERRORS as err:
            report.note(f"footer or summary damaged ({describe(err)}): reading front to back")
            scan, damaged_summary = None, True
    if scan is None:
        scan = scan_stream(path)
        report.readable_bytes = scan.readable
        report.data_complete = scan.data_end
        if scan.chunks == 0 and scan.messages == 0:
            raise LogError(
                f"{path}: truncated before any data ({size} bytes, no complete chunk"
                + (f"; {scan.error}" if scan.error else "")
                + ")"
            )
    report.chunks = scan.chunks
    report.time_origin_ns = _origin(scan)
    for line in scan.notes:
        report.note(line)
    crc_args = (
        path,
        scan.data_end_offset,
        scan.data_crc,
        scan.chunk_records,
        scan.attachment_damaged,
    )
    if check_later:
        check = DataCheck(*crc_args)
        try:
            log = _build(path, scan, report, check)
        except LogError:
            check.result()  # damaged metadata: the CRC's error is the one that says so
            raise
    else:
        scan.data_verified = check_data_crc(*crc_args)
        log = _build(path, scan, report)
    until = report.recorded_until_s
    where = f" up to t = {until:.2f} s" if until is not None else ""
    if no_summary:
        report.note(f"a finished recording without a summary section: read front to back{where}")
    elif closed_early:
        report.note(
            f"recording closed early, without its summary (the writer stopped, e.g. on a full "
            f"disk): {scan.chunks} chunk(s){where}; nothing after was recorded"
        )
    elif not report.finished:
        if scan.data_end:  # (a file with a footer: its summary was damaged, not its data)
            tail = "the writer stopped while finishing the file: no data lost"
            if damaged_summary:
                tail = "the data section is whole"
        else:
            lost = size - scan.readable
            tail = f"the last {lost} byte(s), the chunk being written, are lost"
            if damaged_summary:
                tail = f"the last {lost} byte(s) could not be read"
        what = "read front to back" if damaged_summary else "unfinished recording (no footer)"
        report.note(f"{what}: recovered {scan.chunks} chunk(s){where}; {tail}")
    return log


def _build(
    path: Path, scan: Scan, report: ReadReport, check: DataCheck | None = None
) -> RecordedLog:
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
    except (KeyError, ValueError, TypeError, AttributeError, OverflowError) as err:
        raise LogError(f"{path}: unreadable run metadata ({describe(err)})") from None
    problem = _metadata_problem(layout, settings, truth)
    if problem is not None:
        raise LogError(f"{path}: run metadata: {problem}")

    topics: dict[str, str] = {}
    for cid, channel in scan.channels.items():
        schema = scan.schemas.get(channel.schema_id)
        topics[channel.topic] = schema.name if schema is not None else ""
        del cid
    expected = stream_topics(layout)
    missing = [t for t in expected if t not in topics]
    wrong = [t for t, kind in expected.items() if t in topics and topics[t] != full_name(kind)]
    if missing or wrong:
        what = [f"missing {t}" for t in missing] + [
            f"{t} has schema {topics[t]!r}, expected {full_name(expected[t])!r}" for t in wrong
        ]
        if not scan.channels and scan.definitions_error:  # the first chunk holds them
            what.append(f"no channel definitions read ({scan.definitions_error})")
        raise LogError(f"{path}: raw topics do not match the recorded layout: {'; '.join(what)}")
    known = {**expected, **TOPIC_TYPES}
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
    channels = {
        cid: (ch.topic, topics[ch.topic]) for cid, ch in scan.channels.items() if ch.topic in topics
    }
    return RecordedLog(
        path=path,
        channels=channels,
        chunk_records=scan.chunk_records,
        data_verified=scan.data_verified,
        data_check=check,
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


def _metadata_problem(layout: StreamLayout, settings: object, truth: object) -> str | None:
    """What is wrong with the run metadata's values (a crafted or damaged file), or None."""
    for group in layout.groups:
        if not (math.isfinite(group.rate_hz) and 0 < group.rate_hz <= MAX_RATE_HZ):
            return f"group {group.name!r}: rate_hz {group.rate_hz} is not in (0, {MAX_RATE_HZ:g}]"
        if not math.isfinite(group.t0_s):
            return f"group {group.name!r}: t0_s {group.t0_s} is not finite"
    if not isinstance(settings, dict):
        return f"settings: expected a JSON object, got {type(settings).__name__}"
    for where, value in (("truth", truth), ("layout truth", layout.metadata.get("truth"))):
        if value is not None and not isinstance(value, dict):
            return f"{where}: expected a JSON object or null, got {type(value).__name__}"
    return None


def _origin(scan: Scan) -> int:
    """The run's time origin (ns), 0 when the metadata does not say (checked in :func:`_build`)."""
    try:
        return int((scan.metadata.get(META_RUN) or {}).get("time_origin_ns", "0"))
    except ValueError:
        return 0
