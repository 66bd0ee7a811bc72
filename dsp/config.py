"""Order-tracker configuration and the plan that binds it to a stream layout.

:class:`OrderTrackerConfig` is plain data checked on construction;
:func:`make_plan` resolves channel names against an
:class:`acquisition.stream.StreamLayout` once, and refuses a combination that
cannot work (orders aliasing at the sampling rate, a tacho sampled too slowly,
a channel the source does not have) with a one-line :class:`DspConfigError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from acquisition.stream import SourceError, StreamLayout
from dsp.errors import DspConfigError
from dsp.leakage import coupling
from dsp.tacho import TachoConfig

ACCEL_UNIT = "m/s^2"


def _positive_half_order(h: float) -> bool:
    """Whether ``h`` is a positive, finite multiple of 0.5 (an engine order)."""
    return h > 0 and math.isfinite(h) and abs(2 * h - round(2 * h)) < 1e-9


@dataclass(frozen=True)
class OrderTrackerConfig:
    """What to track and how.

    Attributes
    ----------
    tacho : TachoConfig
    orders : tuple of float
        Engine orders, positive multiples of 0.5.
    channels : tuple of str or None
        Channels to track; None tracks every channel whose unit is m/s^2.
    frames_per_rev : int
        Frames per crank revolution, at ``phi = m * 360 / frames_per_rev`` deg.
    taper_deg : float
        Width of the window tapers (crank deg). Wider is more accurate (the
        sum over samples converges faster), narrower has less latency: 45 deg
        keeps the quadrature error near 5e-8 of the strongest order with 11
        samples per period of the highest order present (order 6 at 4500 rpm,
        5120 Hz); 30 deg lets it grow to 4e-6.
    rpm_min, rpm_max : float
        Valid speed range; frames outside carry ``rpm_out_of_range``. The
        aliasing check uses ``rpm_max``.
    clip_level : float or None
        Absolute level (channel units) at or above which a sample counts as
        clipped; None disables the check.
    cycle_wait_revs : float
        With a cam or pressure reference, how many revolutions a frame waits
        for the 720 deg cycle to be resolved before it goes out flagged.
    max_wait_s : float
        Samples that find no tacho angle for this long are dropped (event
        ``no_tacho``): memory stays bounded when the tacho dies.
    leakage_correction : bool
        Remove the leakage of amplitude ramps between half orders during a
        sweep (:mod:`dsp.leakage`), using ramps fitted over past frames.
    correction_max_order : float or None
        Every half order from 0.5 up to this one is tracked internally for the
        correction (None: the highest tracked order + 2). More orders, less
        residual leakage, more time per sample.
    spectrum_channel : str or None
        A channel (any unit, any sample group; it may be the tacho's
        ``pressure_channel`` or a tracked channel) whose full half-order
        spectrum every frame carries (:attr:`dsp.frames.OrderFrame.spectrum`).
        None: no spectrum, and no cost.
    spectrum_max_order : float
        The spectrum holds orders 0, 0.5, .. up to this one (a positive multiple
        of 0.5). With the leakage correction, every half order up to this one
        + 2 is tracked internally on that channel (below 0.9 of its Nyquist order).
    """

    tacho: TachoConfig = field(default_factory=TachoConfig)
    orders: tuple[float, ...] = (1.0, 1.5, 2.0)
    channels: tuple[str, ...] | None = None
    frames_per_rev: int = 1
    taper_deg: float = 45.0
    rpm_min: float = 300.0
    rpm_max: float = 9000.0
    clip_level: float | None = None
    cycle_wait_revs: float = 4.0
    max_wait_s: float = 2.0
    leakage_correction: bool = True
    correction_max_order: float | None = None
    spectrum_channel: str | None = None
    spectrum_max_order: float = 6.0

    def __post_init__(self) -> None:
        if not self.orders:
            raise DspConfigError("orders: expected at least one order, got none")
        for h in self.orders:
            if not _positive_half_order(h):
                raise DspConfigError(f"orders: expected positive multiples of 0.5, got {h}")
        if len(set(self.orders)) != len(self.orders):
            raise DspConfigError(f"orders: each order once, got {list(self.orders)}")
        if not (isinstance(self.frames_per_rev, int) and self.frames_per_rev >= 1):
            raise DspConfigError(
                f"frames_per_rev: expected an integer >= 1, got {self.frames_per_rev}"
            )
        spacing = 360.0 / self.frames_per_rev
        if not 0 < self.taper_deg < spacing:
            raise DspConfigError(
                f"taper_deg: expected 0 < taper < {spacing:g} deg (the frame spacing), got "
                f"{self.taper_deg}"
            )
        if not 0 < self.rpm_min < self.rpm_max:
            raise DspConfigError(
                f"rpm range: expected 0 < rpm_min < rpm_max, got {self.rpm_min}..{self.rpm_max}"
            )
        if self.clip_level is not None and not self.clip_level > 0:
            raise DspConfigError(f"clip_level: expected > 0, got {self.clip_level}")

        if self.correction_max_order is not None and not self.correction_max_order > 0:
            raise DspConfigError(
                f"correction_max_order: expected > 0, got {self.correction_max_order}"
            )
        h = self.spectrum_max_order
        if not (isinstance(h, (int, float)) and _positive_half_order(h)):
            raise DspConfigError(
                f"spectrum_max_order: expected a positive multiple of 0.5, got {h!r}"
            )
        if self.spectrum_channel is not None and not (
            isinstance(self.spectrum_channel, str) and self.spectrum_channel
        ):
            raise DspConfigError(
                f"spectrum_channel: expected a channel name or None, got {self.spectrum_channel!r}"
            )

    @property
    def k2(self) -> np.ndarray:
        """Twice the orders, as integers (orders are half-integers)."""
        return np.array([round(2 * h) for h in self.orders], dtype=np.int64)

    def internal_k2(self, nyquist_order: float) -> np.ndarray:
        """Twice the orders tracked internally: the output orders, plus every half order
        up to ``correction_max_order`` (below ``nyquist_order``) when correcting leakage."""
        k2 = set(int(k) for k in self.k2)
        if self.leakage_correction:
            top = self.correction_max_order or (max(self.orders) + 2.0)
            top = min(top, 0.9 * nyquist_order)
            k2 |= set(range(1, math.floor(2 * top + 1e-9) + 1))
        return np.array(sorted(k2), dtype=np.int64)

    @property
    def spectrum_size(self) -> int:
        """Length of a frame's spectrum: orders 0, 0.5, .. ``spectrum_max_order``."""
        return round(2 * self.spectrum_max_order) + 1

    def spectrum_k2(self, nyquist_order: float) -> np.ndarray:
        """Twice the orders tracked on the spectrum channel: 0 .. ``2 spectrum_max_order``,
        and with the leakage correction every half order up to ``spectrum_max_order + 2``
        (below 0.9 of ``nyquist_order``, never below the spectrum's own orders)."""
        top = self.spectrum_size - 1
        if self.leakage_correction:
            extra = math.floor(2 * min(self.spectrum_max_order + 2.0, 0.9 * nyquist_order) + 1e-9)
            top = max(top, extra)
        return np.arange(top + 1, dtype=np.int64)


@dataclass(frozen=True)
class GroupPlan:
    """The rows of one sample group the tracker uses.

    ``track_rows`` are tracked channels, landing in frame columns ``track_cols``.
    ``keep_rows`` are the rows buffered until the angle is known (tracked,
    then pressure, then the spectrum channel unless it is one of those);
    ``pressure_at`` and ``spectrum_at`` are indices within them.
    """

    name: str
    rate_hz: float
    t0_s: float
    n_rows: int
    track_rows: tuple[int, ...] = ()
    track_cols: tuple[int, ...] = ()
    tacho_row: int | None = None
    cam_row: int | None = None
    pressure_row: int | None = None
    rpm_row: int | None = None
    spectrum_row: int | None = None

    @property
    def keep_rows(self) -> tuple[int, ...]:
        keep = self.track_rows
        if self.pressure_row is not None:
            keep += (self.pressure_row,)
        if self.spectrum_row is not None and self.spectrum_row not in keep:
            keep += (self.spectrum_row,)
        return keep

    @property
    def pressure_at(self) -> int | None:
        return len(self.track_rows) if self.pressure_row is not None else None

    @property
    def spectrum_only(self) -> bool:
        """The group is in the plan only for the spectrum channel."""
        return self.spectrum_row is not None and not self.track_rows and self.pressure_row is None

    @property
    def spectrum_at(self) -> int | None:
        if self.spectrum_row is None:
            return None
        return self.keep_rows.index(self.spectrum_row)


@dataclass(frozen=True)
class Plan:
    """A configuration bound to a layout: which rows go where."""

    config: OrderTrackerConfig
    channels: tuple[str, ...]
    groups: tuple[GroupPlan, ...]
    tacho_edges: bool
    cam_edges: bool
    k2: np.ndarray  # (n_int,) twice the internally tracked orders
    out: np.ndarray  # (n_orders,) index of each output order in k2
    same: np.ndarray  # (2 fpr, n_int, n_int) leakage coupling, see dsp.leakage.coupling
    image: np.ndarray
    # the spectrum channel (config.spectrum_channel): its group's index, twice the orders
    # tracked on it (0, 1, 2, ..) and their coupling, whose row of order 0 is halved (see
    # dsp.assemble._spectrum)
    spectrum_group: int | None = None
    spectrum_k2: np.ndarray | None = None
    spectrum_same: np.ndarray | None = None
    spectrum_image: np.ndarray | None = None

    def group_index(self, name: str) -> int | None:
        for i, g in enumerate(self.groups):
            if g.name == name:
                return i
        return None


def _find(layout: StreamLayout, channel: str, what: str) -> tuple[str, int]:
    try:
        group, row = layout.find_channel(channel)
    except SourceError:
        raise DspConfigError(
            f"{what} channel {channel!r} is not in the source; it has: "
            + ", ".join(layout.channel_names + layout.edge_channels)
        ) from None
    return group.name, row


def make_plan(layout: StreamLayout, config: OrderTrackerConfig) -> Plan:
    """Bind ``config`` to ``layout``; raise :class:`DspConfigError` if it cannot work."""
    tc = config.tacho
    if config.channels is None:
        channels = tuple(c.name for g in layout.groups for c in g.channels if c.unit == ACCEL_UNIT)
        if not channels:
            raise DspConfigError(
                f"no channel in {ACCEL_UNIT} to track; name them (channels: "
                + ", ".join(layout.channel_names)
                + ")"
            )
    else:
        channels = tuple(config.channels)
    rows: dict[str, dict[str, object]] = {}

    def slot(name: str) -> dict[str, object]:
        return rows.setdefault(name, {"track_rows": [], "track_cols": []})

    for col, ch in enumerate(channels):
        gname, row = _find(layout, ch, "tracked")
        slot(gname)["track_rows"].append(row)  # type: ignore[attr-defined]
        slot(gname)["track_cols"].append(col)  # type: ignore[attr-defined]
    pulse_channel = tc.channel
    tacho_edges = tc.delivery == "edges"
    if tacho_edges:
        if pulse_channel not in layout.edge_channels:
            raise DspConfigError(
                f"tacho channel {pulse_channel!r} (delivery edges) is not an edge channel of the "
                f"source; edge channels: {', '.join(layout.edge_channels) or 'none'}"
            )
    else:
        gname, row = _find(layout, pulse_channel, "tacho")
        slot(gname)["tacho_row"] = row
    cam_edges = False
    if tc.phase_reference == "cam":
        if tc.cam_channel in layout.edge_channels:
            cam_edges = True
        else:
            gname, row = _find(layout, tc.cam_channel, "cam")
            slot(gname)["cam_row"] = row
    if tc.phase_reference == "pressure":
        gname, row = _find(layout, tc.pressure_channel, "pressure")
        slot(gname)["pressure_row"] = row
    if tc.kind == "rpm":
        gname, row = _find(layout, tc.rpm_channel, "rpm")
        slot(gname)["rpm_row"] = row
    spectrum_gname = None
    if config.spectrum_channel is not None:
        spectrum_gname, row = _find(layout, config.spectrum_channel, "spectrum")
        slot(spectrum_gname)["spectrum_row"] = row
    groups = []
    for g in layout.groups:
        if g.name not in rows:
            continue
        r = rows[g.name]
        plan = GroupPlan(
            name=g.name,
            rate_hz=float(g.rate_hz),
            t0_s=float(g.t0_s),
            n_rows=len(g.channels),
            track_rows=tuple(r["track_rows"]),  # type: ignore[arg-type]
            track_cols=tuple(r["track_cols"]),  # type: ignore[arg-type]
            tacho_row=r.get("tacho_row"),  # type: ignore[arg-type]
            cam_row=r.get("cam_row"),  # type: ignore[arg-type]
            pressure_row=r.get("pressure_row"),  # type: ignore[arg-type]
            rpm_row=r.get("rpm_row"),  # type: ignore[arg-type]
            spectrum_row=r.get("spectrum_row"),  # type: ignore[arg-type]
        )
        _check_rates(plan, config)
        groups.append(plan)
    rates = [g.rate_hz for g in groups if g.track_rows]
    nyquist_order = 0.5 * min(rates) / (config.rpm_max / 60.0) if rates else math.inf
    k2 = config.internal_k2(nyquist_order)
    out = np.array([int(np.flatnonzero(k2 == k)[0]) for k in config.k2], dtype=np.int64)
    same, image = coupling(k2, config.frames_per_rev, config.taper_deg)
    bound = Plan(config, channels, tuple(groups), tacho_edges, cam_edges, k2, out, same, image)
    if spectrum_gname is None:
        return bound
    gi = next(i for i, g in enumerate(groups) if g.name == spectrum_gname)
    rate = groups[gi].rate_hz
    nyquist_order = 0.5 * rate / (config.rpm_max / 60.0)
    if config.spectrum_max_order >= nyquist_order:
        raise DspConfigError(
            f"spectrum order {config.spectrum_max_order:g} at {config.rpm_max:g} rpm is "
            f"{config.spectrum_max_order * config.rpm_max / 60.0:.1f} Hz, at or above the Nyquist "
            f"frequency {0.5 * rate:g} Hz of group {spectrum_gname!r} (channel "
            f"{config.spectrum_channel!r}): lower rpm_max or spectrum_max_order, or sample faster"
        )
    sk2 = config.spectrum_k2(nyquist_order)
    s_same, s_image = coupling(sk2, config.frames_per_rev, config.taper_deg)
    # order 0 is the window mean, half the raw sum 2 sum w x q / sum w q: its correction too
    s_same[:, 0, :] *= 0.5
    s_image[:, 0, :] *= 0.5
    return replace(
        bound,
        spectrum_group=gi,
        spectrum_k2=sk2,
        spectrum_same=s_same,
        spectrum_image=s_image,
    )


def _check_rates(g: GroupPlan, config: OrderTrackerConfig) -> None:
    f_max = max(config.orders) * config.rpm_max / 60.0
    if g.track_rows and f_max >= 0.5 * g.rate_hz:
        raise DspConfigError(
            f"order {max(config.orders):g} at {config.rpm_max:g} rpm is {f_max:.1f} Hz, at or above "
            f"the Nyquist frequency {0.5 * g.rate_hz:g} Hz of group {g.name!r}: lower rpm_max or "
            "the orders, or sample faster"
        )
    if g.tacho_row is not None:
        tooth_hz = config.tacho.teeth_per_rev * config.rpm_max / 60.0
        if g.rate_hz < 8.0 * tooth_hz:
            raise DspConfigError(
                f"sampled tacho at {g.rate_hz:g} Hz: {config.tacho.teeth_per_rev} teeth at "
                f"{config.rpm_max:g} rpm pass at {tooth_hz:g} Hz; need >= 8 samples per tooth "
                f"({8 * tooth_hz:g} Hz)"
            )
