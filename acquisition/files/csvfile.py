"""CSV recordings, reading side: the streaming :class:`CsvSource` and how it finds its files.

Format (``docs/file-formats.md``): one file per sample group (rate), the first
column ``time_s``, then one column per channel headed ``name[unit]``; a file
``BASE.csv`` holds group ``accel``, a file ``BASE.NAME.csv`` group ``NAME``. An
edge file has a single column of edge times (``CHANNEL_edge_s``, or any header
naming the channel). An optional ``BASE.meta.json`` carries the metadata. Given the
bench's channel needs, only those channels are passed on, by name and in the
pipeline's units (:mod:`acquisition.files.selection`).

Readers stream: the files are parsed in chunks and merged into time windows
(:class:`~acquisition.files.windowed.WindowedFileSource`), so an hour-long recording
is never held in memory. A sample's grid index is ``round((t - t0) * rate)``; a
jump is a gap (reported as a ``"gap"`` event), a time that does not increase
or lies off the grid is a :class:`SourceError`. NaN samples are passed on
(reported once per channel as a ``"nan"`` event): the DSP flags them.

The window merge shared by every file source is in :mod:`acquisition.files.windowed`,
the writer in :mod:`acquisition.files.csvwriter`.
"""

from __future__ import annotations

import itertools
import json
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from acquisition.channels import ChannelNeed
from acquisition.files.csvwriter import BASE_GROUP, EDGE_SUFFIX, sidecar_path
from acquisition.files.selection import (
    FileGroup,
    event_times,
    scaled,
    select,
    select_all,
    unique_labels,
)
from acquisition.files.windowed import (
    Chunk,
    EdgeStream,
    SampleStream,
    WindowedFileSource,
)
from acquisition.signal_units import unit_factor
from acquisition.stream import ChannelSpec, SourceError

# -- CSV reading ---------------------------------------------------------------------------------

_HEADER = re.compile(r"^\s*([^\[\]]*?)\s*(?:\[([^\[\]]*)\])?\s*$")
_LOADTXT_POS = re.compile(r"at row (\d+), column (\d+)")
_LOADTXT_COLS = re.compile(r"changed from (\d+) to (\d+) at row (\d+)")


def _parse_header(line: str, path: Path) -> list[ChannelSpec]:
    cells = line.rstrip("\r\n").split(",")
    specs = []
    for i, cell in enumerate(cells):
        m = _HEADER.match(cell)
        name = m.group(1) if m else ""
        if not m or not name or name.lower() == "nan":
            raise SourceError(f"{path}: header column {i + 1} is {cell!r}: expected name[unit]")
        specs.append(ChannelSpec(name, m.group(2) or ""))
    return specs


def _csv_chunks(
    fh: IO[str], path: Path, columns: Sequence[str], rows: int, time_factor: float = 1.0
) -> Iterator[Chunk]:
    """Parsed rows of an open CSV after its header.

    Yields (file line of the first row, first column in s, other columns as (n_ch, n)).
    """
    line_no = 2
    while True:
        try:
            lines = list(itertools.islice(fh, rows))
        except UnicodeDecodeError as err:
            raise SourceError(
                f"{path}: not UTF-8 text after line {line_no - 1} (byte 0x{err.object[err.start]:02x}); "
                "save the file as UTF-8"
            ) from None
        if not lines:
            return
        try:
            arr = np.loadtxt(lines, delimiter=",", ndmin=2, dtype=float)
        except ValueError as err:
            raise SourceError(_loadtxt_message(str(err), path, line_no, columns)) from None
        if arr.size and arr.shape[1] != len(columns):
            raise SourceError(
                f"{path}: line {line_no}: expected {len(columns)} columns as in the header, "
                f"got {arr.shape[1]}"
            )
        if arr.size:
            yield (
                line_no,
                arr[:, 0] * time_factor if time_factor != 1.0 else arr[:, 0].copy(),
                (np.ascontiguousarray(arr[:, 1:].T) if arr.shape[1] > 1 else None),
            )
        line_no += len(lines)


def _loadtxt_message(msg: str, path: Path, line0: int, columns: Sequence[str]) -> str:
    m = _LOADTXT_COLS.search(msg)
    if m:  # loadtxt counts this row from 1
        return (
            f"{path}: line {line0 + int(m.group(3)) - 1}: expected {m.group(1)} columns as in the "
            f"header, got {m.group(2)}"
        )
    m = _LOADTXT_POS.search(msg)
    if m:  # and this one from 0
        row, col = int(m.group(1)), int(m.group(2))
        name = columns[col - 1] if 0 < col <= len(columns) else f"#{col}"
        reason = msg.split(" at row")[0]
        return f"{path}: line {line0 + row}, column {name!r}: expected a number ({reason})"
    return f"{path}: from line {line0}: cannot parse as numbers ({msg.splitlines()[0]})"


def group_name_of(path: Path) -> str:
    """``BASE.csv`` -> ``accel``; ``BASE.NAME.csv`` -> ``NAME``."""
    stem = path.name[: -len(path.suffix)] if path.suffix else path.name
    return stem.split(".", 1)[1] if "." in stem else BASE_GROUP


def discover_csv(path: str | Path) -> list[Path]:
    """The base file and its siblings ``BASE.*.csv``, base first."""
    base = Path(path)
    stem = base.name[: -len(base.suffix)] if base.suffix else base.name
    siblings = sorted(p for p in base.parent.glob(f"{glob_escape(stem)}.*.csv") if p != base)
    return [base, *siblings]


def glob_escape(text: str) -> str:
    return re.sub(r"([\[\]*?])", r"[\1]", text)


class CsvSource(WindowedFileSource):
    """Stream a CSV recording (``BASE.csv`` and its ``BASE.*.csv`` siblings).

    Parameters
    ----------
    paths : path or sequence of paths
        One base path (siblings are found) or the explicit list of files.
    block_s : float
        Window length of the merged stream (s).
    rows_per_chunk : int
        Rows parsed at a time per file (bounds the memory).
    """

    def __init__(
        self,
        paths: str | Path | Sequence[str | Path],
        block_s: float = 0.1,
        rows_per_chunk: int = 20000,
        needs: Sequence[ChannelNeed] | None = None,
    ) -> None:
        files = discover_csv(paths) if isinstance(paths, str | Path) else [Path(p) for p in paths]
        self._handles: list[IO[str]] = []
        try:
            groups, columns, time_factors = self._describe(files)
            where = str(files[0])
            if needs is None:
                picks, edge_picks = select_all(groups)
            else:
                picks, edge_picks = select(groups, needs, where)

            def chunks(key: int) -> Iterator[Chunk]:
                return _csv_chunks(
                    self._handles[key], files[key], columns[key], rows_per_chunk, time_factors[key]
                )

            samples = [
                SampleStream(
                    name,
                    p.specs,
                    str(files[p.group.key]),
                    scaled(chunks(p.group.key), p.columns, p.factors),
                    "line",
                )
                for p, name in zip(picks, unique_labels([p.group for p in picks]), strict=True)
            ]
            edges = [
                EdgeStream(
                    e.channel,
                    str(files[e.group.key]),
                    chunks(e.group.key)
                    if e.group.edge_list
                    else event_times(
                        chunks(e.group.key), e.column, e.channel, str(files[e.group.key])
                    ),
                    "line",
                )
                for e in edge_picks
            ]
            super().__init__(samples, edges, _read_sidecar(files[0]), block_s)
            for stream in edges:
                stream.next_time()  # an event file that is a sampled wave fails on opening
        except BaseException:
            self._close_handles()
            raise

    def _describe(self, files: list[Path]) -> tuple[list[FileGroup], list[list[str]], list[float]]:
        """Each file as a group (its header), its column names, its time column's factor to s."""
        groups: list[FileGroup] = []
        columns: list[list[str]] = []
        time_factors: list[float] = []
        for key, path in enumerate(files):
            try:
                # utf-8-sig: the byte order mark spreadsheet exports put first is not a column name
                fh = path.open("r", encoding="utf-8-sig", newline="")
                header = fh.readline()
            except OSError as err:
                raise SourceError(f"{path}: cannot read ({err.strerror})") from None
            except UnicodeDecodeError:
                raise SourceError(f"{path}: not a text CSV file") from None
            self._handles.append(fh)
            if not header.strip():
                raise SourceError(f"{path}: empty file, expected a header line")
            specs = _parse_header(header, path)
            names = [s.name for s in specs]
            columns.append(names)
            label = group_name_of(path)
            if len(specs) == 1:  # an edge file: one column of edge times, any header
                ch = names[0][: -len(EDGE_SUFFIX)] if names[0].endswith(EDGE_SUFFIX) else names[0]
                spec = ChannelSpec(ch, "s")
                groups.append(FileGroup(key, label, (spec,), (path.name,), edge_list=True))
                time_factors.append(_time_factor(specs[0], path))
                continue
            if names[0] not in ("time_s", "time"):
                raise SourceError(
                    f"{path}: first column is {header.split(',')[0].strip()!r}: "
                    "expected time_s "
                    f"(or a single column CHANNEL{EDGE_SUFFIX} for tacho edges)"
                )
            time_factors.append(_time_factor(specs[0], path))
            groups.append(FileGroup(key, label, tuple(specs[1:]), (path.name,)))
        return groups, columns, time_factors

    def _close_handles(self) -> None:
        for fh in self._handles:
            fh.close()
        self._handles = []

    def _shutdown(self) -> None:
        self._close_handles()


def _time_factor(spec: ChannelSpec, path: Path) -> float:
    # time_s, or an edge column: seconds unless it says otherwise (UnitError is a SourceError)
    return unit_factor(spec.unit or "s", "s", f"{path}: column {spec.name!r}")


def _read_sidecar(base: Path) -> dict[str, Any]:
    path = sidecar_path(base)
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise SourceError(f"{path}: cannot read the metadata ({err})") from None
    if not isinstance(data, dict):
        raise SourceError(f"{path}: expected a JSON object of metadata")
    return data
