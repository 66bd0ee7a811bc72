"""The report's figures, drawn with matplotlib (Agg) and returned as PNG bytes.

One function per figure; each takes plain arrays or the report's dataclasses and
never reads files. PNGs are small (100 dpi, no transparency) so a 60 s sweep's
report stays well under a few MB with every figure embedded.

Text size. An 11 in figure at 100 dpi is 1100 px wide, shown unscaled in the
report's 1150 px column; no text is smaller than ``MIN_FONT`` (7 pt = 9.7 px
there: at 80 dpi and 6 pt, legends were 6.7 px, hard to read). :func:`png`
writes the smallest text's pixel size into the PNG (``tEXt`` key
``ptinertia:smallest-text-px``), which the browser test checks against the
size the page shows the image at.
"""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np

# Figure objects without pyplot: no global backend switch, no figure registry to leak.
from matplotlib.figure import Figure
from matplotlib.text import Text

from estimator.result import Z95
from ptinertia.report.data import ConvergenceSeries, FrameSeries, GatingSeries
from ptinertia.report.stats import ModeStats
from ptinertia.resim_compare import ResimCheck

DPI = 100
MIN_FONT = 7.0  # pt: 9.7 px at DPI 100
SMALLEST_TEXT_KEY = "ptinertia:smallest-text-px"
MARGINS = {"left": 0.07, "right": 0.98, "top": 0.9, "bottom": 0.1, "hspace": 0.3, "wspace": 0.25}
AXIS_COLORS = ("tab:blue", "tab:orange", "tab:green")
ORDER_COLORS = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:olive")


# Every title is placed with an explicit ``y``: matplotlib then skips measuring the tick
# labels' bounding boxes to auto-place it, a third of a report's drawing time.


def png(fig: Figure) -> bytes:
    """The figure as PNG bytes (rendered by the Agg canvas), with its smallest text size in px."""
    buf = io.BytesIO()
    fig.savefig(
        buf, format="png", dpi=DPI, metadata={SMALLEST_TEXT_KEY: f"{smallest_text_px(fig):.2f}"}
    )
    return buf.getvalue()


def smallest_text_px(fig: Figure) -> float:
    """Font size in px of the smallest visible, non-empty text of the figure (at ``DPI``)."""
    sizes = [
        float(t.get_fontsize())
        for t in fig.findobj(Text)
        if t.get_visible() and t.get_text().strip() and _drawn(t)
    ]
    return min(sizes, default=math.inf) * DPI / 72.0


def _drawn(text: Text) -> bool:
    """Tick labels exist for every tick position; only those on a visible tick are drawn."""
    parent = text.axes
    return parent is None or parent.get_visible()


def _subplots(
    rows: int = 1,
    cols: int = 1,
    figsize: tuple[float, float] = (8, 4),
    margins: dict[str, float] | None = None,
    **kw: Any,
) -> tuple[Figure, Any]:
    # Fixed margins, not constrained layout: it halves the rendering time of a report.
    fig = Figure(figsize=figsize)
    axes = fig.subplots(rows, cols, **kw)
    fig.subplots_adjust(**{**MARGINS, **(margins or {})})
    return fig, axes


def _shade(ax: Any, span: tuple[float, float] | None) -> None:
    if span is not None:
        ax.axvspan(span[0], span[1], color="0.92", zorder=0, lw=0)


def convergence(
    conv: ConvergenceSeries,
    names: list[tuple[str, str, float]],
    reference: dict[str, float],
    ref_label: str,
) -> Figure:
    """Each term against rpm with its 95 % band (the paper's Figs. 13/15).

    Parameters
    ----------
    names : (parameter name, title with unit, display scale) per panel.
    reference : parameter name -> reference value (SI) drawn as a line (truth or nominal).
    """
    n = len(names)
    cols = 3
    rows = (n + cols - 1) // cols
    h = 2.4 * rows
    fig, axes = _subplots(
        rows, cols, figsize=(11, h), sharex=True, margins={"top": 1 - 0.3 / h, "bottom": 0.45 / h}
    )
    order = np.argsort(conv.time_s)
    rpm = conv.rpm[order]
    for ax, (name, title, scale) in zip(np.ravel(axes), names, strict=False):
        value, std = (c[order] for c in conv.column(name))
        v = value * scale
        half = np.where(np.isfinite(std), Z95 * std * scale, np.nan)
        ax.fill_between(
            rpm, v - half, v + half, color="tab:blue", alpha=0.2, lw=0, label="95 % interval"
        )
        ax.plot(rpm, v, color="tab:blue", lw=1.2, label="estimate")
        if name in reference:
            ax.axhline(reference[name] * scale, color="tab:green", ls="--", lw=1.0, label=ref_label)
        ax.set_title(title, fontsize=9, y=1.0)
        ax.grid(alpha=0.3)
        settled = slice(v.size // 5, None)  # early frames can be far off: zoom on the rest
        lo_b, hi_b = (v - half)[settled], (v + half)[settled]
        ok = np.isfinite(lo_b) & np.isfinite(hi_b)
        if np.count_nonzero(ok) > 4:
            lo, hi = float(np.min(lo_b[ok])), float(np.max(hi_b[ok]))
            ref = reference.get(name)
            if ref is not None:
                lo, hi = min(lo, ref * scale), max(hi, ref * scale)
            pad = 0.1 * max(hi - lo, 1e-9)
            ax.set_ylim(lo - pad, hi + pad)
    for ax in np.ravel(axes)[n:]:
        ax.set_visible(False)
    for ax in np.ravel(axes)[max(0, n - cols) : n]:
        ax.set_xlabel("rpm")
    np.ravel(axes)[0].legend(fontsize=MIN_FONT, loc="best")
    return fig


def _sensor_groups(
    channels: tuple[str, ...], sensors: list[tuple[str, list[str]]] | None
) -> list[tuple[str, list[int]]]:
    if sensors:
        out = []
        for name, chans in sensors:
            idx = [channels.index(c) for c in chans if c in channels]
            if idx:
                out.append((name, idx))
        if out:
            return out
    return [("channels", list(range(len(channels))))]


def orders_figure(
    frames: FrameSeries,
    k: int,
    measured: np.ndarray,
    channels: tuple[str, ...],
    predicted: np.ndarray | None,
    sensors: list[tuple[str, list[str]]] | None,
    span: tuple[float, float] | None,
) -> Figure:
    """Order ``frames.orders[k]``: amplitude (dB re 1 m/s^2) and phase per sensor axis against rpm.

    Measured as thin solid lines, re-simulated (when given) dashed; the mass-line
    range is shaded. (The paper's Fig. 11, and with the re-simulation Figs. 16/17.)
    """
    groups = _sensor_groups(channels, sensors)
    fig, axes = _subplots(
        2,
        len(groups),
        figsize=(min(11.0, 3.9 * len(groups)), 5.0),  # at most the page column
        sharex=True,
        squeeze=False,
    )
    order = np.argsort(frames.rpm)
    rpm = frames.rpm[order]
    for col, (gname, idx) in enumerate(groups):
        ax_a, ax_p = axes[0, col], axes[1, col]
        for ax in (ax_a, ax_p):
            _shade(ax, span)
            ax.grid(alpha=0.3)
        for c, j in enumerate(idx):
            color = AXIS_COLORS[c % 3]
            m = measured[order, k, j]
            with np.errstate(divide="ignore"):
                ax_a.plot(
                    rpm,
                    20 * np.log10(np.abs(m)),
                    color=color,
                    lw=0.8,
                    label=f"{channels[j]} measured",
                )
            ax_p.plot(rpm, np.degrees(np.angle(m)), ".", color=color, ms=1.5)
            if predicted is not None:
                p = predicted[order, k, j]
                with np.errstate(divide="ignore"):
                    ax_a.plot(rpm, 20 * np.log10(np.abs(p)), "--", color="k", lw=0.8, alpha=0.8)
                ph = np.degrees(np.angle(p))
                ph[1:][np.abs(np.diff(ph)) > 180] = np.nan  # no vertical line at the wrap
                ax_p.plot(rpm, ph, "--", color="k", lw=0.8, alpha=0.8)
        ax_a.set_title(gname, fontsize=9, y=1.0)
        ax_a.legend(fontsize=MIN_FONT, loc="lower right")
        ax_p.set_ylim(-180, 180)
        ax_p.set_yticks([-180, -90, 0, 90, 180])
        ax_p.set_xlabel("rpm")
    axes[0, 0].set_ylabel("amplitude, dB re 1 m/s^2")
    axes[1, 0].set_ylabel("phase, deg")
    title = f"order {frames.orders[k]:g}"
    if predicted is not None:
        title += " (dashed: re-simulation with the estimate)"
    fig.suptitle(title, fontsize=10)
    return fig


def resim_difference(check: ResimCheck) -> Figure:
    """Re-simulation minus measurement per order: dB and degrees against rpm, limits marked."""
    n_o = len(check.orders)
    h = 2.5 * n_o + 0.6
    fig, axes = _subplots(
        n_o,
        2,
        figsize=(11, h),
        sharex=True,
        squeeze=False,
        margins={"top": 1 - 0.6 / h, "bottom": 0.45 / h, "left": 0.08},
    )
    order = np.argsort(check.rpm)
    rpm = check.rpm[order]
    for k, h in enumerate(check.orders):
        ax_db, ax_deg = axes[k]
        span = check.mass_line_rpm(k)
        for ax, lim in ((ax_db, check.limit_db), (ax_deg, check.limit_deg)):
            _shade(ax, span)
            ax.axhline(lim, color="tab:red", lw=0.8, ls=":")
            ax.axhline(-lim, color="tab:red", lw=0.8, ls=":")
            ax.grid(alpha=0.3)
        # tolerance-limited axes first and faint, so the judged ones stay readable on top
        for j in np.argsort(check.assessable[k], kind="stable"):
            name = check.channels[j]
            good = bool(check.assessable[k, j])
            style: dict[str, Any] = (
                {"lw": 0.9, "label": name, "zorder": 3}
                if good
                else {"lw": 0.4, "color": "0.7", "alpha": 0.5, "zorder": 2}
            )
            ax_db.plot(rpm, check.diff_db[order, k, j], **style)
            ax_deg.plot(rpm, check.diff_deg[order, k, j], **style)
        ax_db.set_ylim(-4 * check.limit_db, 4 * check.limit_db)
        ax_deg.set_ylim(-4 * check.limit_deg, 4 * check.limit_deg)
        ax_db.set_ylabel(f"H{h:g}: dB")
        ax_deg.set_ylabel(f"H{h:g}: deg")
        if np.any(check.assessable[k]):
            ax_db.legend(fontsize=MIN_FONT, ncol=3, loc="upper right")
    axes[0, 0].set_title("amplitude: 20 log10 |re-simulated / measured|", fontsize=9, y=1.0)
    axes[0, 1].set_title("phase: arg(re-simulated / measured)", fontsize=9, y=1.0)
    axes[-1, 0].set_xlabel("rpm")
    axes[-1, 1].set_xlabel("rpm")
    fig.suptitle(
        "re-simulation check (grey: tolerance-limited axes; shaded: mass-line range; dotted: limits)",
        fontsize=10,
    )
    return fig


def residual(frames: FrameSeries, gating: GatingSeries, gate: float | None) -> Figure:
    """Relative rigid-body fit residual per order against rpm (how rigid the motion is)."""
    fig, ax = _subplots(figsize=(11, 3.2), margins={"bottom": 0.15, "left": 0.09})
    order = np.argsort(frames.rpm)
    for k, h in enumerate(frames.orders):
        r = gating.residual[order, k]
        ax.semilogy(
            frames.rpm[order], r, ".", ms=2, color=ORDER_COLORS[k % 6], label=f"order {h:g}"
        )
    if gate is not None:
        ax.axhline(gate, color="tab:red", ls=":", lw=1, label=f"gate {gate:g}")
    ax.set_xlabel("rpm")
    ax.set_ylabel("residual / signal")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=MIN_FONT, ncol=4)
    ax.set_title(
        "rigidity residual: what a rigid body cannot explain in the 9 channels", fontsize=9, y=1.0
    )
    return fig


def gating(
    frames: FrameSeries, gating: GatingSeries, skipped: tuple[str, ...] = ()
) -> Figure | None:
    """Rejected frames and orders by reason against rpm (None when nothing was left out).

    ``skipped`` are frame reasons that leave a frame out without rejecting it
    (``overlapping``): drawn in grey, labelled ``skipped``, below the rejections.
    """
    rows: list[tuple[str, np.ndarray, str]] = []  # label, rpm, colour
    reasons = np.array(gating.reason, dtype=object)
    for r in sorted({x for x in gating.reason if x and x not in skipped}):
        rows.append((f"frame: {r}", frames.rpm[reasons == r], "tab:red"))
    for k, h in enumerate(frames.orders):
        col = gating.order_reason[:, k]
        for r in sorted({x for x in col if x}):
            rows.append((f"H{h:g}: {r}", frames.rpm[col == r], "tab:red"))
    for r in sorted({x for x in gating.reason if x in skipped}):
        rows.append((f"skipped: {r}", frames.rpm[reasons == r], "0.55"))
    if not rows:
        return None
    h = 0.9 + 0.35 * len(rows)
    fig, ax = _subplots(
        figsize=(11, h), margins={"left": 0.22, "top": 1 - 0.35 / h, "bottom": 0.5 / h}
    )
    for i, (_, rpm, color) in enumerate(rows):
        ax.plot(rpm, np.full(rpm.size, i), "|", ms=8, color=color)
    ax.set_yticks(
        range(len(rows)), [f"{name} ({rpm.size})" for name, rpm, _ in rows], fontsize=MIN_FONT
    )
    for label, (_, _, color) in zip(ax.get_yticklabels(), rows, strict=True):
        label.set_color("tab:red" if color == "tab:red" else "0.35")
    ax.set_ylim(-0.8, len(rows) - 0.2)
    ax.set_xlim(np.nanmin(frames.rpm), np.nanmax(frames.rpm))
    ax.set_xlabel("rpm")
    ax.grid(alpha=0.3, axis="x")
    ax.set_title("what was left out, where", fontsize=9, y=1.0)
    return fig


def campbell(
    modes: ModeStats,
    orders: tuple[float, ...],
    rpm_max: float,
    min_mode_ratio: float | None,
) -> Figure:
    """Campbell diagram: mode frequencies (95 % bands) and order lines from 0 rpm; mass line marked."""
    fig, ax = _subplots(figsize=(11, 3.8), margins={"bottom": 0.13})
    rpm = np.linspace(rpm_max / 100.0, rpm_max, 100)  # log axis: no 0 Hz point
    f_top = max(h * rpm_max / 60.0 for h in orders) * 1.1
    f_low = float(np.min(modes.frequency_hz)) / 1.6
    for j, f in enumerate(modes.frequency_hz):
        c_lo, c_hi = modes.frequency_ci95[j]
        if np.isfinite(c_lo):
            ax.axhspan(c_lo, c_hi, color="tab:gray", alpha=0.25, lw=0)
        ax.axhline(f, color="k", lw=0.7)
        # at the right, where the order lines are far above the modes; staggered for close modes
        x = 0.99 if j % 2 == 0 else 0.8
        ax.text(
            x,
            f,
            f"{j + 1}: {f:.1f} Hz {modes.dominant[j]}",
            va="bottom",
            ha="right",
            fontsize=MIN_FONT,
            transform=ax.get_yaxis_transform(),
        )
    for k, h in enumerate(orders):
        ax.plot(rpm, h * rpm / 60.0, color=ORDER_COLORS[k % 6], lw=1.2, label=f"order {h:g}")
    if min_mode_ratio:
        limit = min_mode_ratio * float(np.max(modes.frequency_hz))
        ax.axhspan(limit, f_top, color="tab:green", alpha=0.07, lw=0)
        ax.axhline(limit, color="tab:green", ls=":", lw=1, label=f"mass line above {limit:.1f} Hz")
    ax.set_yscale("log")
    ax.set_xlim(0, rpm_max)
    ax.set_ylim(f_low, f_top)
    ax.set_xlabel("rpm")
    ax.set_ylabel("Hz")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=MIN_FONT, loc="upper left")
    ax.set_title(
        "rigid-body modes with the estimated properties, and the engine orders", fontsize=9, y=1.0
    )
    return fig
