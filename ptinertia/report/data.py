"""Everything a report shows, gathered from a recording or a result document.

Three inputs, one :class:`ReportData`:

* a recording of a run (``ptinertia run --record``, ``replay --record``): the
  frames, the gating decisions, the published estimates and the final result
  are read back as recorded, nothing is recomputed;
* a raw-only recording (``simulate --out x.mcap``, a crashed run whose final
  estimate was lost): the caller's ``reprocess`` (:mod:`ptinertia.reprocess`) runs
  the chain on it first, with the bench file stored in the log (as
  ``ptinertia replay`` would), and the report says so;
* a result document (``run --json``): only the final estimate; with ``--bench``
  also the modes and the predicted order amplitudes, but nothing measured.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from estimator.result import Estimate, EstimateUpdate
from ptinertia import config
from ptinertia.errors import UsageError
from ptinertia.recorded_bench import replay_bench
from ptinertia.reprocess import Reprocessed
from ptinertia.runner import result_truth
from replay.reader import open_log

# runs the chain over a recording: (log, bench, bench text, where) -> the processed run
Reprocess = Callable[[Any, config.Bench, str, str], Reprocessed]


@dataclass(frozen=True)
class FrameSeries:
    """Order frames as arrays.

    Attributes
    ----------
    time_s, rpm : (n,) s and rev/min.
    orders : tracked orders; channels : channel names.
    amplitudes : (n, n_o, n_ch) complex m/s^2, NaN where the channel was not valid.
    ambiguous : (n,) bool, no 720 deg reference (half-order sign unknown).
    """

    time_s: np.ndarray
    rpm: np.ndarray
    orders: tuple[float, ...]
    channels: tuple[str, ...]
    amplitudes: np.ndarray
    ambiguous: np.ndarray

    def __len__(self) -> int:
        return int(self.rpm.size)


@dataclass(frozen=True)
class GatingSeries:
    """What the estimator did with each frame (same frames as :class:`FrameSeries`).

    Attributes
    ----------
    used : (n, n_o) bool, the order went into the estimate.
    reason : (n,) why the whole frame was rejected ("" when used).
    order_reason : (n, n_o) why an order was rejected ("" when used or not looked at).
    residual : (n, n_o) relative rigid-body fit residual (NaN where not computed).
    """

    used: np.ndarray
    reason: tuple[str, ...]
    order_reason: np.ndarray
    residual: np.ndarray


@dataclass(frozen=True)
class ConvergenceSeries:
    """The published estimates: (n_u,) time and rpm, (n_u, n_p) value and std per name."""

    time_s: np.ndarray
    rpm: np.ndarray
    names: tuple[str, ...]
    value: np.ndarray
    std: np.ndarray

    def column(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        i = self.names.index(name)
        return self.value[:, i], self.std[:, i]


@dataclass
class ReportData:
    """The report's input.

    Attributes
    ----------
    source_path : the file given.
    kind : ``run recording``, ``raw recording (estimated by the report)`` or ``result document``.
    bench, bench_text : the bench file (None for a result document without ``--bench``).
    result : the final result document (``Estimate.to_json``), None when there is no estimate.
    final : the final estimate with its full covariance (recordings only).
    truth : the simulated truth in the result document's shape, None for real data.
    settings : dsp and estimator settings of the run.
    frames, gating, convergence : None for a result document.
    notes : lines for the reader (what was recovered, what was recomputed).
    no_estimate : why there is no estimate (None when there is one).
    source_spec : the run's source (``sim``, ``file:...``, ``can:...``).
    """

    source_path: Path
    kind: str
    bench: config.Bench | None
    bench_text: str | None
    result: dict[str, Any] | None
    final: Estimate | None
    truth: dict[str, Any] | None
    settings: dict[str, Any]
    frames: FrameSeries | None = None
    gating: GatingSeries | None = None
    convergence: ConvergenceSeries | None = None
    notes: list[str] = field(default_factory=list)
    no_estimate: str | None = None
    source_spec: str = ""


def frame_series(frames: list[Any]) -> FrameSeries | None:
    """Stack recorded ``OrderFrame`` objects (None when there are none)."""
    if not frames:
        return None
    orders, channels = frames[0].orders, frames[0].channels
    amps = np.full((len(frames), len(orders), len(channels)), np.nan + 0j)
    for i, f in enumerate(frames):
        if f.orders != orders or f.channels != channels:
            continue  # a frame of another layout cannot share the plots; it stays NaN
        a = np.array(f.amplitudes, dtype=complex)
        a[:, ~np.asarray(f.channel_ok, bool)] = np.nan
        amps[i] = a
    return FrameSeries(
        time_s=np.array([f.time_s for f in frames], float),
        rpm=np.array([f.rpm for f in frames], float),
        orders=tuple(float(h) for h in orders),
        channels=tuple(channels),
        amplitudes=amps,
        ambiguous=np.array(["cycle_ambiguous" in f.flags for f in frames], bool),
    )


def gating_series(outcomes: list[Any], frames: FrameSeries) -> GatingSeries:
    """Gating decisions matched to the frames by time (a frame without one: not looked at)."""
    n, n_o = len(frames), len(frames.orders)
    used = np.zeros((n, n_o), bool)
    order_reason = np.full((n, n_o), "", dtype=object)
    residual = np.full((n, n_o), np.nan)
    reason = ["not recorded"] * n
    index = {round(float(t), 9): i for i, t in enumerate(frames.time_s)}
    for o in outcomes:
        i = index.get(round(float(o.time_s), 9))
        if i is None:
            continue
        reason[i] = o.reason or ""
        for k, h in enumerate(frames.orders):
            used[i, k] = h in o.used_orders
            order_reason[i, k] = o.rejected.get(h, "")
            if h in o.relative_residual:
                residual[i, k] = o.relative_residual[h]
    return GatingSeries(used, tuple(reason), order_reason, residual)


def convergence_series(updates: list[EstimateUpdate]) -> ConvergenceSeries | None:
    if not updates:
        return None
    names = updates[0].estimate.names
    keep = [u for u in updates if u.estimate.names == names]
    return ConvergenceSeries(
        time_s=np.array([u.time_s for u in keep]),
        rpm=np.array([u.rpm for u in keep]),
        names=tuple(names),
        value=np.array([[u.estimate.value(n) for n in names] for u in keep]),
        std=np.array([[u.estimate.std(n) for n in names] for u in keep]),
    )


def why_no_estimate(gating: GatingSeries | None, frames: FrameSeries | None) -> str:
    """One line: why no frame made it into an estimate."""
    if frames is None or len(frames) == 0:
        return "no order frame was produced (no tacho signal, or the recording is too short)"
    assert gating is not None
    counts: dict[str, int] = {}
    for r in gating.reason:
        if r:
            counts[r] = counts.get(r, 0) + 1
    detail = ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
    return (
        f"none of the {len(frames)} order frames ({np.nanmin(frames.rpm):.0f}-"
        f"{np.nanmax(frames.rpm):.0f} rpm) passed the estimator's gates: {detail or 'unknown'}"
    )


def _truth_doc(truth: Any) -> dict[str, Any] | None:
    return result_truth(truth) if isinstance(truth, dict) else None


def load_recording(
    path: Path, bench_path: str | None = None, reprocess: Reprocess | None = None
) -> ReportData:
    """A :class:`ReportData` from an MCAP recording.

    A raw-only log, or any log with another bench file (``bench_path``), is processed
    by ``reprocess`` first (the app's :func:`ptinertia.reprocess.reprocess_log`).
    """
    log = open_log(path)
    bench, bench_text = replay_bench(log, path, bench_path or None, mount_scale=False)
    # A run's recording carries its settings; a raw-only one has none ({}).
    if log.settings and not bench_path:
        data = _from_run_log(path, log, bench, bench_text, list(log.frames()))
    else:
        if reprocess is None:
            why = "--bench given" if bench_path else "a raw-only recording"
            raise UsageError(
                f"{path}: {why}: the chain must run on it first, and no reprocess was given "
                "(ptinertia.reprocess.reprocess_log)"
            )
        processed = reprocess(log, bench, bench_text, str(path))
        data = _from_reprocessed(path, log, bench, bench_text, processed, bool(bench_path))
    data.notes = [*log.report.lines(), *data.notes]
    return data


def _from_run_log(
    path: Path, log: Any, bench: config.Bench, text: str, frames_list: list[Any]
) -> ReportData:
    frames = frame_series(frames_list)
    gating = gating_series(list(log.outcomes()), frames) if frames is not None else None
    convergence = convergence_series(list(log.estimates()))
    final = log.final_estimate()
    result = log.result
    notes = []
    if result is None and final is not None:
        result = final.to_json()
        notes.append(
            "the run's result document was not in the log: rebuilt from its final estimate"
        )
    elif result is None and convergence is not None:
        # a run cut short (killed, power cut) keeps its published estimates
        last = list(log.estimates())[-1]
        final = last.estimate
        result = final.to_json()
        notes.append(
            f"the run ended without a final estimate: showing the last published one "
            f"(t = {last.time_s:.2f} s, {last.rpm:.0f} rpm)"
        )
    truth = _truth_doc(log.truth)
    if result is not None and truth is not None:
        result = {**result, "truth": truth}
    return ReportData(
        source_path=path,
        kind="run recording",
        bench=bench,
        bench_text=text,
        result=result,
        final=final,
        truth=truth,
        settings=dict(log.settings),
        frames=frames,
        gating=gating,
        convergence=convergence,
        notes=notes,
        no_estimate=None if result is not None else why_no_estimate(gating, frames),
        source_spec=log.source,
    )


def _from_reprocessed(
    path: Path, log: Any, bench: config.Bench, text: str, run: Reprocessed, rerun_reason: bool
) -> ReportData:
    frames = frame_series(run.frames)
    gating = gating_series(run.outcomes, frames) if frames is not None else None
    why = (
        "--bench given: the estimate was recomputed from the raw data with that bench file"
        if rerun_reason
        else "raw-only recording: the estimate was computed by the report from the raw data, "
        "with the bench file stored in the log (as `ptinertia replay` would)"
    )
    truth = _truth_doc(log.truth)
    return ReportData(
        source_path=path,
        kind="raw recording (estimated by the report)",
        bench=bench,
        bench_text=text,
        result=run.result,
        final=run.final,
        truth=truth,
        settings=run.settings,
        frames=frames,
        gating=gating,
        convergence=convergence_series(run.updates),
        notes=[why],
        no_estimate=None if run.result is not None else why_no_estimate(gating, frames),
        source_spec=log.source,
    )


def load_result(path: Path, bench_path: str | None = None) -> ReportData:
    """A :class:`ReportData` from a result document (``run --json``)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise UsageError(f"{path}: not a readable result document ({err})") from None
    if not isinstance(doc, dict) or "inertia_kgm2" not in doc:
        raise UsageError(f"{path}: not a ptinertia result document (no 'inertia_kgm2' key)")
    bench = config.load_bench(bench_path) if bench_path else None
    text = Path(bench_path).read_text(encoding="utf-8") if bench_path else None
    notes = ["result document only: no frames, no convergence history, no measured orders"]
    if bench is None:
        notes.append("no --bench given: no modes and no re-simulation")
    return ReportData(
        source_path=path,
        kind="result document",
        bench=bench,
        bench_text=text,
        result=doc,
        final=None,
        truth=doc.get("truth"),
        settings={},
        notes=notes,
        source_spec=str(doc.get("source", "")),
    )


def load(
    path: str | Path, bench_path: str | None = None, reprocess: Reprocess | None = None
) -> ReportData:
    """Dispatch on the file: ``.json`` is a result document, anything else a recording
    (``reprocess``: see :func:`load_recording`)."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{path}: no such file")
    if path.suffix.lower() == ".json":
        return load_result(path, bench_path)
    return load_recording(path, bench_path, reprocess)
