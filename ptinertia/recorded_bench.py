"""The bench a recording is replayed with.

The one given, or the one recorded in the log with its file paths confined to the log's
own attachments (a recording is input from anywhere); used by replay, campaigns and the
report alike.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path, PurePath

from ptinertia.config import (
    GAS_FILE_KEY,
    Bench,
    bench_file_paths,
    load_bench,
    loads_bench,
    with_bench_paths,
)
from ptinertia.errors import UsageError
from replay.recorded_log import RecordedLog


def replay_bench(
    log: RecordedLog, log_path: Path, bench_path: str | None, mount_scale: bool
) -> tuple[Bench, str]:
    """The bench a log is replayed with, and its text: ``bench_path`` if given, else the
    bench file recorded in the log; ``[estimator] mount_scale`` switched on if asked."""
    if bench_path is not None:
        bench_text = Path(bench_path).read_text(encoding="utf-8")
        bench = load_bench(bench_path)
    else:
        if not log.bench_text:
            raise UsageError(f"{log_path}: the log holds no bench file; give one with --bench")
        bench_text = log.bench_text
        bench = confined_to_attachments(
            loads_bench(bench_text, f"{log_path}:bench.toml"), log.attachments, log_path
        )
    return with_mount_scale(bench, mount_scale), bench_text


def confined_to_attachments(bench: Bench, attachments: dict[str, bytes], log_path: Path) -> Bench:
    """``bench`` (read from a recording) with its file paths resolved to the log's attachments.

    A recording is input from anywhere: a path in its bench file (``[gas] file``,
    ``[can] dbc``) must never open a file of the user's (``../../etc/passwd``).
    A path names an attachment by its last component, which is copied to a
    private temporary directory; a DBC that is not attached is dropped (replay
    reads one only with ``--dbc``); a missing pressure trace is an error.
    """

    def extract(name: str) -> str | None:
        data = attachments.get(PurePath(name).name)
        if data is None or PurePath(name).name in ("", ".", ".."):
            return None
        folder = Path(tempfile.mkdtemp(prefix="ptinertia-attachment-"))
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        path = folder / PurePath(name).name
        path.write_bytes(data)
        return str(path)

    paths = {key: extract(path) for key, path in bench_file_paths(bench).items()}
    if GAS_FILE_KEY in paths and paths[GAS_FILE_KEY] is None:
        raise UsageError(
            f"{log_path}: the recorded bench's [gas] file {bench_file_paths(bench)[GAS_FILE_KEY]!r} "
            "is not attached to the recording (paths in a recording resolve only to its "
            "attachments); give the bench with --bench"
        )
    bench = with_bench_paths(bench, paths)
    return bench


def with_mount_scale(bench: Bench, on: bool) -> Bench:
    """``bench`` with ``[estimator] mount_scale`` switched on when ``on``."""
    if not on:
        return bench
    return bench.model_copy(
        update={"estimator": bench.estimator.model_copy(update={"mount_scale": True})}
    )


def file_attachments(paths: list[str]) -> dict[str, bytes]:
    """The files a run reads besides its data (the DBC it decodes with, the bench's
    pressure trace), as recording attachments (name -> bytes): a replay reads them from
    the log, never from the user's disk (ptinertia.recorded_bench)."""
    out = {}
    for name in paths:
        try:
            out[Path(name).name] = Path(name).read_bytes()
        except OSError:
            pass  # the source or the gas model names an unreadable file in its own error
    return out
