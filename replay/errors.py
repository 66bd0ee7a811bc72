"""The replay layer's user error.

A recording is a source, so :class:`LogError` subclasses
:class:`acquisition.stream.SourceError` (itself a ``ValueError``): the CLI
already prints it as one line with exit code 2, and code that opens "some
source" catches it with the other source errors.
"""

from __future__ import annotations

from acquisition.stream import SourceError


class LogError(SourceError):
    """A recording cannot be written or read (empty, not MCAP, truncated before any data, missing topics)."""


class BadMessage(Exception):
    """One message cannot be decoded against the layout (the reader skips it and reports it)."""


def describe(err: BaseException) -> str:
    """``"Type: message"`` of an exception met while reading, for a one-line note."""
    text = str(err).strip()
    return f"{type(err).__name__}: {text}" if text else type(err).__name__
