"""Lazy registry of source and writer backends (python-can ``can/interfaces`` style).

A name maps to ``("module", "attribute")``; the module is imported only when the
backend is used, so a replay never imports CAN drivers and a CSV run never
imports asammdf. A source backend is a class or an opener function called as
``backend(path_or_arg, ...)``; :mod:`ptinertia.sources` calls them.
"""

from __future__ import annotations

import importlib
from typing import Any

from acquisition.stream import SourceError

# source kind -> (module, class or opener)
SOURCES: dict[str, tuple[str, str]] = {
    "sim": ("acquisition.sim.simulator", "SimulatedBench"),
    "csv": ("acquisition.files.csvfile", "CsvSource"),
    "mf4": ("acquisition.files.mdf", "MdfSource"),
    "can": ("acquisition.can.source", "open_can"),
    "can-log": ("acquisition.can.logs", "open_can_log"),
    "mcap": ("replay.source", "open_replay"),
}

# file extension (lower case, with the dot) -> source kind
FILE_KINDS: dict[str, str] = {
    ".csv": "csv",
    ".mf4": "mf4",
    ".mdf": "mf4",
    ".blf": "can-log",
    ".asc": "can-log",
    ".trc": "can-log",
    ".log": "can-log",
    ".mcap": "mcap",
}

# file extension -> (module, writer class) for ``ptinertia simulate``
WRITERS: dict[str, tuple[str, str]] = {
    ".csv": ("acquisition.files.csvwriter", "CsvWriter"),
    ".mf4": ("acquisition.files.mdf", "MdfWriter"),
    ".mcap": ("replay.raw_writer", "McapFileWriter"),
}


def _load(table: dict[str, tuple[str, str]], name: str, what: str) -> Any:
    try:
        module, attr = table[name]
    except KeyError:
        raise SourceError(f"unknown {what} {name!r}; known: {', '.join(sorted(table))}") from None
    try:
        mod = importlib.import_module(module)
    except ImportError as err:
        raise SourceError(
            f"{what} {name!r} is not available in this installation ({err})"
        ) from None
    return getattr(mod, attr)


def source_backend(kind: str) -> Any:
    """The class or opener registered under ``kind`` (``sim``, ``csv``, ``mf4``, ``can``, ...)."""
    return _load(SOURCES, kind, "source kind")


def file_kind(suffix: str) -> str:
    """Source kind of a file extension (``.csv`` -> ``csv``, ``.blf`` -> ``can-log``, ...)."""
    try:
        return FILE_KINDS[suffix.lower()]
    except KeyError:
        raise SourceError(
            f"file extension {suffix or '(none)'!r} not supported; expected one of "
            + ", ".join(sorted(FILE_KINDS))
        ) from None


def writer_class(suffix: str) -> Any:
    """The writer class for a file extension (``.csv``, ``.mf4``)."""
    return _load(WRITERS, suffix.lower(), "output file extension")
