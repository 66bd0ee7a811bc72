"""The live Rerun view of a run: rpm, orders, the estimates with +-2 sigma bands, and a 3D scene.

Importing this module does not import Rerun (about 0.5 s and a large wheel):
:class:`RerunSink` imports it in ``start``. The sink must not slow processing:
series rows are buffered and go out with one ``send_columns`` per entity at
most every ``flush_period_s`` of wall time; the 3D scene is sampled every
``scene_period_s`` of *stream* time (so a replay at 100x real time draws the
same scene as the live run) and batched the same way.

A saved recording (``--rerun save``) has no one watching live, so it is sent
once at the end, or every ``max_rows`` frames (4096, Rerun's own chunk row
limit), whichever comes first: each ``send_columns`` is a chunk of the file,
and a 60 s run's ``.rrd`` held 284 chunks where ``rerun rrd optimize``
compacts it to 63; sent this way it holds as many as the compacted one
(``tests/ptinertia/viewer/test_viewer.py`` checks with ``rerun rrd optimize``).

What is shown, and where, is listed in ``docs/viewer.md``; the option parsing
lives in :mod:`ptinertia.viewer.options`, the entity paths and blueprint in
:mod:`ptinertia.viewer.layout` (static part: :mod:`ptinertia.viewer.static`), the
plotted numbers in :mod:`ptinertia.viewer.data`, the geometry in :mod:`ptinertia.viewer.scene`.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from acquisition.stream import SourceEvent
from estimator.outcome import FrameOutcome
from estimator.result import Estimate, EstimateUpdate, enforce_physical, principal_axes
from ptinertia.sinks import RunContext, Sink
from ptinertia.viewer import layout as lay
from ptinertia.viewer.data import BAND_K, band_columns, estimate_rows, order_columns, truth_values
from ptinertia.viewer.options import (
    RERUN_HELP,
    ViewerMode,
    add_rerun_option,
    check_port_free,
    default_rrd_path,
    has_display,
    open_recording,
    parse_rerun_option,
    probe_viewer,
)
from ptinertia.viewer.scene import (
    covariance_ellipsoid,
    displacement_amplitudes,
    displacement_at,
    equivalent_box,
    exaggerated_pose,
    nice_exaggeration,
    peak_excursion,
)
from ptinertia.viewer.static import log_static

__all__ = [
    "RERUN_HELP",
    "RerunSink",
    "ViewerMode",
    "add_rerun_option",
    "default_rrd_path",
    "estimate_rows",
    "has_display",
    "make_viewer_sink",
    "parse_rerun_option",
    "truth_values",
]

MOTION_TARGET = 0.1  # exaggerated excursion, as a fraction of the box's half diagonal


def make_viewer_sink(
    text: str | None, recording_path: str | Path | None = None, **options: Any
) -> RerunSink | None:
    """The :class:`RerunSink` for ``--rerun text``, or None for ``off``."""
    mode = parse_rerun_option(text, recording_path)
    return None if mode.kind == "off" else RerunSink(mode, **options)


class _Buffer:
    """Rows of one entity waiting for one ``send_columns`` (``instances`` per row)."""

    def __init__(self, archetype: str, instances: int = 1) -> None:
        self.archetype = archetype
        self.instances = instances
        self.time: list[float] = []
        self.rpm: list[int] = []
        self.fields: dict[str, list[Any]] = {}

    def add(self, time_s: float, rpm: int, **fields: Any) -> None:
        self.time.append(time_s)
        self.rpm.append(rpm)
        for key, val in fields.items():
            self.fields.setdefault(key, []).append(val)

    def send(self, rr: Any, rec: Any, path: str) -> None:
        if not self.time:
            return
        n = len(self.time)
        arrays: dict[str, Any] = {}
        for key, rows in self.fields.items():
            if self.instances > 1:
                rows = [x for row in rows for x in row]
            arrays[key] = rows if isinstance(rows[0], str) else np.asarray(rows, dtype=float)
        cols = getattr(rr, self.archetype).columns(**arrays)
        if self.instances > 1:
            cols = cols.partition([self.instances] * n)
        indexes = [
            rr.TimeColumn(lay.TIME, duration=np.asarray(self.time)),
            rr.TimeColumn(lay.RPM_TIMELINE, sequence=np.asarray(self.rpm, dtype=np.int64)),
        ]
        rec.send_columns(path, indexes=indexes, columns=cols)
        self.time, self.rpm, self.fields = [], [], {}


class RerunSink(Sink):
    """Streams the run to Rerun (see the module docstring and ``docs/viewer.md``).

    Parameters
    ----------
    mode : where the view goes (:func:`parse_rerun_option`); not ``off``.
    scene_period_s : stream time between two samples of the animated motion (s).
    body_period_s : stream time between two redraws of the estimated box and cog ellipsoid (s).
    flush_period_s : wall time between two batches sent to Rerun (s); None: 0.5 s for a
        live view, only at the end (or every ``max_rows`` frames) for a saved file.
    max_rows : frames buffered at most before a batch is sent.
    exaggeration : motion scale of the animated powertrain; None picks a 1-2-5
        factor from the first fitted motion (then fixed, so amplitudes compare along the sweep).
    animation_steps : scene samples per animated engine cycle (720 deg).
    out : where the how-to-open line goes (default stderr).
    clock : wall clock (s), for tests.
    """

    def __init__(
        self,
        mode: ViewerMode,
        *,
        scene_period_s: float = 0.1,
        body_period_s: float = 0.5,
        flush_period_s: float | None = None,
        max_rows: int = 4096,
        exaggeration: float | None = None,
        animation_steps: int = 24,
        close_timeout_s: float = 10.0,
        out: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if mode.kind == "off":
            raise ValueError("RerunSink needs a viewer mode other than 'off'")
        self.mode = mode
        self.scene_period_s = scene_period_s
        self.body_period_s = body_period_s
        if flush_period_s is None:
            flush_period_s = math.inf if mode.kind == "save" else 0.5
        self.flush_period_s = flush_period_s
        self.max_rows = max_rows
        self.exaggeration = exaggeration
        self.animation_steps = animation_steps
        self.close_timeout_s = close_timeout_s
        self.out = out
        self.clock = clock
        self._rr: Any = None
        self._rec: Any = None
        self._buffers: dict[str, _Buffer] = {}

    # -- set-up ---------------------------------------------------------------------------
    def start(self, context: RunContext) -> None:
        # The blueprint needs Rerun imported; a missing viewer or a busy port is the
        # user's to hear about first (open_recording checks again, it is public).
        if self.mode.kind == "connect" and self.mode.url:
            probe_viewer(self.mode.url)
        if self.mode.kind == "serve":
            check_port_free(self.mode.bind_ip, self.mode.port)
        import rerun as rr

        setup = context.setup
        self._rr = rr
        self._setup = setup
        self._channels = tuple(setup.channels)
        orders = context.settings.get("dsp", {}).get("orders") or context.bench.dsp.orders
        self._orders = tuple(float(h) for h in orders)
        corr = setup.corrections
        self._extras = tuple(
            e
            for e, on in (
                ("mass", not setup.mass_known),
                ("crank_offset", corr.crank_offset),
                ("unbalance", corr.unbalance),
            )
            if on
        )
        self._truth = truth_values(context.truth)
        blueprint = lay.default_blueprint(list(self._orders), list(self._extras), bool(self._truth))
        self._rec = open_recording(self.mode, blueprint, self.out or sys.stderr)
        name = getattr(getattr(context.bench, "meta", None), "name", None)
        if name:
            self._rec.send_recording_name(str(name))
        self._flush_clock = self.clock()
        self._last_scene_t = -math.inf
        self._last_body_t = -math.inf
        self._tick = 0
        self._t, self._rpm = 0.0, 0
        self._estimate: Estimate | None = None
        self._body_dirty = True
        self._motion: tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, ...]] | None = None
        self._column_of: dict[tuple[str, ...], np.ndarray] = {}
        # (t, rpm index, rpm, orders, amplitudes, residual per order, orders used)
        self._frames: list[tuple[Any, ...]] = []
        self._estimates: list[tuple[float, int, Estimate]] = []
        log_static(rr, self._rec, context, self._orders, self._extras, self._truth)

    # -- stream ---------------------------------------------------------------------------
    def _row(
        self, path: str, archetype: str = "Scalars", instances: int = 1, **fields: Any
    ) -> None:
        buf = self._buffers.get(path)
        if buf is None:
            buf = self._buffers[path] = _Buffer(archetype, instances)
        buf.add(self._t, self._rpm, **fields)

    def _columns(self, channels: tuple[str, ...]) -> np.ndarray:
        """Index of each of our channels in a frame's channel list (-1: absent)."""
        idx = self._column_of.get(channels)
        if idx is None:
            where = {c: i for i, c in enumerate(channels)}
            idx = self._column_of[channels] = np.array([where.get(c, -1) for c in self._channels])
        return idx

    def on_frame(self, frame: Any, outcome: FrameOutcome) -> None:
        if self._rec is None:
            return
        self._t = float(frame.time_s)
        if math.isfinite(frame.rpm):
            self._rpm = round(frame.rpm)
        idx = self._columns(tuple(frame.channels))
        amps = np.asarray(frame.amplitudes)[:, idx]
        if np.any(idx < 0):
            amps = np.where(idx >= 0, amps, np.nan)
        res = outcome.relative_residual
        self._frames.append(
            (
                self._t,
                self._rpm,
                float(frame.rpm),
                tuple(frame.orders),
                amps,
                [res.get(h, math.nan) for h in self._orders],
                len(outcome.used_orders),
            )
        )
        if outcome.motion is not None:
            u_o, theta = displacement_amplitudes(outcome.motion, frame.orders, frame.rpm)
            self._motion = (outcome.motion.origin, u_o, theta, tuple(frame.orders))
        if self._t - self._last_scene_t >= self.scene_period_s:
            self._scene_tick()
        if (
            len(self._frames) >= self.max_rows
            or self.clock() - self._flush_clock >= self.flush_period_s
        ):
            self._flush()

    def on_estimate(self, update: EstimateUpdate) -> None:
        if self._rec is None:
            return
        self._estimate = update.estimate
        self._body_dirty = True
        self._estimates.append((float(update.time_s), self._rpm, update.estimate))

    def on_event(self, event: SourceEvent) -> None:
        self._text(
            f"{event.kind}: {event.message}" + (f" (x{event.count})" if event.count > 1 else ""),
            event.time_s,
        )

    def on_backlog(self, seconds: float) -> None:
        self._text(f"processing is {seconds:.1f} s behind acquisition", None)

    def _text(self, text: str, time_s: float | None) -> None:
        if self._rec is None:
            return
        self._rec.set_time(lay.TIME, duration=self._t if time_s is None else float(time_s))
        self._rec.set_time(lay.RPM_TIMELINE, sequence=self._rpm)
        self._rec.log(lay.EVENTS, self._rr.TextLog(text, level="WARN"))

    # -- 3D scene -------------------------------------------------------------------------
    def _body(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """cog (3,) m, principal axes (3, 3), moments (3,) kg m^2 and box half sizes (3,) m.

        The nominal body until the estimate determines inertia and cog.
        """
        setup, est = self._setup, self._estimate
        inertia, cog, mass = setup.inertia_nominal, setup.cog_nominal, setup.mass_nominal
        if est is not None and bool(np.all(est.observable[:9])):
            inertia, cog = est.inertia, est.cog
            m = est.mass()
            mass = m[0] if m is not None else mass
        moments, axes = principal_axes(enforce_physical(np.asarray(inertia, float))[0])
        return np.asarray(cog, float), axes, moments, equivalent_box(moments, mass)

    def _scene_tick(self) -> None:
        self._last_scene_t = self._t
        if self._body_dirty and self._t - self._last_body_t >= self.body_period_s:
            self._body_dirty = False
            self._last_body_t = self._t
            cog, axes, moments, half = self._shape = self._body()
            self._row(lay.POWERTRAIN, "Transform3D", translation=cog, mat3x3=axes)
            self._row(lay.BOX, "Boxes3D", half_sizes=half)
            labels = [f"I{k + 1} = {moments[k]:.3g} kg m²" for k in range(3)]
            self._row(lay.PRINCIPAL_AXES, "Arrows3D", 3, vectors=np.diag(1.3 * half), labels=labels)
            est = self._estimate
            if est is not None and bool(np.all(est.observable[6:9])):
                size, ell_axes = covariance_ellipsoid(est.cov[6:9, 6:9], BAND_K)
                self._row(lay.COG, "Transform3D", translation=est.cog, mat3x3=ell_axes)
                self._row(lay.COG_ELLIPSOID, "Ellipsoids3D", half_sizes=size)
        if self._motion is None:
            return
        origin, u_o, theta, orders = self._motion
        if self.exaggeration is None:
            radius = float(np.linalg.norm(self._shape[3]))
            excursion = peak_excursion(u_o, theta, radius)
            self.exaggeration = nice_exaggeration(excursion, MOTION_TARGET * radius)
            self._text(f"3D motion exaggerated x{self.exaggeration:g}", None)
        # Stroboscopic slow motion: each tick advances the crank by 720 deg / steps.
        phi = 4.0 * math.pi * self._tick / self.animation_steps
        u, th = displacement_at(u_o, theta, orders, phi)
        translation, rot = exaggerated_pose(origin, u, th, self.exaggeration)
        self._row(lay.MOVING, "Transform3D", translation=translation, mat3x3=rot)
        self._tick += 1

    # -- output ---------------------------------------------------------------------------
    def _indexes(self, time_s: list[float], rpm: list[int]) -> list[Any]:
        rr = self._rr
        return [
            rr.TimeColumn(lay.TIME, duration=np.asarray(time_s, dtype=float)),
            rr.TimeColumn(lay.RPM_TIMELINE, sequence=np.asarray(rpm, dtype=np.int64)),
        ]

    def _send(self, path: str, indexes: list[Any], scalars: np.ndarray) -> None:
        self._rec.send_columns(
            path, indexes=indexes, columns=self._rr.Scalars.columns(scalars=scalars)
        )

    def _flush(self) -> None:
        """Send everything buffered: one ``send_columns`` per entity."""
        self._flush_clock = self.clock()
        frames, self._frames = self._frames, []
        if frames:
            index = self._indexes([f[0] for f in frames], [f[1] for f in frames])
            self._send(lay.RPM, index, np.array([f[2] for f in frames]))
            self._send(lay.RESIDUAL, index, np.array([f[5] for f in frames], dtype=float))
            self._send(lay.USED_ORDERS, index, np.array([f[6] for f in frames], dtype=float))
            for orders in dict.fromkeys(f[3] for f in frames):
                sel = [f for f in frames if f[3] == orders]
                sub = (
                    index
                    if len(sel) == len(frames)
                    else self._indexes([f[0] for f in sel], [f[1] for f in sel])
                )
                amplitude, phase = order_columns(np.stack([f[4] for f in sel]))
                for k, h in enumerate(orders):
                    self._send(lay.order_amplitude(h), sub, amplitude[:, k])
                    self._send(lay.order_phase(h), sub, phase[:, k])
        estimates, self._estimates = self._estimates, []
        if estimates:
            index = self._indexes([e[0] for e in estimates], [e[1] for e in estimates])
            bands = band_columns([e[2] for e in estimates], self._extras, self._truth)
            for name, rows in bands.items():
                self._send(lay.estimate_path(name), index, rows)
        for path, buf in self._buffers.items():
            buf.send(self._rr, self._rec, path)

    def close(self, final: Estimate | None) -> None:
        rec = self._rec
        if rec is None:
            return
        out = self.out or sys.stderr
        try:
            if final is not None:
                self._estimate, self._body_dirty = final, True
            self._last_body_t = -math.inf  # the final box is drawn whatever the period
            self._scene_tick()
            self._flush()
            rec.flush(timeout_sec=self.close_timeout_s)
        except RuntimeError as err:  # a viewer that went away must not fail the run
            print(f"ptinertia: warning: Rerun did not take all the data: {err}", file=out)
        finally:
            self._rec = None
            rec.disconnect()
        if self.mode.kind == "save":
            print(f"ptinertia: {self.mode.open_hint()}", file=out)
