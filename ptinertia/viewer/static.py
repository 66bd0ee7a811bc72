"""The static part of the Rerun view: series styles, view coordinates, mounts, sensors, truth box."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimator.result import enforce_physical, principal_axes, tensor_from_terms
from powertrain.rigidbody import TERMS
from ptinertia.sinks import RunContext
from ptinertia.viewer import layout as lay
from ptinertia.viewer.scene import equivalent_box


def log_static(
    rr: Any,
    rec: Any,
    context: RunContext,
    orders: tuple[float, ...],
    extras: tuple[str, ...],
    truth: dict[str, float],
) -> None:
    """Log what does not change during the run: series styles, the bench, the truth.

    Parameters
    ----------
    rr : the ``rerun`` module; rec : the recording stream.
    context : the run (bench for mounts and sensors, setup for channel geometry).
    orders : tracked orders; extras : extra estimates plotted; truth : :func:`truth_values`.
    """
    setup = context.setup
    channels = tuple(setup.channels)
    s = rr.SeriesLines
    rec.log(lay.BENCH, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(lay.RPM, s(names=["rpm"], colors=[[60, 60, 60]]), static=True)
    axis = [int(np.argmax(np.abs(d))) for d in setup.directions]
    colors = lay.channel_colors([int(i) for i in setup.sensor_of_channel], axis)
    names = list(channels)
    for h in orders:
        rec.log(lay.order_amplitude(h), s(names=names, colors=colors), static=True)
        rec.log(
            lay.order_phase(h),
            rr.SeriesPoints(names=names, colors=colors, marker_sizes=[1.5] * len(names)),
            static=True,
        )
    labels = [lay.order_label(h) for h in orders]
    rec.log(lay.RESIDUAL, s(names=labels), static=True)
    rec.log(lay.USED_ORDERS, s(names=["orders used"]), static=True)
    for name in TERMS + lay.COG_TERMS + extras:
        has_truth = name in truth
        rec.log(
            lay.estimate_path(name),
            s(
                names=[name, "+2σ", "−2σ"] + (["truth"] if has_truth else []),
                colors=[lay.VALUE_RGB, lay.BAND_RGB, lay.BAND_RGB]
                + ([lay.TRUTH_RGB] if has_truth else []),
                widths=[2.0, 1.0, 1.0] + ([1.5] if has_truth else []),
            ),
            static=True,
        )
    mounts = getattr(context.bench, "mounts", [])
    if mounts:
        rec.log(
            lay.MOUNTS,
            rr.Boxes3D(
                centers=[m.position_m for m in mounts],
                half_sizes=[[0.025] * 3] * len(mounts),
                labels=[m.name for m in mounts],
                colors=[[120, 120, 120]],
                fill_mode="solid",
            ),
            static=True,
        )
    for k, sensor in enumerate(getattr(context.bench, "sensors", [])):
        path = f"{lay.SENSORS}/{sensor.name}"
        rgb = lay.SENSOR_RGB[k % len(lay.SENSOR_RGB)]
        rec.log(
            path,
            rr.Points3D([sensor.position_m], labels=[sensor.name], radii=0.012, colors=[rgb]),
            static=True,
        )
        sel = np.flatnonzero(setup.sensor_of_channel == k)
        rec.log(
            f"{path}/axes",
            rr.Arrows3D(
                origins=setup.positions[sel],
                vectors=0.08 * setup.directions[sel],
                labels=[channels[i] for i in sel],
                colors=[colors[i] for i in sel],
            ),
            static=True,
        )
    rec.log(
        lay.NOMINAL_COG,
        rr.Points3D(
            [setup.cog_nominal], labels=["nominal cog"], radii=0.006, colors=[[150, 150, 150]]
        ),
        static=True,
    )
    if {"Ixx", "Gx"} <= set(truth):
        terms = np.array([truth[t] for t in TERMS])
        moments, axes = principal_axes(enforce_physical(tensor_from_terms(terms))[0])
        mass = truth.get("mass", float(setup.mass_nominal))
        cog = [truth[g] for g in lay.COG_TERMS]
        rec.log(lay.TRUTH, rr.Transform3D(translation=cog, mat3x3=axes), static=True)
        rec.log(
            lay.TRUTH_BOX,
            rr.Boxes3D(
                half_sizes=[equivalent_box(moments, mass)],
                colors=[lay.TRUTH_RGB],
                labels=["truth"],
                fill_mode="majorwireframe",
            ),
            static=True,
        )
    rec.log(
        lay.BOX,
        rr.Boxes3D.from_fields(
            colors=[[*lay.VALUE_RGB, 90]], fill_mode="transparentfillmajorwireframe"
        ),
        static=True,
    )
    rec.log(lay.PRINCIPAL_AXES, rr.Arrows3D.from_fields(colors=list(lay.AXIS_RGB)), static=True)
    rec.log(
        lay.COG_ELLIPSOID,
        rr.Ellipsoids3D.from_fields(
            colors=[[255, 140, 0, 160]], fill_mode="solid", labels=["cog ±2σ"]
        ),
        static=True,
    )
