"""``ptinertia report``: one self-contained HTML page a CAE engineer can trust and use.

Sections: the final estimate with 95 % intervals (against the truth or the bench
file's nominal values), its convergence with rpm, the order amplitudes and phases
per sensor axis, the re-simulation check (:mod:`ptinertia.resim`), the rigidity
residual, the rigid-body modes the estimate predicts, what was gated out and the
settings. :func:`build_report` is pure (data in, HTML and PNGs out);
:func:`write_report` puts them on disk.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from ptinertia.outputs import atomic_write, write_error
from ptinertia.progress import work_bar
from ptinertia.report import gating, plots, sections
from ptinertia.report.data import ReportData, Reprocess, load
from ptinertia.report.html import esc, image, page, verdict
from ptinertia.report.stats import (
    parameter_covariance,
)
from ptinertia.resim import resim_check
from ptinertia.resim_compare import ResimCheck


@dataclass
class Report:
    """The rendered report: the page, its figures (name -> PNG) and the check."""

    html: str
    figures: dict[str, bytes] = field(default_factory=dict)
    check: ResimCheck | None = None
    headline: list[str] = field(default_factory=list)


def _sensors(data: ReportData) -> list[tuple[str, list[str]]] | None:
    if data.bench is None:
        return None
    return [(s.name, [c for c in s.channels if c]) for s in data.bench.sensors]


def _resim(data: ReportData) -> ResimCheck | None:
    if data.result is None or data.bench is None or data.frames is None or data.gating is None:
        return None
    f = data.frames
    return resim_check(
        data.bench,
        data.result,
        f.rpm,
        f.orders,
        f.channels,
        f.amplitudes,
        f.ambiguous,
        data.gating.used,
    )


RESIM_METHOD = (
    "The estimated body replaces the bench file's powertrain in the 6-DOF model (same mounts, "
    "engine excitation and nominal sensors{extras}), driven at each frame's rpm. Judged per order "
    "and channel over the mass-line frames (those where the estimator used the order): the 95th "
    "percentile of |difference|. Tolerance-limited channels are axes that the declared sensor "
    "tolerances (gain, alignment, position) already make uncertain by more than the amplitude "
    "limit; they are shown in grey and not judged."
)


def _convergence_section(data: ReportData, figures: dict[str, bytes]) -> str:
    head = "<h2>2. Convergence with rpm</h2>"
    if data.convergence is None:
        return head + "<p>No published estimates in the input.</p>"
    conv = sections.with_mass(data.convergence)
    ref, ref_label = sections.reference(data)
    panels = [*sections.PANELS, *([("mass", "mass, kg", 1.0)] if "mass" in conv.names else [])]
    figures["convergence"] = plots.png(
        plots.convergence(conv, panels, ref, ref_label or "reference")
    )
    caption = (
        "Each term against the rpm of the frames so far, with its 95 % interval (paper Figs. 13/15)"
    )
    return head + image("convergence", figures["convergence"], caption)


def _orders_section(data: ReportData, check: ResimCheck | None, figures: dict[str, bytes]) -> str:
    out = ["<h2>3. Orders and re-simulation</h2>"]
    doc = data.result or {}
    if check is not None:
        extras = (", plus the estimated residual unbalance" if doc.get("unbalance") else "") + (
            ", with the estimated crank reference offset" if doc.get("crank_offset_deg") else ""
        )
        out.append(verdict(check.passed, check.summary()))
        out.append(f'<p class="small">{esc(RESIM_METHOD.format(extras=extras))}</p>')
    elif not doc:
        out.append("<p>No re-simulation: there is no estimate. Measured orders only.</p>")
    elif data.frames is not None:
        out.append("<p>No re-simulation: the input has no bench file.</p>")
    f = data.frames
    if f is None or not len(f):
        return "".join([*out, "<p>No measured order frames in the input.</p>"])
    meas = check.measured if check is not None else f.amplitudes
    chans = check.channels if check is not None else f.channels
    pred = None if check is None else check.predicted
    for k, h in enumerate(f.orders):
        name = f"order-{h:g}".replace(".", "_")
        span = check.mass_line_rpm(k) if check is not None else None
        fig = plots.orders_figure(f, k, meas, chans, pred, _sensors(data), span)
        figures[name] = plots.png(fig)
        caption = f"Order {h:g}: amplitude and phase per sensor axis (paper Fig. 11); shaded: mass-line range"
        out.append(image(name, figures[name], caption))
    if check is not None:
        figures["resim"] = plots.png(plots.resim_difference(check))
        caption = "Re-simulated against measured, dB and degrees (paper Figs. 16/17)"
        out += [image("resim", figures["resim"], caption), sections.resim_table(check)]
    return "".join(out)


def _residual_section(data: ReportData, figures: dict[str, bytes]) -> str:
    head = "<h2>4. Rigidity residual</h2>"
    if data.frames is None or data.gating is None or not len(data.frames):
        return head + "<p>No gating record in the input.</p>"
    gates = (data.settings.get("estimator") or {}).get("gates") or {}
    fig = plots.residual(data.frames, data.gating, gates.get("max_relative_residual"))
    figures["residual"] = plots.png(fig)
    caption = (
        "Relative residual of the rigid-body fit per order (rising: an elastic mode approaches)"
    )
    return head + image("residual", figures["residual"], caption)


SECTIONS = ("estimate", "convergence", "orders", "residual", "modes", "gating")


def _no_step(name: str) -> None:
    """Where a progress bar is not wanted."""


def build_report(data: ReportData, step: Callable[[str], None] = _no_step) -> Report:
    """Render the report (pure: no file is written).

    ``step(name)`` is called before each section of :data:`SECTIONS` (a progress bar's hook).
    """
    try:
        ver = version("ptinertia")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree
        ver = "unknown"
    figures: dict[str, bytes] = {}
    doc = data.result
    title = f"ptinertia report: {data.bench.meta.name if data.bench else data.source_path.name}"
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    head = [
        f"<h1>{esc(title)}</h1>",
        f'<p class="small">Input {esc(data.source_path.name)} ({esc(data.kind)}), source '
        f"{esc(data.source_spec or 'unknown')}; ptinertia {esc(ver)}; generated {esc(stamp)}.</p>",
    ]
    step("estimate")
    pc = parameter_covariance(doc, data.final) if doc is not None else None
    check = _resim(data)
    headline: list[str] = []
    summary = ['<div class="box">']
    if doc is None or pc is None:
        why = data.no_estimate or "no usable frame"
        headline.append(f"NO ESTIMATE: {why}")
        summary.append(f'<p class="bad">No estimate: {esc(why)}.</p>')
        estimate = f'<h2>1. Estimate</h2><p class="bad">No estimate: {esc(why)}.</p>'
    else:
        lo, hi = doc["rpm_range"] or (math.nan, math.nan)
        headline.append(f"estimate from {doc['frames']['used']} frames, {lo:.0f}-{hi:.0f} rpm")
        summary.append(f"<p>{esc(headline[-1])}.</p>")
        estimate = sections.estimate_section(data, pc)
    if check is not None:
        headline.append(check.summary())
        summary.append(verdict(check.passed, check.summary()))
    summary.append("</div>")
    makers: list[tuple[str, Callable[[], str]]] = [
        ("convergence", lambda: _convergence_section(data, figures)),
        ("orders", lambda: _orders_section(data, check, figures)),
        ("residual", lambda: _residual_section(data, figures)),
        ("modes", lambda: sections.modes_section(data, pc, figures)),
        ("gating", lambda: gating.gating_section(data, figures)),
    ]
    body = [estimate]
    for name, make in makers:
        step(name)
        body.append(make())
    body.append(sections.settings_section(data))
    return Report(page(title, [*head, "".join(summary), *body]), figures, check, headline)


def write_report(report: Report, out: str | Path, png_dir: str | Path | None = None) -> list[Path]:
    """Write the HTML (atomically) and, when asked, every figure as ``NAME.png``; returns the paths."""
    out = Path(out)
    atomic_write(out, report.html)
    written = [out]
    if png_dir is not None:
        d = Path(png_dir)
        try:
            d.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise write_error(d, err) from None
        for name, data in report.figures.items():
            p = d / f"{name}.png"
            atomic_write(p, data)
            written.append(p)
    return written


def make_report(
    path: str | Path,
    out: str | Path,
    bench: str | None = None,
    png_dir: str | Path | None = None,
    reprocess: Reprocess | None = None,
    progress: bool = False,
) -> Report:
    """Load, render and write: what ``ptinertia report`` does (``reprocess``: runs the chain
    on a recording that needs it, see :func:`ptinertia.report.data.load_recording`).

    ``progress``: a bar on stderr, by stage, when the work takes more than a second
    (a 60 s run's report: about 5 s, most of it drawing the figures).
    """
    bar = work_bar(2 + len(SECTIONS), "report", unit="step") if progress else None

    def step(name: str) -> None:
        if bar is not None:
            bar.set_postfix_str(name, refresh=False)
            bar.update(1)

    try:
        step("reading the input")
        data = load(path, bench, reprocess)
        report = build_report(data, step)
        step("writing")
        write_report(report, out, png_dir)
    finally:
        if bar is not None:
            bar.close()
    return report
