"""The head of a recording: run metadata, attachments, and one channel per topic.

:meth:`replay.recorder.McapRecorder.start` writes it once, before the first
chunk, so a file cut short after its first chunk still holds the bench file,
the layout, the settings and the truth (``docs/recording-format.md``).
:class:`RecordingInfo` says what goes in; the app's ``RunContext`` has the same
fields and works in its place.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from mcap.well_known import MessageEncoding, SchemaEncoding

from acquisition.files.csvwriter import json_default
from acquisition.stream import StreamLayout
from replay import foxglove, stream_codec
from replay.errors import LogError
from replay.mcapwriter import ThreadedWriter
from replay.schemas import (
    BENCH_ATTACHMENT,
    FORMAT,
    META_RUN,
    SCHEMA_VERSION,
    TOPIC_TYPES,
    edge_topic,
    full_name,
    raw_topic,
    schema_data,
    stream_topics,
)

MEDIA_TYPES = {
    ".toml": "application/toml",
    ".json": "application/json",
    ".dbc": "text/x-dbc",
    ".txt": "text/plain",
}


@dataclass(frozen=True)
class RecordingInfo:
    """What a recording keeps besides the stream (the fields of ``RunContext`` it reads).

    A ``ptinertia.sinks.RunContext`` works in its place.
    """

    layout: StreamLayout
    bench_text: str = ""
    truth: dict[str, Any] | None = None
    settings: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    attachments: dict[str, bytes] = field(default_factory=dict)


def ptinertia_version() -> str:
    """The installed ptinertia's version, written into every recording."""
    try:
        return version("ptinertia")
    except PackageNotFoundError:
        return "unknown"


def check_topics(layout: StreamLayout) -> None:
    """One topic per group and edge channel, none taking a fixed topic (a group named ``can``)."""
    seen = set(TOPIC_TYPES)
    for topic in [raw_topic(g.name) for g in layout.groups] + [
        edge_topic(c) for c in layout.edge_channels
    ]:
        if topic in seen:
            raise LogError(f"cannot record: two streams would share the topic {topic}; rename one")
        seen.add(topic)


def write_head(writer: ThreadedWriter, context: Any, origin_ns: int) -> dict[str, int]:
    """Write the run metadata, the attachments, the schemas and channels; topic -> channel id.

    ``context`` is a :class:`RecordingInfo` (or anything with its fields);
    ``origin_ns`` the log time of stream time 0. The layout's topics must have
    passed :func:`check_topics`.
    """
    layout: StreamLayout = context.layout
    writer.add_metadata(META_RUN, run_metadata(context, layout, origin_ns))
    now = time.time_ns()
    bench_text = getattr(context, "bench_text", "") or ""
    if bench_text:
        writer.add_attachment(now, now, BENCH_ATTACHMENT, "application/toml", bench_text.encode())
    for name, data in (getattr(context, "attachments", None) or {}).items():
        if name == BENCH_ATTACHMENT and bench_text:
            continue  # a replayed log's own bench file: this run's bench text replaces it
        media_type = MEDIA_TYPES.get(Path(name).suffix.lower(), "application/octet-stream")
        writer.add_attachment(now, now, name, media_type, bytes(data))
    schema_ids: dict[str, int] = {}
    channels: dict[str, int] = {}
    # the raw stream's channels first (groups, edge channels, /events), then the fixed
    # topics; /raw/can always, so a reader finds every topic up front
    for topic, kind in {**stream_topics(layout), **TOPIC_TYPES}.items():
        if kind not in schema_ids:
            data = foxglove.schema_data(kind) if topic in foxglove.TOPICS else schema_data()
            schema_ids[kind] = writer.register_schema(
                name=full_name(kind), encoding=SchemaEncoding.Protobuf, data=data
            )
        channels[topic] = writer.register_channel(
            topic=topic, message_encoding=MessageEncoding.Protobuf, schema_id=schema_ids[kind]
        )
    return channels


def run_metadata(context: Any, layout: StreamLayout, origin_ns: int) -> dict[str, str]:
    """The ``ptinertia`` metadata record: format, versions, source, layout, settings, truth."""
    truth = getattr(context, "truth", None)
    if truth is None:
        truth = layout.metadata.get("truth")
    return {
        "format": FORMAT,
        "schema_version": str(SCHEMA_VERSION),
        "ptinertia_version": ptinertia_version(),
        "source": str(getattr(context, "source", "") or ""),
        "layout": stream_codec.layout_to_json(layout),
        "settings": json.dumps(getattr(context, "settings", None) or {}, default=json_default),
        "truth": json.dumps(truth, default=json_default),
        "time_origin_ns": str(origin_ns),
        "started_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def end_metadata(messages: dict[str, int], final: Any) -> dict[str, str]:
    """The end-of-run metadata record: finished, when, messages per topic, and the final
    estimate's result document (``final``: an ``Estimate`` or None)."""
    return {
        "status": "finished",
        "closed_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        "messages": json.dumps(dict(messages)),
        "result": json.dumps(final.to_json() if final is not None else None),
    }
