"""Recordings written again by mcap's own ``Writer`` (the options a user's tool may choose),
the records of their summary section, and the CLI's replay of them."""

from __future__ import annotations

import json
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from mcap.records import Attachment, Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from ptinertia.cli import main
from replay.schemas import META_RUN


def replay(log: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> Any:
    """Exit code, result document (or None), stderr lines of ``ptinertia replay log``."""
    out.unlink(missing_ok=True)
    code = main(["replay", str(log), "--quiet", "--json", str(out)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    return code, json.loads(out.read_text()) if out.exists() else None, err


def rewritten(
    source: Path,
    path: Path,
    edit_layout: Callable[[dict[str, Any]], None] | None = None,
    topics: dict[str, str] | None = None,
    **options: Any,
) -> Path:
    """``source``'s records written again, in file order, by ``Writer(**options)``;
    ``edit_layout`` changes the run metadata's layout (a channel is registered for each
    sample group it adds); ``topics`` renames channels."""
    with open(source, "rb") as src, open(path, "wb") as out:
        writer = Writer(out, **options)
        writer.start(profile="", library="a user's tool")
        schemas, channels = {0: 0}, {}
        added: list[str] = []  # sample groups edit_layout added
        for rec in StreamReader(src).records:
            if isinstance(rec, Schema) and rec.id not in schemas:
                schemas[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in channels:
                topic = (topics or {}).get(rec.topic, rec.topic)
                channels[rec.id] = writer.register_channel(
                    topic, rec.message_encoding, schemas[rec.schema_id], rec.metadata
                )
                for group in added if rec.topic == "/raw/accel" else ():
                    topic = f"/raw/{group}"
                    writer.register_channel(topic, rec.message_encoding, schemas[rec.schema_id])
            elif isinstance(rec, Message):
                writer.add_message(
                    channels[rec.channel_id], rec.log_time, rec.data, rec.publish_time, rec.sequence
                )
            elif isinstance(rec, Metadata):
                metadata = dict(rec.metadata)
                if rec.name == META_RUN and edit_layout is not None:
                    layout = json.loads(metadata["layout"])
                    before = {g["name"] for g in layout["groups"]}
                    edit_layout(layout)
                    added = [g["name"] for g in layout["groups"] if g["name"] not in before]
                    metadata["layout"] = json.dumps(layout)
                writer.add_metadata(rec.name, metadata)
            elif isinstance(rec, Attachment):
                writer.add_attachment(
                    rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data
                )
        writer.finish()
    return path


def summary_records(data: bytes) -> list[tuple[int, int]]:
    """(opcode, byte offset) of every record of a finished file's summary section."""
    footer = len(data) - 8 - 29
    (start,) = struct.unpack_from("<Q", data, footer + 9)
    out, pos = [], start
    while pos < footer:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        out.append((opcode, pos))
        pos += 9 + length
    return out
