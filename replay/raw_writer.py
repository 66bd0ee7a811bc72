"""Write a source's raw stream alone, with no dsp and no estimate, as a replayable recording.

This is ``ptinertia simulate --out x.mcap``: the file has the format of a
recorded run (:mod:`replay.recorder`) without its ``/orders``, ``/gating`` and
``/estimate`` messages, and replays the same way. :func:`record_source` takes
any iterable of items; :class:`McapFileWriter` is the same thing behind the
stream-writer interface of the app's registry (``start``, ``write``,
``finish``), beside the CSV and MF4 writers.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from acquisition.stream import StreamItem, StreamLayout
from replay.recorder import CHUNK_S, McapRecorder, RecorderStats
from replay.recording_head import RecordingInfo


def record_source(
    source: Iterable[StreamItem],
    path: str | Path,
    *,
    layout: StreamLayout | None = None,
    bench_text: str | None = None,
    truth: dict[str, Any] | None = None,
    settings: dict[str, Any] | None = None,
    source_spec: str = "sim",
    attachments: dict[str, bytes] | None = None,
    chunk_s: float = CHUNK_S,
    time_origin_ns: int | None = None,
) -> RecorderStats:
    """Record a source's raw stream (no dsp, no estimate) as a replayable log.

    The log has the format of a recorded run without its ``/orders``,
    ``/gating`` and ``/estimate`` messages, and replays the same way.

    Parameters
    ----------
    source : an ``acquisition.stream.Source`` (or any iterable of items, with ``layout``).
    path : output file.
    layout : defaults to ``source.layout``.
    bench_text : the bench file text; defaults to ``layout.metadata["bench_text"]``.
    truth : the simulated truth; defaults to ``layout.metadata["truth"]``.
    settings, source_spec, attachments : stored as in a recorded run.

    Returns
    -------
    RecorderStats : messages and payload bytes per topic.
    """
    if layout is None:
        layout = source.layout  # type: ignore[attr-defined]
    assert layout is not None
    info = RecordingInfo(
        layout=layout,
        bench_text=bench_text
        if bench_text is not None
        else str(layout.metadata.get("bench_text", "")),
        truth=truth if truth is not None else layout.metadata.get("truth"),
        settings=settings or {},
        source=source_spec,
        attachments=dict(attachments or {}),
    )
    recorder = McapRecorder(path, chunk_s=chunk_s, time_origin_ns=time_origin_ns)
    recorder.start(info)
    try:
        for item in source:
            recorder.on_item(item)
    finally:
        recorder.close(None)
    return recorder.stats


class McapFileWriter:
    """The stream writer interface of ``ptinertia.registry.WRITERS`` for ``.mcap``.

    Lifecycle ``start(layout)``, ``write(item)`` for every item, ``finish()``
    (or a context manager), like ``CsvWriter``: ``ptinertia simulate --out x.mcap``
    then needs only the registry line ``".mcap": ("replay.raw_writer", "McapFileWriter")``.
    The bench text and the truth come from ``layout.metadata`` (``bench_text``,
    ``truth``), where the simulated source puts them.
    """

    def __init__(self, path: str | Path, source_spec: str = "sim") -> None:
        self.path = Path(path)
        self.source_spec = source_spec
        self.paths: list[Path] = []
        self.recorder = McapRecorder(self.path)

    def start(self, layout: StreamLayout) -> None:
        self.recorder.start(
            RecordingInfo(
                layout=layout,
                bench_text=str(layout.metadata.get("bench_text", "")),
                truth=layout.metadata.get("truth"),
                source=self.source_spec,
            )
        )
        self.paths = [self.path]

    def write(self, item: StreamItem) -> None:
        self.recorder.on_item(item)

    def finish(self) -> None:
        self.recorder.close(None)

    def __enter__(self) -> McapFileWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()
