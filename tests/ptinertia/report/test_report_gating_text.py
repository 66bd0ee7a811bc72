"""What the report says about the unbalance and the left-out frames, and how large it writes.

An undetected unbalance has no angle; the gating chart and table list the same
reasons with the same counts; no text in a figure is drawn under 9 px.
"""

from __future__ import annotations

import re
import struct

import numpy as np
import pytest
from support.png_text import png_text
from support.report_logs import realistic_log

from ptinertia.report import plots
from ptinertia.report.build import make_report
from ptinertia.report.data import load
from ptinertia.report.gating import SKIPPED
from ptinertia.report.sections import unbalance_line
from ptinertia.runner import unbalance_text


def test_an_undetected_unbalance_has_no_angle() -> None:
    # what the default i3 run's document holds: m r at 3e-10 with a std of 4.6e-5 kg m
    unb = {
        "mr_kgm": {"value": 2.86e-10, "std": 4.62e-5},
        "angle_deg": {"value": 157.3, "std": 16834795.4},
    }
    line = unbalance_line(unb)
    assert "deg" not in line and "157" not in line
    assert line == "residual static unbalance not detected (below 0.092 g m)"
    unb["mr_kgm"] = {"value": 1.2e-3, "std": 1e-4}  # 12 std: detected
    unb["angle_deg"] = {"value": 40.0, "std": 4.8}
    assert (
        unbalance_line(unb)
        == "residual static unbalance 1.200 g m (std 0.100) at 40.0 deg (std 4.8)"
    )


def test_the_unbalance_location_and_couple_follow_the_same_rule() -> None:
    unb = {
        "mr_kgm": {"value": 1.0e-3, "std": 1e-5},
        "angle_deg": {"value": 120.0, "std": 0.6},
        "axial_m": {"value": 0.0801, "std": 0.0012},
        "couple_kgm2": {"value": 3e-6, "std": 2e-6},  # 1.5 std: not detected
        "couple_angle_deg": {"value": 30.0, "std": 0.6},
    }
    assert unbalance_line(unb) == (
        "residual static unbalance 1.000 g m (std 0.010) at 120.0 deg (std 0.6), 80.1 mm "
        "(std 1.2) along the crank axis from the reference point; couple unbalance not "
        "detected (below 0.0040 g m^2)"
    )
    assert unbalance_text(unb) == (
        "residual unbalance 1.000 +- 0.020 g m at 120.0 deg, 80.1 +- 2.4 mm along the crank "
        "axis from the reference point; no couple (below 0.0040 g m^2)"
    )
    # the static part lost in its noise: no angle, no location; a couple of 5 std is shown
    unb.update(mr_kgm={"value": 1e-5, "std": 1e-5}, axial_m=None)
    unb["couple_kgm2"] = {"value": 1e-4, "std": 2e-5}
    line = unbalance_line(unb)
    assert line == (
        "residual static unbalance not detected (below 0.020 g m); couple unbalance 0.1000 "
        "g m^2 (std 0.0200) at 30.0 deg (std 0.6)"
    )
    assert "mm" not in unbalance_text(unb) and "couple 0.1000 +- 0.0392" in unbalance_text(unb)


def test_the_gating_chart_lists_what_the_table_lists(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    log, _ = realistic_log(tmp_path_factory)
    report = make_report(log, tmp_path_factory.mktemp("gating") / "report.html")
    section = report.html.split("<h2>6.")[1].split("<h2>")[0]
    cells = re.findall(
        r"<tr><td[^>]*>([^<]*)</td><td[^>]*>([^<]*)</td><td[^>]*>([^<]*)</td>", section
    )
    table = {(what.split(",")[0].strip(), reason, int(n)) for what, reason, n in cells}
    data = load(log)
    assert data.frames is not None and data.gating is not None
    fig = plots.gating(data.frames, data.gating, tuple(SKIPPED))
    assert fig is not None
    labels = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    chart = set()
    for label in labels:
        kind, rest = label.split(": ", 1)
        reason, n = re.fullmatch(r"(\S+) \((\d+)\)", rest).groups()  # type: ignore[union-attr]
        chart.add(("order" if kind.startswith("H") else "frame", reason, int(n)))
    # orders are counted per order in the chart, summed over orders in the table
    per_reason: dict[tuple[str, str], int] = {}
    for kind, reason, n in chart:
        per_reason[(kind, reason)] = per_reason.get((kind, reason), 0) + n
    assert {(k, r, n) for (k, r), n in per_reason.items()} == table
    assert any(r == "overlapping" for _, r, _ in table)  # the realistic run skips overlaps
    red = [t.get_text() for t in fig.axes[0].get_yticklabels() if t.get_color() == "tab:red"]
    assert not any("overlapping" in t for t in red)


def test_every_figure_writes_text_of_9_px_or_more(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    log, _ = realistic_log(tmp_path_factory)
    report = make_report(log, tmp_path_factory.mktemp("fonts") / "report.html")
    assert len(report.figures) >= 7
    for name, data in report.figures.items():
        px = float(png_text(data)[plots.SMALLEST_TEXT_KEY])
        assert 9.0 <= px < 30, (name, px)
        width = struct.unpack(">I", data[16:20])[0]
        assert width <= 1118, (name, width)  # shown unscaled in the 1150 px column


def test_the_smallest_text_is_measured_from_the_figure() -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 1))
    ax = fig.subplots()
    ax.plot(np.arange(3))
    ax.legend(["x"], fontsize=5)
    assert plots.smallest_text_px(fig) == pytest.approx(5 * plots.DPI / 72)
