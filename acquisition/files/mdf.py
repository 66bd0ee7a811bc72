"""ASAM MDF4 recordings (``.mf4``) through asammdf: streaming reader and writer.

The reader takes any layout a DAQ or asammdf writes when given the bench's channel
needs: each channel found by name (and group) in any channel group, its unit converted,
edge channels from event groups (:mod:`acquisition.files.selection`); the groups the
bench does not need are never read.

The writer's layout (``docs/file-formats.md``): one channel group per sample group, its
acquisition name the group name (``accel``, ``rpm``, ``pressure``, ``tacho``),
its master channel the time (s); a tacho edge channel is a channel group of
its own whose single channel, commented ``ptinertia:edges``, holds the edge
times (s, float64) and whose master is the same times. Samples and times are
written as float64, so they read back bit for bit. The metadata (simulated
truth, bench) is an embedded attachment ``ptinertia-metadata.json``.

The reader pulls ``records_per_chunk`` records of one group at a time
(asammdf reads lazily), so long recordings stream.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.channels import ChannelNeed
from acquisition.files.csvwriter import json_default
from acquisition.files.selection import (
    FileGroup,
    event_times,
    scaled,
    select,
    select_all,
    unique_labels,
)
from acquisition.files.windowed import Chunk, EdgeStream, SampleStream, WindowedFileSource
from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SourceError,
    StreamItem,
    StreamLayout,
)

EDGE_COMMENT = "ptinertia:edges"
METADATA_NAME = "ptinertia-metadata.json"


def _open_mdf(path: Path) -> Any:
    from asammdf import MDF  # on use: heavy, and a CSV run never needs it

    if not path.is_file():
        raise SourceError(f"{path}: no such MDF file")
    try:
        return MDF(path)
    except Exception as err:  # asammdf raises many types for a file that is not MDF
        raise SourceError(
            f"{path}: not a readable MDF4 file ({type(err).__name__}: {err})"
        ) from None


def _mdf_chunks(
    mdf: Any, gi: int, indices: list[int], n: int, per_chunk: int, where: str
) -> Iterator[Chunk]:
    for start in range(0, n, per_chunk):
        count = min(per_chunk, n - start)
        try:
            times = np.asarray(
                mdf.get_master(gi, record_offset=start, record_count=count), dtype=float
            )
            sigs = [
                mdf.get(
                    group=gi, index=ci, record_offset=start, record_count=count, samples_only=True
                )[0]
                for ci in indices
            ]
        except Exception as err:
            raise SourceError(
                f"{where}: cannot read records {start}..{start + count} ({err})"
            ) from None
        data = np.array(sigs, dtype=float) if sigs else None
        yield start, times, data


class MdfSource(WindowedFileSource):
    """Stream an MDF4 recording: the layout above, or any layout a DAQ or asammdf writes.

    Parameters
    ----------
    path : path
    block_s : float
        Window length of the merged stream (s).
    records_per_chunk : int
        Records read at a time per channel group.
    needs : sequence of ChannelNeed, optional
        The channels the run reads (:func:`acquisition.files.selection.select`): found
        by name in any group, converted to the pipeline's units, everything else left
        unread. None: every group as written, units unchecked.
    """

    def __init__(
        self,
        path: str | Path,
        block_s: float = 0.1,
        records_per_chunk: int = 65536,
        needs: Sequence[ChannelNeed] | None = None,
    ) -> None:
        self.path = Path(path)
        self._mdf = _open_mdf(self.path)
        try:
            groups, records = self._describe(needs is None)
            if needs is None:
                picks, edge_picks = select_all(groups)
            else:
                picks, edge_picks = select(groups, needs, str(self.path))
            samples: list[SampleStream] = []
            edges: list[EdgeStream] = []
            names = unique_labels([p.group for p in picks])
            for pick, name in zip(picks, names, strict=True):
                gi = pick.group.key
                where = f"{self.path} group {pick.group.label!r}"
                indices = [records[gi][1][c] for c in pick.columns]
                chunks = _mdf_chunks(
                    self._mdf, gi, indices, records[gi][0], records_per_chunk, where
                )
                samples.append(
                    SampleStream(
                        name,
                        pick.specs,
                        where,
                        scaled(chunks, None, pick.factors),
                        "record",
                    )
                )
            for e in edge_picks:
                gi = e.group.key
                where = f"{self.path} group {e.group.label!r}"
                n = records[gi][0]
                if e.group.edge_list:
                    chunks = _mdf_chunks(self._mdf, gi, [], n, records_per_chunk, where)
                else:
                    index = records[gi][1][e.column]
                    raw = _mdf_chunks(self._mdf, gi, [index], n, records_per_chunk, where)
                    chunks = event_times(raw, 0, e.channel, where)
                edges.append(
                    EdgeStream(e.channel, f"{where} channel {e.channel!r}", chunks, "record")
                )
            super().__init__(samples, edges, self._metadata(), block_s)
            for stream in edges:
                stream.next_time()  # an event group that is a sampled wave fails on opening
        except BaseException:
            self._mdf.close()
            raise

    def _describe(self, strict: bool) -> tuple[list[FileGroup], dict[int, tuple[int, list[int]]]]:
        """The file's channel groups, and per group its record count and channel indices.

        ``strict`` (no bench): a channel without a usable name is an error, empty
        groups are left out; otherwise unusable channels are skipped (nobody can ask
        for them) and an empty group is kept (a channel needed there has no samples).
        """
        groups: list[FileGroup] = []
        records: dict[int, tuple[int, list[int]]] = {}
        for gi, group in enumerate(self._mdf.groups):
            cg = group.channel_group
            n = int(cg.cycles_nr)
            master = self._mdf.masters_db.get(gi)
            chans = [(ci, c) for ci, c in enumerate(group.channels) if ci != master]
            label = cg.acq_name or f"group{gi}"
            if not chans or (strict and n == 0):
                continue
            edge_list = len(chans) == 1 and chans[0][1].comment == EDGE_COMMENT
            usable = []
            for ci, c in chans:
                if not c.name or c.name.lower() == "nan":
                    if strict:
                        raise SourceError(
                            f"{self.path} group {label!r}: a channel has no usable name "
                            f"({c.name!r})"
                        )
                    continue
                usable.append((ci, ChannelSpec(c.name, c.unit or "")))
            groups.append(
                FileGroup(
                    gi,
                    label,
                    tuple(spec for _, spec in usable),
                    (str(gi), f"group{gi}"),
                    edge_list,
                )
            )
            records[gi] = (n, [ci for ci, _ in usable])
        return groups, records

    def _metadata(self) -> dict[str, Any]:
        for i, att in enumerate(self._mdf.attachments):
            if str(att.file_name).endswith(METADATA_NAME):
                data, _, _ = self._mdf.extract_attachment(i)
                try:
                    meta = json.loads(data)
                except ValueError as err:
                    raise SourceError(
                        f"{self.path}: attachment {METADATA_NAME} is not JSON ({err})"
                    ) from None
                return meta if isinstance(meta, dict) else {}
        return {}

    def _shutdown(self) -> None:
        self._mdf.close()


class MdfWriter:
    """Write a stream as an MDF4 file (the layout :class:`MdfSource` reads).

    Lifecycle: ``start(layout)``, ``write(item)``, ``finish()`` (saves the file).
    asammdf spools the appended blocks to a temporary file until ``finish``, so
    memory stays flat; the disk holds the data twice until then.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._mdf: Any = None
        self._index: dict[str, int] = {}
        self._layout: StreamLayout | None = None
        self.paths: list[Path] = []

    def start(self, layout: StreamLayout) -> None:
        from asammdf import MDF, Signal  # on use, as in the reader

        self._layout = layout
        self._mdf = MDF(version="4.10")
        empty = np.zeros(0)
        for g in layout.groups:
            sigs = [Signal(empty, empty, name=c.name, unit=c.unit) for c in g.channels]
            self._index[g.name] = self._mdf.append(
                sigs, acq_name=g.name, comment=f"rate_hz={g.rate_hz!r}"
            )
        for ch in layout.edge_channels:
            sig = Signal(empty, empty, name=ch, unit="s", comment=EDGE_COMMENT)
            self._index["\0edge:" + ch] = self._mdf.append(
                [sig], acq_name=ch, comment="tacho edge times"
            )

    def write(self, item: StreamItem) -> None:
        if self._layout is None:
            raise RuntimeError("MdfWriter.write before start")
        if isinstance(item, SampleBlock):
            g = self._layout.group(item.group)
            t = g.t0_s + np.arange(item.first_index, item.first_index + item.n_samples) / g.rate_hz
            self._mdf.extend(self._index[g.name], [(t, None), *((row, None) for row in item.data)])
        elif isinstance(item, EdgeBlock):
            t = np.asarray(item.times_s, dtype=float)
            self._mdf.extend(self._index["\0edge:" + item.channel], [(t, None), (t, None)])

    def finish(self) -> list[Path]:
        if self._mdf is None:
            return self.paths
        meta = json.dumps(
            self._layout.metadata if self._layout else {}, default=json_default
        ).encode()
        self._mdf.attach(meta, file_name=METADATA_NAME, embedded=True, compression=True)
        try:
            self._mdf.save(self.path, overwrite=True)
        except OSError as err:
            raise SourceError(f"{self.path}: cannot write ({err.strerror})") from None
        finally:
            self._mdf.close()
            self._mdf = None
        self.paths = [self.path]
        return self.paths

    def __enter__(self) -> MdfWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()
