"""A recording run through the chain again: the steps every replay shares.

``ptinertia replay LOG``, a campaign's worker and the report's reprocessing all do
the same thing with a log: check that it holds the channels the bench file needs,
run :func:`ptinertia.runner.run_source` over it with the log's attachments (which a
new recording carries on), and say in the result what the reader had to skip.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from acquisition.channels import check_channels
from ptinertia.config import Bench, bench_file_paths
from ptinertia.pipeline import RunSummary
from ptinertia.recorded_bench import file_attachments
from ptinertia.runner import RunOptions, run_source
from ptinertia.to_acquisition import channel_needs
from replay.reader import RecordedLog
from replay.source import McapSource


def run_recording(
    log: RecordedLog,
    where: str,
    bench: Bench,
    bench_text: str,
    options: RunOptions,
    source: Any = None,
    dbc: str | None = None,
) -> tuple[RunSummary, dict[str, Any] | None]:
    """The run summary and result document of ``log`` replayed with ``bench``.

    ``where`` names the log in messages (a channel the bench needs and the log lacks);
    ``source`` replaces the log's recorded samples (default: :class:`McapSource` at full
    speed), e.g. its raw CAN frames decoded again (with ``dbc``). The result document
    gains ``recording_skipped`` when damaged parts of the log were skipped. A new
    recording carries the log's attachments with the files this replay read instead
    (``bench``'s pressure trace and DBC, ``dbc``): replayed again, it gives this result.
    """
    source = McapSource(log) if source is None else source
    check_channels(source.layout, channel_needs(bench), where)
    files = list(bench_file_paths(bench).values()) + ([dbc] if dbc else [])
    attachments = {**log.attachments, **file_attachments(files)}
    options = dataclasses.replace(options, attachments=attachments)
    summary, doc = run_source(bench, bench_text, source, log.source or "replay", options)
    skipped = log.report.skipped_document()
    if doc is not None and skipped:
        doc["recording_skipped"] = skipped
    return summary, doc
