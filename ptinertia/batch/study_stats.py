"""A study's figures: per term the bias, spread, worst error and 95 % interval coverage.

Computed on the client from the runs in run order, so they are the same
whatever the number of workers. Layouts are ranked by their inertia error: the
root mean square over runs and the six terms, in % of the mean principal moment
(so the small products do not weigh more than the moments they are read against).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimator.result import Z95
from powertrain.rigidbody import TERMS as INERTIA
from ptinertia.outputs import atomic_output


def unit_of(term: str) -> str:
    if term in INERTIA:
        return "kgm2"
    return "kg" if term == "mass" else "m"


@dataclass(frozen=True)
class TermStats:
    """One term over the runs of one layout; errors are estimate - truth, SI units.

    ``bias``: mean error; ``spread``: its standard deviation (ddof 1); ``worst``: the
    error of largest magnitude (signed); ``coverage``: share of runs whose 95 %
    interval holds the truth; ``mean_ci95``: the mean half-width of those intervals
    (what the estimator claims); ``truth``: the term's true value (of the first run).
    """

    term: str
    unit: str
    runs: int
    truth: float
    bias: float
    spread: float
    worst: float
    coverage: float
    mean_ci95: float


def term_stats(runs: Sequence[dict[str, tuple[float, float, float]]]) -> dict[str, TermStats]:
    """Per term over ``runs`` (each ``term -> (estimate, std, truth)``, failed runs left out)."""
    out: dict[str, TermStats] = {}
    terms = list(dict.fromkeys(t for r in runs for t in r))
    for term in terms:
        rows = np.array([r[term] for r in runs if term in r], dtype=float)
        err = rows[:, 0] - rows[:, 2]
        std = rows[:, 1]
        ci = Z95 * std
        covered = np.isfinite(ci) & (np.abs(err) <= ci)
        out[term] = TermStats(
            term=term,
            unit=unit_of(term),
            runs=len(rows),
            truth=float(rows[0, 2]),
            bias=float(np.mean(err)),
            spread=float(np.std(err, ddof=1)) if len(rows) > 1 else math.nan,
            worst=float(err[np.argmax(np.abs(err))]),
            coverage=float(np.mean(covered)),
            mean_ci95=float(np.mean(ci[np.isfinite(ci)])) if np.isfinite(ci).any() else math.nan,
        )
    return out


def inertia_score_pct(runs: Sequence[dict[str, tuple[float, float, float]]]) -> float:
    """RMS inertia error over runs and terms, in % of the mean principal moment (the ranking)."""
    sq: list[float] = []
    for r in runs:
        scale = float(np.mean([r[t][2] for t in ("Ixx", "Iyy", "Izz")]))
        sq.extend(((r[t][0] - r[t][2]) / scale) ** 2 for t in INERTIA)
    return 100.0 * math.sqrt(float(np.mean(sq))) if sq else math.nan


def cog_rms_mm(runs: Sequence[dict[str, tuple[float, float, float]]]) -> float:
    """RMS length of the cog error vector, mm."""
    sq = [sum((r[g][0] - r[g][2]) ** 2 for g in ("Gx", "Gy", "Gz")) for r in runs]
    return 1e3 * math.sqrt(float(np.mean(sq))) if sq else math.nan


def _pct(value: float, truth: float) -> str:
    return repr(100.0 * value / abs(truth)) if truth else ""


def write_stats(stats: dict[str, dict[str, TermStats]], path: Path) -> None:
    """``study.csv``: one row per layout and term (SI units; %: of the term's own truth)."""
    header = [
        "layout",
        "term",
        "unit",
        "runs",
        "truth",
        "bias",
        "spread",
        "worst",
        "coverage95",
        "mean_ci95",
        "bias_pct",
        "spread_pct",
        "worst_pct",
    ]
    rows = []
    for layout, per_term in stats.items():
        for s in per_term.values():
            rows.append(
                [
                    layout,
                    s.term,
                    s.unit,
                    s.runs,
                    repr(s.truth),
                    repr(s.bias),
                    repr(s.spread),
                    repr(s.worst),
                    repr(s.coverage),
                    repr(s.mean_ci95),
                    _pct(s.bias, s.truth),
                    _pct(s.spread, s.truth),
                    _pct(s.worst, s.truth),
                ]
            )
    _write_csv(path, header, rows)


def write_runs(
    draws: Sequence[dict[str, Any]],
    results: Mapping[str, Sequence[Any]],
    path: Path,
) -> None:
    """``runs.csv``: each run of each layout, its draws and each term's error (or its error line)."""
    keys = list(dict.fromkeys(k for d in draws for k in d))
    terms = list(
        dict.fromkeys(
            t for per in results.values() for r in per if r.error is None for t in r.terms
        )
    )
    header = ["layout", "run", *keys, "status", *(f"{t}_error" for t in terms), "error"]
    rows = []
    for layout, per in results.items():
        for i, (draw, r) in enumerate(zip(draws, per, strict=True)):
            cells = [layout, i, *(repr(draw.get(k, "")) for k in keys)]
            cells.append("ok" if r.error is None else "failed")
            cells += [repr(r.terms[t][0] - r.terms[t][2]) if t in r.terms else "" for t in terms]
            cells.append(r.error or "")
            rows.append(cells)
    _write_csv(path, header, rows)


def write_ranking(ranking: Sequence[tuple[str, float, float, int]], path: Path) -> None:
    """``layouts.csv``: rank, layout, inertia score %, cog RMS mm, runs with an estimate."""
    rows = [
        [k + 1, name, repr(score), repr(cog), n] for k, (name, score, cog, n) in enumerate(ranking)
    ]
    _write_csv(path, ["rank", "layout", "inertia_rms_pct", "cog_rms_mm", "runs_ok"], rows)


def _write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> None:
    with atomic_output(path) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
