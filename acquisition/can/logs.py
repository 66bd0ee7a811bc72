"""CAN log files as sources (BLF, ASC, TRC, candump .log, MF4 bus logging) and as outputs.

Reading goes through python-can's readers and the same :class:`FrameDecoder` as
the live bus, with the DBC of the bench file, so a log can be decoded again with
a corrected DBC. Receive times in the log only help to unwrap short counters
(samples are placed by their counters), which is why an ASC file, whose
absolute times python-can does not keep, replays exactly like a BLF.

python-can's TRC writer refuses CAN FD frames; :class:`FrameLogWriter` writes
TRC 2.1 itself (PEAK's format: type ``FB`` for CAN FD with bit-rate switch,
column ``L`` the DLC code), which python-can's reader understands.
"""

from __future__ import annotations

import gzip
from collections.abc import Callable, Iterable, Iterator, Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import IO, Any

from acquisition.can.bus import frame_to_message, message_to_frame
from acquisition.can.dbc import load_plan
from acquisition.can.frames import DLC_SIZES, RawFrame
from acquisition.can.plan import CanPlan
from acquisition.can.reorder import DecoderOptions
from acquisition.can.source import CanFrameSource, CanSettings
from acquisition.channels import ChannelNeed
from acquisition.stream import SourceError, StreamItem

CAN_LOG_SUFFIXES = (".blf", ".asc", ".trc", ".log")  # and the same gzip-compressed (.asc.gz)


def log_suffix(path: str | Path) -> str:
    """The format suffix of a log: ``.asc`` for ``run.asc`` and ``run.asc.gz`` alike."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if len(suffixes) >= 2 and suffixes[-1] == ".gz":
        return suffixes[-2]
    return suffixes[-1] if suffixes else ""


def is_can_log(path: str | Path) -> bool:
    """A CAN log by its extension (gzip-compressed too, as python-can reads them: ``.asc.gz``),
    or an MF4 file holding raw CAN frames (``CAN_DataFrame``)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".gz":
        return log_suffix(p) in CAN_LOG_SUFFIXES
    if suffix in CAN_LOG_SUFFIXES:
        return True
    if suffix != ".mf4" or not p.is_file():
        return False
    try:
        from asammdf import MDF  # on use: heavy, and optional

        with MDF(str(p)) as mdf:
            return "CAN_DataFrame" in mdf.channels_db
    except Exception:  # not readable as MDF here: let the MDF source report it
        return False


def read_frames(
    path: str | Path, batch_frames: int = 5000, errors: list[int] | None = None
) -> Iterator[list[RawFrame]]:
    """The data frames of a CAN log in batches; error frames are counted into ``errors[0]``
    (and remote frames into ``errors[1]``, when the list has two places)."""
    import can  # on use: python-can loads its interfaces; a CSV run never needs it

    p = Path(path)
    if not p.is_file():
        raise SourceError(f"CAN log {str(p)!r} not found")
    try:
        reader = can.LogReader(str(p))
    except Exception as err:  # python-can raises ValueError, OSError, struct.error...
        raise SourceError(f"CAN log {str(p)!r} cannot be read: {err}") from None
    batch: list[RawFrame] = []
    try:
        for msg in reader:
            if msg.is_error_frame:
                if errors is not None:
                    errors[0] += 1
                continue
            if msg.is_remote_frame:
                if errors is not None and len(errors) > 1:
                    errors[1] += 1
                continue
            batch.append(message_to_frame(msg))
            if len(batch) >= batch_frames:
                yield batch
                batch = []
    except (ValueError, OSError, EOFError) as err:
        raise SourceError(
            f"CAN log {str(p)!r}: unreadable after {len(batch)} frames of the current batch ({err})"
        ) from None
    finally:
        stop = getattr(reader, "stop", None)
        if stop is not None:
            stop()
    if batch:
        yield batch


class CanLogSource(CanFrameSource):
    """A CAN log decoded with a DBC plan (see :func:`open_can_log`)."""

    def __init__(
        self,
        path: str | Path,
        plan: CanPlan,
        options: DecoderOptions | None = None,
        batch_frames: int = 5000,
        frame_listener: Callable[[list[RawFrame]], None] | None = None,
    ) -> None:
        self.path = Path(path)
        self._errors = [0, 0]  # error frames, remote frames
        self.frame_listener = frame_listener  # the recorder: a recording keeps the raw frames
        super().__init__(
            plan,
            self._batches_with_errors(batch_frames),
            options,
            {"source": "can-log", "file": str(self.path)},
        )

    def _batches_with_errors(self, batch_frames: int) -> Iterator[list[RawFrame]]:
        for batch in read_frames(self.path, batch_frames, self._errors):
            self.decoder.stats.bus_errors = self._errors[0]
            if self.frame_listener is not None:
                self.frame_listener(batch)
            yield batch
        self.decoder.stats.bus_errors = self._errors[0]

    def _iter_items(self) -> Iterator[StreamItem]:
        yield from super()._iter_items()
        # a log from another bench (a vendor's demo file): say what was expected and what came
        where = f"CAN log {str(self.path)!r}"
        if self.decoder.stats.frames_in == 0:
            raise SourceError(
                f"{where} holds no CAN data frames ({self._errors[1]} remote frames, "
                f"{self._errors[0]} error frames)"
            )
        mismatch = self.decoder.stats.nothing_matched(self.decoder.plan.describe(), where)
        if mismatch is not None:
            raise SourceError(mismatch)


def open_can_log(
    path: str | Path, settings: CanSettings, needs: Sequence[ChannelNeed], **overrides: Any
) -> CanLogSource:
    """``--source file:run.blf``: the channels ``needs`` decoded from the log.

    The DBC is ``settings.dbc`` (the bench file's ``[can] dbc``) unless the override
    ``dbc`` names another.

    Overrides: ``dbc``, ``reorder_window_s``, ``frame_listener`` (called with every
    batch of raw frames: the recorder), ``block_s`` (ignored: a log's batches are
    frames, not seconds).
    """
    known = {"dbc", "reorder_window_s", "block_s", "frame_listener"}
    bad = sorted(set(overrides) - known)
    if bad:
        raise SourceError(
            f"source 'file:{path}': unknown option {bad[0]!r}; known: {', '.join(sorted(known))}"
        )
    if not Path(path).is_file():
        raise SourceError(f"CAN log {str(path)!r} not found")
    dbc = overrides.get("dbc")
    plan = load_plan(needs, settings.dbc if dbc is None else dbc)
    opts = DecoderOptions(
        reorder_window_s=float(overrides.get("reorder_window_s", DecoderOptions.reorder_window_s))
    )
    return CanLogSource(path, plan, opts, frame_listener=overrides.get("frame_listener"))


class FrameLogWriter:
    """Writes raw frames to a CAN log chosen by extension (python-can's writers, TRC our own)."""

    def __init__(self, path: str | Path) -> None:
        import can  # on use: python-can loads its interfaces

        self.path = Path(path)
        suffix = log_suffix(self.path)
        self._trc: IO[str] | None = None
        self._logger: Any = None
        self.count = 0
        if suffix == ".trc":
            gz = self.path.suffix.lower() == ".gz"
            self._trc = (
                gzip.open(self.path, "wt", encoding="ascii")
                if gz
                else self.path.open("w", encoding="ascii")
            )
            self._t0: float | None = None
        elif suffix in (".blf", ".asc", ".log", ".mf4"):
            try:
                self._logger = can.Logger(str(self.path))
            except (ValueError, OSError, ImportError) as err:
                raise SourceError(f"cannot write CAN log {str(self.path)!r}: {err}") from None
        else:
            raise SourceError(
                f"CAN log {str(self.path)!r}: expected .blf, .asc, .trc, .log or .mf4 "
                "(the first four also gzip-compressed, .asc.gz)"
            )

    def write(self, frame: RawFrame) -> None:
        if self._trc is not None:
            self._write_trc(frame)
        else:
            self._logger.on_message_received(frame_to_message(frame, channel=0))
        self.count += 1

    def _write_trc(self, f: RawFrame) -> None:
        assert self._trc is not None
        t = f.timestamp_ns * 1e-9
        if self._t0 is None:
            self._t0 = t
            start = datetime.fromtimestamp(t, UTC) - datetime(1899, 12, 30, tzinfo=UTC)
            self._trc.write(
                ";$FILEVERSION=2.1\n"
                f";$STARTTIME={start / timedelta(days=1)!r}\n"
                ";$COLUMNS=N,O,T,B,I,d,R,L,D\n"
                ";   written by ptinertia (CAN FD frames: type FB, L = DLC code)\n"
            )
        n = len(f.data)
        if n not in DLC_SIZES:
            raise SourceError(f"TRC: a CAN frame cannot hold {n} bytes")
        dlc = DLC_SIZES.index(n)
        kind = "FB" if f.is_fd else "DT"
        ident = f"{f.arbitration_id:08X}" if f.is_extended_id else f"{f.arbitration_id:04X}"
        data = " ".join(f"{b:02X}" for b in f.data)
        offset_ms = (t - self._t0) * 1e3
        self._trc.write(
            f"{self.count + 1:7d} {offset_ms:13.3f} {kind} 1 {ident} Rx - {dlc:2d} {data}\n"
        )

    def close(self) -> None:
        if self._trc is not None:
            self._trc.close()
            self._trc = None
        if self._logger is not None:
            self._logger.stop()
            self._logger = None

    def __enter__(self) -> FrameLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_can_log(path: str | Path, frames: Iterable[RawFrame]) -> int:
    """Write ``frames`` to ``path``; return how many."""
    with FrameLogWriter(path) as w:
        for f in frames:
            w.write(f)
        return w.count
