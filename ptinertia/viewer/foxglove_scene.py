"""The 3D scene of a recording for Foxglove: the bench, the estimated body, its animated motion.

The same scene as the Rerun view (:mod:`ptinertia.viewer.rerun_sink`), from the
same geometry (:mod:`ptinertia.viewer.scene`), written into the recording with
Foxglove's well-known schemas (:mod:`replay.foxglove`): open the ``.mcap`` in
Foxglove, add a 3D panel (or load ``docs/foxglove-layout.json``) and the bench,
the box of the estimated inertia, the cog ellipsoid and the motion play along
the timeline.

Frames: ``bench`` (the bench frame, Z up) is the root; ``moving`` follows the
exaggerated rigid motion of the last fitted frame, played stroboscopically
(one engine cycle over ``animation_steps`` scene ticks, as in Rerun);
``powertrain`` sits at the estimated cog along the principal axes; ``cog`` at the
estimated cog along the axes of its covariance ellipsoid.

It is a sink placed after the :class:`replay.recorder.McapRecorder` it writes
through (``ptinertia.commands.run.recorder_sinks``); the recorder closes first, so
the scene's last body is the one of the last published estimate.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimator.outcome import FrameOutcome
from estimator.result import EstimateUpdate, enforce_physical, principal_axes
from ptinertia.sinks import RunContext, Sink
from ptinertia.viewer import layout as lay
from ptinertia.viewer.data import BAND_K
from ptinertia.viewer.scene import (
    covariance_ellipsoid,
    displacement_amplitudes,
    displacement_at,
    equivalent_box,
    exaggerated_pose,
    nice_exaggeration,
    peak_excursion,
)
from replay import foxglove as fg
from replay.recorder import McapRecorder

MOTION_TARGET = 0.1  # exaggerated excursion, as a fraction of the box's half diagonal


def _rgba(rgb: tuple[int, int, int], alpha: float = 1.0) -> fg.RGBA:
    return (rgb[0] / 255, rgb[1] / 255, rgb[2] / 255, alpha)


class FoxgloveScene(Sink):
    """Writes ``/foxglove/scene`` and ``/foxglove/tf`` through a recorder.

    Parameters
    ----------
    recorder : the run's recorder, started before this sink.
    scene_period_s : stream time between two poses of the animated motion (s).
    body_period_s : stream time between two redraws of the estimated body (s).
    animation_steps : scene ticks per animated engine cycle (720 deg).
    """

    def __init__(
        self,
        recorder: McapRecorder,
        scene_period_s: float = 0.1,
        body_period_s: float = 0.5,
        animation_steps: int = 24,
    ) -> None:
        self.recorder = recorder
        self.scene_period_s = scene_period_s
        self.body_period_s = body_period_s
        self.animation_steps = animation_steps
        self.exaggeration: float | None = None
        self._last_scene_t = -math.inf
        self._last_body_t = -math.inf
        self._tick = 0
        self._motion: tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, ...]] | None = None
        self._radius = 0.3  # m, half diagonal of the body, for the exaggeration

    def _ns(self, t: float) -> int:
        return max(0, self.recorder.origin_ns + round(t * 1e9))

    # -- the bench, once ------------------------------------------------------------------
    def start(self, context: RunContext) -> None:
        setup = self._setup = context.setup
        t_ns = self._ns(0.0)
        grey = (0.47, 0.47, 0.47, 1.0)
        bench = []
        for m in getattr(context.bench, "mounts", []):
            bench += [fg.cube(m.position_m, [0.05] * 3, grey), fg.text(m.position_m, m.name)]
        bench.append(fg.sphere(setup.cog_nominal, [0.012] * 3, (0.6, 0.6, 0.6, 1.0)))
        bench.append(fg.text(setup.cog_nominal, "nominal cog"))
        entities = [fg.entity(t_ns, fg.BENCH, "bench", bench)]
        axis = [int(np.argmax(np.abs(d))) for d in setup.directions]
        for k, sensor in enumerate(getattr(context.bench, "sensors", [])):
            rgb = _rgba(lay.SENSOR_RGB[k % len(lay.SENSOR_RGB)])
            prims = [
                fg.sphere(sensor.position_m, [0.024] * 3, rgb),
                fg.text(sensor.position_m, sensor.name),
            ]
            for i in np.flatnonzero(setup.sensor_of_channel == k):
                color = _rgba(lay.AXIS_RGB[axis[i]])
                prims.append(fg.arrow(setup.positions[i], 0.08 * setup.directions[i], color))
            # sensors ride on the moving body, as in the Rerun view
            entities.append(fg.entity(t_ns, fg.MOVING, f"sensor/{sensor.name}", prims))
        self.recorder.write_view(fg.TOPIC_SCENE, 0.0, fg.scene_update(entities))
        self.recorder.write_view(
            fg.TOPIC_TF, 0.0, fg.frame_transform(t_ns, fg.BENCH, fg.MOVING, [0, 0, 0], np.eye(3))
        )
        self._body(0.0, setup.inertia_nominal, setup.cog_nominal, setup.mass_nominal, None)

    # -- the estimated body ---------------------------------------------------------------
    def on_estimate(self, update: EstimateUpdate) -> None:
        t = float(update.time_s)
        est = update.estimate
        if t - self._last_body_t < self.body_period_s or not bool(np.all(est.observable[:9])):
            return
        m = est.mass()
        mass = m[0] if m is not None else self._setup.mass_nominal
        self._body(t, est.inertia, est.cog, mass, est.cov[6:9, 6:9])

    def _body(
        self,
        t: float,
        inertia: np.ndarray,
        cog: np.ndarray,
        mass: float,
        cog_cov: np.ndarray | None,
    ) -> None:
        self._last_body_t = t
        t_ns = self._ns(t)
        moments, axes = principal_axes(enforce_physical(np.asarray(inertia, float))[0])
        half = equivalent_box(moments, mass)
        self._radius = float(np.linalg.norm(half))
        body = [fg.cube([0, 0, 0], 2 * half, _rgba(lay.VALUE_RGB, 0.35))]
        for k in range(3):
            vector = np.zeros(3)
            vector[k] = 1.3 * half[k]
            body += [
                fg.arrow([0, 0, 0], vector, _rgba(lay.AXIS_RGB[k])),
                fg.text(vector, f"I{k + 1} = {moments[k]:.3g} kg m²"),
            ]
        entities = [fg.entity(t_ns, fg.POWERTRAIN, "powertrain", body)]
        tf = [fg.frame_transform(t_ns, fg.MOVING, fg.POWERTRAIN, cog, axes)]
        if cog_cov is not None:
            size, ell_axes = covariance_ellipsoid(cog_cov, BAND_K)
            ellipsoid = [
                fg.sphere([0, 0, 0], 2 * size, (1.0, 0.55, 0.0, 0.6)),
                fg.text([0, 0, 0], "cog ±2σ"),
            ]
            entities.append(fg.entity(t_ns, fg.COG, "cog", ellipsoid))
            tf.append(fg.frame_transform(t_ns, fg.BENCH, fg.COG, cog, ell_axes))
        self.recorder.write_view(fg.TOPIC_SCENE, t, fg.scene_update(entities))
        for data in tf:
            self.recorder.write_view(fg.TOPIC_TF, t, data)

    # -- the animated motion --------------------------------------------------------------
    def on_frame(self, frame: Any, outcome: FrameOutcome) -> None:
        if outcome.motion is not None:
            u_o, theta = displacement_amplitudes(outcome.motion, frame.orders, frame.rpm)
            self._motion = (outcome.motion.origin, u_o, theta, tuple(frame.orders))
        t = float(frame.time_s)
        if self._motion is None or t - self._last_scene_t < self.scene_period_s:
            return
        self._last_scene_t = t
        origin, u_o, theta, orders = self._motion
        if self.exaggeration is None:  # fixed once, so amplitudes compare along the sweep
            excursion = peak_excursion(u_o, theta, self._radius)
            self.exaggeration = nice_exaggeration(excursion, MOTION_TARGET * self._radius)
        phi = 4.0 * math.pi * self._tick / self.animation_steps  # stroboscopic slow motion
        u, th = displacement_at(u_o, theta, orders, phi)
        translation, rot = exaggerated_pose(origin, u, th, self.exaggeration)
        self.recorder.write_view(
            fg.TOPIC_TF, t, fg.frame_transform(self._ns(t), fg.BENCH, fg.MOVING, translation, rot)
        )
        self._tick += 1
