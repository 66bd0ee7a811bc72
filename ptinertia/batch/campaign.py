"""Campaign replay: many MCAP logs re-processed on a Dask cluster, one result per log.

Each task gets a log's path and the replay settings (:class:`ReplayJob`), reads
the log on its worker and runs the same chain as ``ptinertia replay LOG``
(:func:`ptinertia.runner.run_source`), so its result document is the one a
serial replay writes, byte for byte. A log that cannot be replayed (corrupt,
recorded with another bench) comes back as a row carrying its one-line error;
the others complete. The client writes each result as it arrives (atomically),
then the campaign table (CSV, one row per log) and a plot of each term across
the logs with its 95 % interval.
"""

from __future__ import annotations

import csv
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from estimator.result import Z95
from ptinertia.batch.cluster import ClusterSpec, failure_line, open_client, run_tasks
from ptinertia.batch.plots import plot_campaign
from ptinertia.errors import user_error_types
from ptinertia.no_estimate import no_estimate_reason
from ptinertia.outputs import atomic_output
from ptinertia.recorded_bench import replay_bench
from ptinertia.recorded_run import run_recording
from ptinertia.runner import RunOptions, write_json
from replay.reader import open_log

INERTIA_TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
COG_TERMS = ("Gx", "Gy", "Gz")
TABLE_NAME = "campaign.csv"
PLOT_NAME = "campaign.png"


@dataclass(frozen=True)
class ReplayJob:
    """The replay settings every log of a campaign is processed with (what travels to workers).

    ``bench_path``: a bench file overriding the one stored in each log; ``orders``,
    ``corrections_off`` and ``mount_scale`` as ``replay``'s ``--orders``, ``--no`` and
    ``--mount-scale``.
    """

    bench_path: str | None = None
    orders: tuple[float, ...] | None = None
    corrections_off: tuple[str, ...] = ()
    mount_scale: bool = False


@dataclass(frozen=True)
class LogResult:
    """One log's outcome: ``status`` is ``ok``, ``no estimate`` or ``error``."""

    log: str
    status: str
    doc: dict[str, Any] | None = None
    error: str | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)


def replay_log(log_path: str, job: ReplayJob) -> LogResult:
    """Replay one log as ``ptinertia replay LOG --quiet`` does (runs on a worker).

    A user error (unreadable or corrupt log, bench not matching the recorded channels)
    is returned in the result; anything else propagates, so Dask retries it.
    """
    try:
        return _replay(Path(log_path), job)
    except user_error_types() as err:
        return LogResult(log_path, "error", error=str(err))


def _replay(log_path: Path, job: ReplayJob) -> LogResult:
    log = open_log(log_path)
    bench, bench_text = replay_bench(log, log_path, job.bench_path, job.mount_scale)
    options = RunOptions(orders=job.orders, corrections_off=job.corrections_off, quiet=True)
    summary, doc = run_recording(log, str(log_path), bench, bench_text, options)
    warnings = tuple(log.report.lines())
    if doc is None or summary.estimate is None:
        reason = no_estimate_reason(summary.rejected, summary.orders_rejected)
        return LogResult(str(log_path), "no estimate", None, f"no estimate: {reason}", warnings)
    return LogResult(str(log_path), "ok", doc, None, warnings)


def result_path(out_dir: Path, log: str) -> Path:
    """Where a log's result document goes (the name ``replay DIR`` has always used)."""
    return out_dir / (Path(log).stem + ".result.json")


def run_campaign(
    logs: Sequence[Path],
    job: ReplayJob,
    out_dir: Path,
    spec: ClusterSpec,
    progress: bool = True,
    err: TextIO | None = None,
    on_result: Callable[[int, Any], None] | None = None,
) -> list[LogResult]:
    """Replay ``logs`` on the cluster ``spec``; write each result, the table and the plot.

    Returns one :class:`LogResult` per log, in the order of ``logs``. ``on_result(i, r)``
    hears of each log as it completes (``r`` a :class:`LogResult` or the task's exception).
    The progress bar goes to ``err`` (default: the standard error at call time).
    """
    err = sys.stderr if err is None else err
    # imported here: tqdm's bar only for campaigns
    from tqdm import tqdm

    out_dir.mkdir(parents=True, exist_ok=True)
    calls = [(str(p), job) for p in logs]
    with (
        open_client(spec) as client,
        tqdm(total=len(calls), unit="log", disable=not progress, file=err) as bar,
    ):

        def done(i: int, result: Any) -> None:
            if isinstance(result, LogResult) and result.doc is not None:
                write_json(result.doc, result_path(out_dir, result.log))
            bar.update(1)
            if on_result is not None:
                on_result(i, result)

        raw = run_tasks(client, replay_log, calls, on_done=done, key="replay")
    results = [
        r if isinstance(r, LogResult) else LogResult(log, "error", error=failure_line(r))
        for (log, _), r in zip(calls, raw, strict=True)
    ]
    write_table(results, out_dir / TABLE_NAME)
    plot_campaign([Path(r.log).stem for r in results], term_series(results), out_dir / PLOT_NAME)
    return results


def term_values(doc: dict[str, Any]) -> dict[str, tuple[float, float | None, str]]:
    """``term -> (value, std, unit)`` of a result document (inertia, cog, mass if estimated)."""
    out: dict[str, tuple[float, float | None, str]] = {}
    inertia = doc["inertia_kgm2"]
    for name in INERTIA_TERMS:
        out[name] = (inertia["value"][name], inertia["std"][name], "kgm2")
    for i, name in enumerate(COG_TERMS):
        out[name] = (doc["cog_m"]["value"][i], doc["cog_m"]["std"][i], "m")
    if doc.get("mass_kg"):
        out["mass"] = (doc["mass_kg"]["value"], doc["mass_kg"].get("std"), "kg")
    return out


def term_series(
    results: Sequence[LogResult],
) -> dict[str, tuple[str, list[tuple[int, float, float | None]]]]:
    """``term -> (unit, [(log index, value, std), ...])`` over the logs with an estimate."""
    out: dict[str, tuple[str, list[tuple[int, float, float | None]]]] = {}
    for i, r in enumerate(results):
        if r.doc is None:
            continue
        for name, (value, std, unit) in term_values(r.doc).items():
            out.setdefault(name, (unit, []))[1].append((i, value, std))
    return out


def table_rows(results: Sequence[LogResult]) -> tuple[list[str], list[dict[str, Any]]]:
    """The campaign table: header and one row per log."""
    terms: dict[str, str] = {}
    for r in results:
        if r.doc is not None:
            for name, (_, _, unit) in term_values(r.doc).items():
                terms.setdefault(name, unit)
    header = ["log", "status"]
    for name, unit in terms.items():
        header += [f"{name}_{unit}", f"{name}_std_{unit}", f"{name}_ci95_{unit}"]
    header += ["frames_used", "frames_rejected", "rejections", "warnings", "error"]
    rows = []
    for r in results:
        row: dict[str, Any] = {"log": Path(r.log).name, "status": r.status, "error": r.error or ""}
        row["warnings"] = "; ".join(r.warnings)
        if r.doc is not None:
            for name, (value, std, unit) in term_values(r.doc).items():
                row[f"{name}_{unit}"] = repr(value)
                row[f"{name}_std_{unit}"] = "" if std is None else repr(std)
                row[f"{name}_ci95_{unit}"] = "" if std is None else repr(Z95 * std)
            frames = r.doc["frames"]
            row["frames_used"] = frames["used"]
            row["frames_rejected"] = sum(frames["rejected"].values())
            row["rejections"] = "; ".join(f"{k} {v}" for k, v in frames["rejected"].items())
        rows.append(row)
    return header, rows


def write_table(results: Sequence[LogResult], path: Path) -> None:
    """The campaign table as CSV (written atomically, as the results)."""
    header, rows = table_rows(results)
    with atomic_output(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=header, restval="")
        writer.writeheader()
        writer.writerows(rows)


def print_summary(results: Sequence[LogResult], out: TextIO | None = None) -> None:
    """One line per log: its status, and the largest inertia term or the error (to ``out``,
    default the standard output at call time: a default bound at import keeps a stream
    that may be closed by then, as pytest's captured ones are)."""
    out = sys.stdout if out is None else out
    width = max((len(Path(r.log).name) for r in results), default=3)
    for r in results:
        name = Path(r.log).name
        if r.doc is None:
            print(f"{name:{width}}  {r.status:11}  {r.error}", file=out)
            continue
        values = term_values(r.doc)
        cells = "  ".join(
            f"{n} {values[n][0]:.4f} +- {Z95 * (values[n][1] or 0.0):.4f}"
            for n in ("Ixx", "Iyy", "Izz")
        )
        print(f"{name:{width}}  {r.status:11}  {cells} kg m^2", file=out)
