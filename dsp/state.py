"""The order tracker's state: what is carried from one stream item to the next.

Every class here is a frozen dataclass whose arrays and dicts are replaced,
never modified in place, so a step function can return a new state and leave
the old one valid (the pure ``track`` of :mod:`dsp.orders`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from acquisition.stream import SourceEvent
from dsp import angle as ang
from dsp.config import Plan
from dsp.gap_fit import NO_HOLES, NO_RECENT, Holes, Recent
from dsp.immutable import evolve
from dsp.rpmangle import RpmAngleState
from dsp.sum_rows import Row
from dsp.tacho import EdgeDetectorState
from dsp.wheel import DecoderState, RunStart

TWO_PI = 2.0 * math.pi
TACHO_REASONS = ("tacho_resync", "no_tacho")


@dataclass(frozen=True)
class Invalid:
    """A crank-angle stretch without usable samples: ``reason`` is a frame flag.

    ``group`` is the group index for a sample gap (``missing_channel``), None for
    a tacho stretch (every channel). The end points carry times for interpolation.
    """

    phi_a: float
    phi_b: float
    t_a: float
    t_b: float
    reason: str
    group: int | None


@dataclass(frozen=True)
class GroupState:
    """Per-group stream state.

    ``pend`` holds samples waiting for the angle, as (first grid index, kept
    rows (n_keep, n)) pieces of consecutive samples; ``last_*`` describe the last sample that got one; ``acc`` maps a
    segment ``m`` to its sums (:mod:`dsp.sums`); ``spec`` the same for the spectrum
    channel's orders (the group holding it only); ``pressure`` candidate TDC ``k`` to
    (sum, count) of the pressure near ``phi_w = 2 pi k``; ``holes`` the tracked
    channels' missing samples and ``recent`` their last engine cycle, which fills them
    (:mod:`dsp.gap_fit`).
    """

    pend: tuple[tuple[int, np.ndarray], ...] = ()
    last_index: int = -1
    last_phi: float = -math.inf
    last_t: float = math.nan
    last_run: int = -1
    first_phi: float = math.nan
    starved: bool = False
    acc: dict[int, Row] = field(default_factory=dict)
    spec: dict[int, Row] = field(default_factory=dict)
    pressure: dict[int, tuple[float, int]] = field(default_factory=dict)
    holes: Holes = NO_HOLES
    recent: Recent = NO_RECENT


@dataclass(frozen=True)
class TrackerState:
    """Everything the tracker carries between items (see :func:`track`)."""

    plan: Plan
    decoder: DecoderState = field(default_factory=DecoderState)
    table: ang.AngleTable = field(default_factory=ang.AngleTable)
    tacho_det: EdgeDetectorState = field(default_factory=EdgeDetectorState)
    cam_det: EdgeDetectorState = field(default_factory=EdgeDetectorState)
    rpm_angle: RpmAngleState = field(default_factory=RpmAngleState)
    groups: tuple[GroupState, ...] = ()
    runs: dict[int, RunStart] = field(default_factory=dict)
    chain_of_run: dict[int, int] = field(default_factory=dict)
    parity: dict[int, tuple[int, float]] = field(default_factory=dict)
    cam_pending: np.ndarray = field(default_factory=lambda: np.empty(0))
    invalid: tuple[Invalid, ...] = ()
    next_frame: int | None = None
    # last frames before correction: (j (h,), chain (h,), amplitudes (h, n_int, n_ch)), for ramps
    history: tuple[np.ndarray, ...] = ()
    # the same for the spectrum channel: (j (h,), chain (h,), spectrum (h, n_spec, 1))
    spec_history: tuple[np.ndarray, ...] = ()
    events: tuple[SourceEvent, ...] = ()
    # the half-order sign of each chain re-acquired after an outage, and the last frame's
    # half-order amplitudes (n_half, n_ch) that a new chain is continued from (dsp.rejoin)
    chain_sign: dict[int, int] = field(default_factory=dict)
    half_ref: np.ndarray | None = None


def initial_state(plan: Plan) -> TrackerState:
    """The state before the first item."""
    return TrackerState(plan=plan, groups=tuple(GroupState() for _ in plan.groups))


def last_complete_frame(st: TrackerState, front: float) -> int:
    """The last frame whose window (and half taper) lies before crank angle ``front`` (rad)."""
    cfg = st.plan.config
    spacing = TWO_PI / cfg.frames_per_rev
    return math.floor((front - 0.5 * math.radians(cfg.taper_deg)) / spacing) - cfg.frames_per_rev


def set_group(st: TrackerState, gi: int, gs: GroupState) -> TrackerState:
    """``st`` with group ``gi`` replaced."""
    groups = list(st.groups)
    groups[gi] = gs
    return evolve(st, groups=tuple(groups))


def chain_at(st: TrackerState, phi: float) -> int | None:
    """The parity chain of the run holding crank angle ``phi`` (None outside every run)."""
    t, _ = ang.time_at(st.table, np.array([phi]))
    if not np.isfinite(t[0]):
        return None
    ok, _, _, run = ang.lookup(st.table, t)
    return st.chain_of_run.get(int(run[0])) if ok[0] else None


def chains_at(st: TrackerState, phis: np.ndarray) -> np.ndarray:
    """:func:`chain_at` of every angle in ``phis`` (rad), -1 for None: (n,) int64.

    One run in the table (the rule: a re-sync is rare) has contiguous intervals, so an
    angle inside its second to second-last interval lies inside the run whatever the
    rounding of the time :func:`chain_at` goes through; only angles near the ends, or a
    table of several runs, take the exact path, one angle at a time.
    """
    phis = np.asarray(phis, dtype=float)
    out = np.full(phis.size, -1, dtype=np.int64)
    table = st.table
    exact = np.ones(phis.size, bool)
    if table.run.size >= 3 and table.run[0] == table.run[-1]:
        inner = (phis >= table.phi_lo[1]) & (phis <= table.phi_hi[-2])
        out[inner] = st.chain_of_run.get(int(table.run[0]), -1)
        exact = ~inner
    for i in np.flatnonzero(exact):
        chain = chain_at(st, float(phis[i]))
        out[i] = -1 if chain is None else chain
    return out
