"""Entity paths, colours and the default blueprint of the Rerun view.

One place names every entity, so the sink, the blueprint, the docs and the
tests agree. Rerun is imported inside :func:`default_blueprint` only.

Timelines: ``time`` (duration, stream clock) and ``rpm`` (sequence, the
frame's mean speed rounded to 1 rpm): pick ``rpm`` in the time panel to see
the estimates against speed (the paper's Figs. 13 and 15).
"""

from __future__ import annotations

from typing import Any

from powertrain.rigidbody import TERMS

TIME = "time"
RPM_TIMELINE = "rpm"

RPM = "rpm"
EVENTS = "events"
RESIDUAL = "quality/relative_residual"
USED_ORDERS = "quality/used_orders"
COG_TERMS = ("Gx", "Gy", "Gz")
EXTRAS = ("mass", "crank_offset", "unbalance")
EXTRA_UNITS = {"mass": "kg", "crank_offset": "deg", "unbalance": "kg m"}

BENCH = "bench"
MOUNTS = "bench/mounts"
NOMINAL_COG = "bench/nominal_cog"
TRUTH = "bench/truth"
TRUTH_BOX = "bench/truth/box"
COG = "bench/cog"
COG_ELLIPSOID = "bench/cog/ellipsoid"
MOVING = "bench/moving"
POWERTRAIN = "bench/moving/powertrain"
BOX = "bench/moving/powertrain/box"
PRINCIPAL_AXES = "bench/moving/powertrain/principal_axes"
SENSORS = "bench/moving/sensors"

# value, +2 sigma, -2 sigma, truth
VALUE_RGB = (31, 119, 180)
BAND_RGB = (158, 202, 225)
TRUTH_RGB = (214, 39, 40)
AXIS_RGB = ((230, 60, 60), (60, 180, 60), (60, 100, 230))
SENSOR_RGB = ((228, 26, 28), (55, 126, 184), (77, 175, 74), (152, 78, 163), (255, 127, 0))


def order_label(order: float) -> str:
    """``1.0 -> "H1"``, ``1.5 -> "H1.5"``."""
    return f"H{order:g}"


def order_amplitude(order: float) -> str:
    return f"orders/{order_label(order)}/amplitude"


def order_phase(order: float) -> str:
    return f"orders/{order_label(order)}/phase"


def estimate_path(name: str) -> str:
    group = "inertia" if name in TERMS else "cog" if name in COG_TERMS else "extra"
    return f"estimate/{group}/{name}"


def channel_colors(sensor_of_channel: list[int], axis_of_channel: list[int]) -> list[list[int]]:
    """One hue per sensor, three shades for its axes (x full, y lighter, z darker)."""
    shade = (1.0, 0.65, 0.4)
    out = []
    for s, a in zip(sensor_of_channel, axis_of_channel, strict=True):
        base = SENSOR_RGB[s % len(SENSOR_RGB)]
        k = shade[a % 3]
        out.append([int(255 - (255 - c) * k) if a == 1 else int(c * k) for c in base])
    return out


def default_blueprint(orders: list[float], extras: list[str], has_truth: bool) -> Any:
    """The layout shown on first open: 3D scene and rpm on the left, tabs of plots on the right.

    Parameters
    ----------
    orders : tracked orders (one amplitude and one phase plot each).
    extras : the extra estimates present (subset of :data:`EXTRAS`).
    has_truth : the scene has a truth box (named in the view title).
    """
    import rerun.blueprint as rrb

    def plot(path: str, name: str) -> Any:
        return rrb.TimeSeriesView(
            origin=f"/{path}", name=name, plot_legend=rrb.PlotLegend(visible=False)
        )

    inertia = rrb.Grid(
        *[plot(estimate_path(t), f"{t} [kg m²] ±2σ") for t in TERMS],
        grid_columns=3,
        name="inertia",
    )
    cog = rrb.Grid(
        *[plot(estimate_path(t), f"{t} [m] ±2σ") for t in COG_TERMS],
        *[plot(estimate_path(e), f"{e} [{EXTRA_UNITS[e]}] ±2σ") for e in extras],
        grid_columns=3,
        name="cog",
    )
    order_views = []
    for h in orders:
        order_views.append(
            rrb.TimeSeriesView(
                origin=f"/{order_amplitude(h)}", name=f"{order_label(h)} amplitude [m/s²]"
            )
        )
        order_views.append(
            rrb.TimeSeriesView(origin=f"/{order_phase(h)}", name=f"{order_label(h)} phase [deg]")
        )
    order_tab = rrb.Grid(*order_views, grid_columns=2, name="orders")
    quality = rrb.Vertical(
        rrb.TimeSeriesView(origin=f"/{RESIDUAL}", name="rigid-fit residual / signal"),
        rrb.TimeSeriesView(origin=f"/{USED_ORDERS}", name="orders used per frame"),
        rrb.TextLogView(origin=f"/{EVENTS}", name="events"),
        name="quality",
    )
    scene_name = "powertrain (box = estimated inertia" + (
        ", wireframe = truth)" if has_truth else ")"
    )
    left = rrb.Vertical(
        rrb.Spatial3DView(origin=f"/{BENCH}", name=scene_name),
        rrb.TimeSeriesView(origin=f"/{RPM}", name="rpm"),
        row_shares=[3, 1],
    )
    right = rrb.Tabs(inertia, cog, order_tab, quality, active_tab=0)
    return rrb.Blueprint(
        rrb.Horizontal(left, right, column_shares=[2, 3]),
        rrb.TimePanel(timeline=TIME),
        rrb.SelectionPanel(state="collapsed"),
        auto_views=False,
    )
