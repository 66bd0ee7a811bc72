"""The whole chain for one source: shared by ``run`` and ``replay``.

Builds the dsp stage and the estimator from the bench file, attaches the
sinks (progress line, recorder, viewer), runs the pipeline, and turns the
final estimate into the result document (and a table for the terminal).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, TextIO

from acquisition.stream import Source, SourceError, StreamLayout
from estimator.result import Z95, Estimate
from estimator.setup import Corrections, Gates, Tolerances
from estimator.streaming import InertiaEstimator
from estimator.unbalance import DETECTED_STDS, detected
from ptinertia.config import Bench
from ptinertia.outputs import atomic_write
from ptinertia.pipeline import Pipeline, RunSummary
from ptinertia.progress import ProgressLine
from ptinertia.sinks import RunContext, Sink
from ptinertia.to_dsp import BenchTracker, tracker_config
from ptinertia.to_estimator import PressureGas, estimator_setup, pressure_gas


@dataclass(frozen=True)
class RunOptions:
    """Per-run choices beyond the bench file (command-line overrides)."""

    orders: tuple[float, ...] | None = None
    corrections_off: tuple[str, ...] = ()
    quiet: bool = False
    live: bool = False
    sinks: tuple[Sink, ...] = ()
    attachments: dict[str, bytes] = field(default_factory=dict)


def make_estimator(
    bench: Bench, corrections_off: tuple[str, ...] = (), pressure: PressureGas | None = None
) -> InertiaEstimator:
    """The streaming estimator with the bench file's ``[estimator]`` settings (``pressure``:
    the gas torque comes from that channel, see :func:`ptinertia.to_estimator.pressure_gas`)."""
    s = bench.estimator
    self_calibration = s.self_calibration and "self_calibration" not in corrections_off
    corrections = Corrections(
        suspension=s.suspension and "suspension" not in corrections_off,
        gyroscopic=s.gyroscopic and "gyroscopic" not in corrections_off,
        unbalance=s.unbalance and "unbalance" not in corrections_off,
        unbalance_location=s.unbalance_location and "unbalance" not in corrections_off,
        crank_offset=s.crank_offset and "crank_offset" not in corrections_off,
        mount_scale=s.mount_scale and "mount_scale" not in corrections_off,
        self_calibration=self_calibration,
        # "auto" follows the self-calibration actually run (not switched off by --no)
        channel_weights="channel_weights" not in corrections_off
        and (s.channel_weights == "measured" or (s.channel_weights == "auto" and self_calibration)),
    )
    tolerances = Tolerances(
        gain_rel=s.gain_tolerance_pct / 100.0,
        alignment_rad=math.radians(s.alignment_tolerance_deg),
        position_m=s.position_tolerance_m,
    )
    gates = Gates(
        max_relative_residual=s.max_relative_residual,
        max_rpm_change=s.max_rpm_change,
        min_mode_ratio=s.min_mode_ratio,
        rpm_range=(s.rpm_min, s.rpm_max),
    )
    setup = estimator_setup(
        bench, corrections=corrections, tolerances=tolerances, gates=gates, pressure=pressure
    )
    return InertiaEstimator(setup, forgetting=s.forgetting)


def settings_of(bench: Bench, tracker: BenchTracker, estimator: InertiaEstimator) -> dict[str, Any]:
    """Plain-JSON settings in force (kept in recordings and reports)."""
    cfg = tracker.config
    return {
        "dsp": {
            "orders": list(cfg.orders),
            "frames_per_rev": cfg.frames_per_rev,
            "taper_deg": cfg.taper_deg,
            "rpm_range": [cfg.rpm_min, cfg.rpm_max],
            "tacho": asdict(cfg.tacho),
        },
        "estimator": {
            "corrections": asdict(estimator.setup.corrections),
            "tolerances": asdict(estimator.setup.tolerances),
            "gates": asdict(estimator.setup.gates),
            "forgetting": estimator.forgetting,
            "mass_known": estimator.setup.mass_known,
            "gas_torque": (
                f"pressure channel {cfg.spectrum_channel}"
                if cfg.spectrum_channel is not None
                else "model"
            ),
            "parameters": list(estimator.layout.names),
        },
    }


def processing_chain(
    bench: Bench,
    layout: StreamLayout,
    orders: tuple[float, ...] | None = None,
    corrections_off: tuple[str, ...] = (),
) -> tuple[BenchTracker, InertiaEstimator]:
    """The dsp and the estimator for ``bench`` on a stream of ``layout``: with the gas
    torque from the cylinder-pressure channel when the stream records one."""
    pressure = pressure_gas(bench, layout)
    channel = None if pressure is None else pressure.channel
    tracker = BenchTracker(layout, tracker_config(bench, orders, channel))
    return tracker, make_estimator(bench, corrections_off, pressure)


def run_source(
    bench: Bench, bench_text: str, source: Source, source_spec: str, options: RunOptions
) -> tuple[RunSummary, dict[str, Any] | None]:
    """Run the chain on ``source``; returns the summary and the result document."""
    truth = source.layout.metadata.get("truth")
    if truth is not None and not isinstance(truth, dict):  # a crafted or damaged sidecar
        raise SourceError(
            f"{source_spec}: metadata 'truth': expected a JSON object or null, "
            f"got {type(truth).__name__}"
        )
    tracker, estimator = processing_chain(
        bench, source.layout, options.orders, options.corrections_off
    )
    context = RunContext(
        bench_text=bench_text,
        bench=bench,
        layout=source.layout,
        setup=estimator.setup,
        truth=truth,
        settings=settings_of(bench, tracker, estimator),
        source=source_spec,
        attachments=dict(options.attachments),
    )
    sinks: list[Sink] = [ProgressLine(quiet=options.quiet), *options.sinks]
    summary = Pipeline(source, tracker, estimator, sinks, context, live=options.live).run()
    doc = None
    if summary.estimate is not None:
        doc = summary.estimate.to_json(result_truth(truth))
        doc["source"] = source_spec
        if summary.gaps:  # stretches without crank angle the run went on across
            doc["gaps"] = summary.gaps
        if summary.interrupted:
            doc["interrupted"] = True
    return summary, doc


def result_truth(truth: dict[str, Any] | None) -> dict[str, Any] | None:
    """The simulated truth in the result document's shape."""
    if not truth:
        return None
    out: dict[str, Any] = {
        "inertia_kgm2": {"value": truth.get("inertia_kgm2")},
        "cog_m": {"value": truth.get("cog_m")},
        "mass_kg": {"value": truth.get("mass_kg")},
    }
    if truth.get("unbalance"):
        out["unbalance"] = truth["unbalance"]
    return out


def write_json(doc: dict[str, Any], path: str | Path) -> None:
    """Write atomically (:func:`ptinertia.outputs.atomic_write`): a reader never sees
    half a result file, a full disk leaves no ``.part`` behind."""
    atomic_write(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def misfit_line(doc: dict[str, Any]) -> str | None:
    """One line when the model does not fit the data (``doc["misfit"]``), else None."""
    m = doc.get("misfit")
    if not m:
        return None
    where = ""
    if "order" in m:
        where = (
            f"; H{m['order']:g} {m['equation']} misfits most ({100 * m['share']:.0f} % of the "
            f"residual): check {m['likely_inputs']}"
        )
    return (
        f"the model does not fit the data: chi-square per degree of freedom "
        f"{m['chi2_per_dof']:.3g} (far above 1: limit {m['limit']:g}){where}; result marked inconsistent"
    )


def unbalance_text(unb: dict[str, Any]) -> str:
    """The run table's unbalance line (95 % intervals): an angle and a location only when
    ``m r`` is detected (``estimator.unbalance.detected``: below, its angle means nothing), and the
    couple no point unbalance explains (``estimator.unbalance``) by the same rule."""
    mr, mr_std = unb["mr_kgm"]["value"], unb["mr_kgm"]["std"] or 0.0
    if detected(unb["mr_kgm"]):
        text = (
            f"residual unbalance {1e3 * mr:.3f} +- {1e3 * Z95 * mr_std:.3f} g m at "
            f"{unb['angle_deg']['value']:.1f} deg"
        )
        axial = unb.get("axial_m")
        if axial:
            text += (
                f", {1e3 * axial['value']:.1f} +- {1e3 * Z95 * (axial['std'] or math.nan):.1f} mm "
                "along the crank axis from the reference point"
            )
    else:
        text = f"residual unbalance not detected (below {1e3 * DETECTED_STDS * mr_std:.3f} g m)"
    couple = unb.get("couple_kgm2")
    if couple:
        c, c_std = couple["value"], couple["std"] or 0.0
        if detected(couple):
            text += (
                f"; couple {1e3 * c:.4f} +- {1e3 * Z95 * c_std:.4f} g m^2 at "
                f"{unb['couple_angle_deg']['value']:.1f} deg"
            )
        else:
            text += f"; no couple (below {1e3 * DETECTED_STDS * c_std:.4f} g m^2)"
    return text


def print_table(estimate: Estimate, doc: dict[str, Any], out: TextIO | None = None) -> bool:
    """Estimate, 95 % interval, truth and error, one line per term (to ``out``, default the
    standard output at call time, not the one at import); False, with the reason on stderr
    and no table, when the tensor is not physical (no estimate)."""
    out = sys.stdout if out is None else out
    misfit = misfit_line(doc)
    problems = list(doc["principal"]["consistency"]["problems"])
    half = doc.get("half_order") or {}
    if half.get("reference_doubtful"):
        problems.insert(
            0,
            "phase reference doubtful: the half orders fit "
            f"{1 / max(half['residual_ratio'], 1e-300):.3g} times better with the cycle 360 deg "
            "from where the cam/pressure reference puts it, too little to decide (100 needed); "
            "check [tacho] cam_angle_deg",
        )
    if problems:
        print(
            "ptinertia: no estimate to stand behind: "
            + "; ".join(
                p if p.startswith("phase") else f"the fitted inertia tensor is {p}"
                for p in problems
            )
            + (f"; {misfit}" if misfit else ""),
            file=sys.stderr,
        )
        return False
    truth = doc.get("truth") or {}
    t_inertia = (truth.get("inertia_kgm2") or {}).get("value") or {}
    t_cog = (truth.get("cog_m") or {}).get("value")
    rows: list[tuple[str, float, float, float | None, str]] = []
    for name in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"):
        rows.append((name, estimate.value(name), estimate.std(name), t_inertia.get(name), "kg m^2"))
    for i, name in enumerate(("Gx", "Gy", "Gz")):
        t = t_cog[i] if t_cog else None
        rows.append(
            (
                name,
                1e3 * estimate.value(name),
                1e3 * estimate.std(name),
                None if t is None else 1e3 * t,
                "mm",
            )
        )
    mass = estimate.mass()
    if mass is not None:
        t_mass = (truth.get("mass_kg") or {}).get("value")
        rows.append(("mass", mass[0], mass[1], t_mass, "kg"))
    header = f"{'term':6} {'estimate':>11} {'95% +-':>9} {'truth':>11} {'error':>9}  unit"
    print(header, file=out)
    for name, value, std, t, unit in rows:
        ci = Z95 * std if math.isfinite(std) else float("nan")
        if t is None:
            print(f"{name:6} {value:11.4f} {ci:9.4f} {'':>11} {'':>9}  {unit}", file=out)
            continue
        err = value - t
        rel = f"{100 * err / abs(t):8.2f}%" if unit != "mm" and abs(t) > 0 else f"{err:8.2f} "
        print(f"{name:6} {value:11.4f} {ci:9.4f} {t:11.4f} {rel:>9}  {unit}", file=out)
    unb = doc.get("unbalance")
    if unb:
        print(unbalance_text(unb), file=out)
    frames = doc["frames"]
    rejected = ", ".join(f"{k} {v}" for k, v in frames["rejected"].items()) or "none"
    lo, hi = doc["rpm_range"] or (math.nan, math.nan)
    print(f"frames used {frames['used']} ({lo:.0f}-{hi:.0f} rpm), rejected: {rejected}", file=out)
    scales = doc.get("mount_stiffness_scale")
    if scales:
        print(
            "mount stiffness scale (x the bench file's): "
            + ", ".join(
                f"{name} {v['value']:.3f} +- {Z95 * v['std']:.3f}"
                if v["std"] is not None
                else f"{name} not observed"
                for name, v in scales.items()
            ),
            file=out,
        )
    elastic = doc.get("elastic_mode")
    if elastic:
        print(
            f"elastic mode detected (H{elastic['order']:g} non-rigid from "
            f"{elastic['frequency_hz']:.0f} Hz): inertia and cog extrapolated to 0 Hz "
            "past its f^2 growth",
            file=out,
        )
    half = doc.get("half_order") or {}
    if half.get("reference_contradicted"):
        print(
            "phase reference contradicted: the half orders fit "
            f"{1 / max(half['residual_ratio'], 1e-300):.3g} times better with the cycle 360 deg "
            "from where the cam/pressure reference puts it; the residual test's sign was used "
            "(check [tacho] cam_angle_deg)",
            file=out,
        )
    unseen = doc.get("unseen_motion")
    if unseen:
        axis = ", ".join(f"{v:.2f}" for v in unseen["unseen_rotation_axis"])
        print(
            f"{unseen['pairs']} order readings came from frames that do not see the rotation "
            f"about [{axis}] (two usable sensors): that rotation was fitted per reading and the "
            "rest solved jointly; expect wider intervals",
            file=out,
        )
    if doc.get("unobservable"):
        print(
            "unobservable (no excitation reaches them): " + ", ".join(doc["unobservable"]), file=out
        )
    if misfit:
        print(misfit, file=out)
    return True
