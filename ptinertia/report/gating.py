"""Section 6 of the report: what the estimator left out, and why (table and chart agree).

A frame is either used, rejected (a reason in :data:`REASONS`, drawn in red) or
skipped (:data:`SKIPPED`: its window overlaps the last used frame, so its data
are already in the estimate; the result document counts it apart, as
``skipped_overlapping``, and so do the table and the chart, in grey).
"""

from __future__ import annotations

from ptinertia.report import plots
from ptinertia.report.data import ReportData
from ptinertia.report.html import image, table

REASONS = {
    "rpm_unsteady": "speed changed too much across the analysis window (order leakage)",
    "rpm_out_of_range": "outside the estimator's rpm range",
    "near_rigid_modes": "order frequency too close to the rigid-body modes (below the mass line)",
    "non_rigid": "the 9 channels do not move as a rigid body (elastic mode, bad channel)",
    "no_excitation": "the engine does not excite this order",
    "too_few_channels": "fewer than 6 valid channels",
    "tacho": "no valid crank angle (tacho lost or re-synchronised)",
    "no_rpm": "no speed",
    "sensor_geometry": "the valid channels cannot resolve a rigid motion",
    "dsp_settling": "the order tracker's leakage correction had not settled (start of the run, a gap)",
    "cycle_ambiguous": "the half orders cannot tell which of two crank revolutions this is",
}
# Left out but not rejected: the estimator skips a frame whose window overlaps the last used
# one (its data are already in the estimate), so it is neither a fault nor counted as one.
SKIPPED = {
    "overlapping": "window overlaps the previous used frame: its data are already in the estimate"
}


def gating_section(data: ReportData, figures: dict[str, bytes]) -> str:
    out = ["<h2>6. What was gated out, and why</h2>"]
    doc = data.result
    counts: dict[str, int] = {}
    order_counts: dict[str, int] = {}
    skipped = 0
    if doc is not None:
        counts = dict(doc["frames"]["rejected"])
        order_counts = dict(doc["frames"].get("orders_rejected", {}))
        skipped = int(doc["frames"].get("skipped_overlapping", 0))
    elif data.gating is not None:
        for r in data.gating.reason:
            if r in SKIPPED:
                skipped += 1
            elif r:
                counts[r] = counts.get(r, 0) + 1
    total = len(data.frames) if data.frames is not None else None
    used = doc["frames"]["used"] if doc is not None else 0
    out.append(
        f"<p>Frames: {'' if total is None else f'{total} tracked, '}{used} used"
        + (f", {skipped} skipped as overlapping (not rejected)" if skipped else "")
        + ".</p>"
    )
    rows = [
        ["frame", r, str(n), REASONS.get(r, "")]
        for r, n in sorted(counts.items(), key=lambda kv: -kv[1])
    ]
    rows += [
        ["order", r, str(n), REASONS.get(r, "")]
        for r, n in sorted(order_counts.items(), key=lambda kv: -kv[1])
    ]
    if skipped:
        rows.append(["frame, skipped", "overlapping", str(skipped), SKIPPED["overlapping"]])
    out.append(
        table(["what", "reason", "count", "meaning"], rows, left=2)
        if rows
        else "<p>Nothing was rejected.</p>"
    )
    if data.frames is not None and data.gating is not None:
        fig = plots.gating(data.frames, data.gating, tuple(SKIPPED))
        if fig is not None:
            figures["gating"] = plots.png(fig)
            out.append(
                image(
                    "gating",
                    figures["gating"],
                    "Rejected frames and orders by reason against rpm (red), and the frames "
                    "skipped as overlapping (grey), as in the table",
                )
            )
    return "".join(out)
