"""CSV recordings, writing side: :class:`CsvWriter` and the file names the reader shares.

Format in ``docs/file-formats.md`` and :mod:`acquisition.files.csvfile`. The names of
the files (``BASE.csv`` for group ``accel``, ``BASE.NAME.csv``, the
``CHANNEL_edge_s`` column of an edge file, the ``BASE.meta.json`` sidecar) are
defined here and imported by the reader. Its own module because the writer
shares nothing with the streaming reader but those names; :func:`json_default`
is also what the MDF writer and the replay log use for metadata.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import IO, Any

import numpy as np

from acquisition.stream import EdgeBlock, SampleBlock, SourceError, StreamItem, StreamLayout

# -- file names, shared with the reader (acquisition.files.csvfile imports them from here) ----------------

EDGE_SUFFIX = "_edge_s"
BASE_GROUP = "accel"


def sidecar_path(base: Path) -> Path:
    stem = base.name[: -len(base.suffix)] if base.suffix else base.name
    return base.with_name(stem + ".meta.json")


# -- CSV writing ---------------------------------------------------------------------------------


class CsvWriter:
    """Write a stream as CSV files (the format :class:`~acquisition.files.csvfile.CsvSource` reads).

    Lifecycle: ``start(layout)``, ``write(item)`` for every item, ``finish()``
    (or use it as a context manager). Values are written with 17 significant
    digits, so float64 samples and times read back bit for bit.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._files: dict[str, IO[str]] = {}
        self._layout: StreamLayout | None = None
        self.paths: list[Path] = []

    def _file_for(self, key: str) -> Path:
        stem = self.path.name[: -len(self.path.suffix)] if self.path.suffix else self.path.name
        return self.path if key == BASE_GROUP else self.path.with_name(f"{stem}.{key}.csv")

    def start(self, layout: StreamLayout) -> None:
        self._layout = layout
        keys: dict[str, str] = {}
        for g in layout.groups:
            keys[g.name] = ",".join(["time_s", *(f"{c.name}[{c.unit}]" for c in g.channels)])
        for ch in layout.edge_channels:
            if ch in keys:
                raise SourceError(
                    f"{self.path}: edge channel {ch!r} has the name of a sample group"
                )
            keys[ch] = ch + EDGE_SUFFIX
        for key, header in keys.items():
            path = self._file_for(key)
            try:
                fh = path.open("w", encoding="utf-8", newline="")
            except OSError as err:
                raise SourceError(f"{path}: cannot write ({err.strerror})") from None
            fh.write(header + "\n")
            self._files[key] = fh
            self.paths.append(path)
        meta = sidecar_path(self.path)
        meta.write_text(
            json.dumps(layout.metadata, indent=1, default=json_default), encoding="utf-8"
        )
        self.paths.append(meta)

    def write(self, item: StreamItem) -> None:
        if self._layout is None:
            raise RuntimeError("CsvWriter.write before start")
        if isinstance(item, SampleBlock):
            g = self._layout.group(item.group)
            t = g.t0_s + np.arange(item.first_index, item.first_index + item.n_samples) / g.rate_hz
            _write_rows(self._files[g.name], np.column_stack([t, item.data.T]))
        elif isinstance(item, EdgeBlock):
            _write_rows(self._files[item.channel], np.asarray(item.times_s, dtype=float)[:, None])

    def finish(self) -> list[Path]:
        for fh in self._files.values():
            fh.close()
        self._files = {}
        return self.paths

    def __enter__(self) -> CsvWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()


def _write_rows(fh: IO[str], rows: np.ndarray) -> None:
    # repr is the shortest text that reads back to the same float64 (as fast as savetxt's %.17g)
    fh.write("".join([",".join(map(repr, row)) + "\n" for row in rows.tolist()]))


def json_default(obj: object) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value of type {type(obj).__name__} is not JSON-serialisable")
