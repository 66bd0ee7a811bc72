"""Figures of campaigns and studies (matplotlib, Agg: no display needed).

:func:`plot_campaign`: each term across the logs with its 95 % interval.
:func:`plot_study`: each term's error over the runs with its 95 % interval, one
colour per sensor layout, and per layout the bias, spread and coverage.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from estimator.result import Z95

# display unit of each term kind: (scale from SI, label)
DISPLAY = {"kgm2": (1.0, "kg m^2"), "m": (1e3, "mm"), "kg": (1.0, "kg")}


def _pyplot() -> Any:
    # imported here: matplotlib is heavy and only the figures need it; Agg draws without a display
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _grid(n: int) -> tuple[int, int]:
    cols = min(3, n)
    return math.ceil(n / cols), cols


def plot_campaign(
    names: Sequence[str],
    series: dict[str, tuple[str, list[tuple[int, float, float | None]]]],
    path: Path,
) -> None:
    """One panel per term: its value per log with the 95 % interval; failed logs left blank.

    ``names``: the logs; ``series[term] = (unit, [(log index, value, std), ...])``, SI units
    (``unit`` one of ``kgm2``, ``m``, ``kg``).
    """
    plt = _pyplot()
    rows, cols = _grid(max(1, len(series)))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), squeeze=False)
    for ax, (term, (unit, points)) in zip(axes.flat, series.items(), strict=False):
        scale, label = DISPLAY[unit]
        xs = [i for i, _, _ in points]
        ys = [scale * v for _, v, _ in points]
        ci = [scale * Z95 * s if s is not None and math.isfinite(s) else 0.0 for _, _, s in points]
        ax.errorbar(xs, ys, yerr=ci, fmt="o", ms=3, capsize=2)
        ax.set_title(f"{term} ({label})", fontsize=9)
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels(names if len(names) <= 20 else [], rotation=60, fontsize=6)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(series) :]:
        ax.set_visible(False)
    fig.suptitle(f"campaign: {len(names)} logs; bars: 95 % interval", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_study(
    errors: dict[str, dict[str, list[tuple[float, float]]]],
    units: dict[str, str],
    coverage: dict[str, dict[str, float]],
    path: Path,
) -> None:
    """One panel per term: each run's error with its 95 % interval, a colour per layout.

    ``errors[layout][term]``: ``(error, std)`` per run, SI units; ``units[term]``: ``kgm2``,
    ``m`` or ``kg``; ``coverage[layout][term]``: the share of runs whose interval holds
    the truth.
    """
    plt = _pyplot()
    layouts = list(errors)
    terms = list(next(iter(errors.values()))) if errors else []
    rows, cols = _grid(max(1, len(terms)))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), squeeze=False)
    width = 0.8 / max(1, len(layouts))
    for ax, term in zip(axes.flat, terms, strict=False):
        scale, label = DISPLAY[units[term]]
        for k, layout in enumerate(layouts):
            runs = errors[layout].get(term, [])
            xs = [i + (k - (len(layouts) - 1) / 2) * width for i in range(len(runs))]
            ys = [scale * e for e, _ in runs]
            ci = [scale * Z95 * s if math.isfinite(s) else 0.0 for _, s in runs]
            ax.errorbar(
                xs,
                ys,
                yerr=ci,
                fmt="o",
                ms=2,
                capsize=1,
                label=f"{layout}: cover {100 * coverage[layout][term]:.0f} %",
            )
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_title(f"{term} error ({label})", fontsize=9)
        ax.set_xlabel("run", fontsize=7)
        ax.legend(fontsize=6)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(terms) :]:
        ax.set_visible(False)
    fig.suptitle("study: error per run, bars: the run's 95 % interval", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
