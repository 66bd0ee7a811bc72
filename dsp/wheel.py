"""Tooth-wheel decoding: gap detection, tooth numbering, missed and extra edges.

Edge times go in, *knots* come out: ``(t_s, n)`` pairs where ``n`` is the
absolute wheel position in tooth pitches (the gap counts its missing teeth), so
the crank angle of a knot is ``phi = phi_first_tooth + n * 2 pi / N`` exactly.

Checks, all vectorised over the edges of a block (a Python loop per tooth
would cost more than the whole order tracking):

* Synchronisation: the gap is an interval about ``M + 1`` times the one before
  and after it. A sync is confirmed only when the *next* gap arrives exactly
  one revolution later, so a missed edge cannot pass for the gap.
* Tracking: each interval divided by its expected pitch count (1, or ``M + 1``
  across the gap) must stay within ``tolerance`` of the previous one. A
  missing edge doubles it, an extra edge cuts one of the two parts below half:
  either breaks the pattern, an event is reported, no knot is produced until
  the wheel has re-synchronised at a later gap.
* An edge becomes a knot only once the interval *after* it has passed too, so
  a spurious edge never becomes a knot.
* A run of missing edges (a lost CAN frame of edges) whose length is a whole tooth
  count at the neighbouring teeth's rate is filled from them
  (:func:`fill_missing_edges`) instead of breaking the pattern; a single missed edge
  still breaks it (a sensor glitch may as well be a spurious extra interval).
* After a re-sync the revolution count across the lost stretch is bridged from
  the tooth rate on both sides; if the estimate is not clearly within a
  quarter revolution of a whole number, the run is marked ``bridged=False``
  (the 720 deg cycle and the unwrapped angle may have slipped).

Pulses (N per revolution, no gap) and once-per-revolution pulses are the same
with ``M = 0``: any three consistent intervals synchronise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from acquisition.stream import SourceEvent
from dsp import kernels
from dsp.immutable import evolve
from dsp.tacho import TachoConfig
from dsp.wheel_intervals import wheel_intervals

# Revolutions across which a lost stretch is still bridged (speed assumed to vary linearly).
MAX_BRIDGE_REVS = 20.0
# Missing edges are filled (fill_missing_edges) across at most this many pitches when the
# hole's length is within FILL_TOLERANCE pitches of a whole tooth count.
MAX_FILL_PITCHES = 40
# A single missed edge stays a loss of sync (a sensor glitch, flagged and re-synchronised
# as before); a run of missing edges is what a lost CAN frame of edges leaves.
MIN_FILL_EDGES = 2
FILL_REPORT_S = 1.0  # fills are reported at most once per this much edge time
FILL_TOLERANCE = 0.3


@dataclass(frozen=True)
class RunStart:
    """A synchronised stretch of the wheel begins.

    ``reason``: ``"start"`` (first sync), ``"tacho_resync"`` (after a missed or
    extra edge) or ``"no_tacho"`` (after a dropout of several pitches).
    ``bridged``: the revolution count across the lost stretch is certain.
    """

    run: int
    t_s: float
    n: int
    reason: str
    bridged: bool


@dataclass(frozen=True)
class Knots:
    """Knots committed by one decoder step (arrays of equal length)."""

    t_s: np.ndarray  # (k,) float64, s
    n: np.ndarray  # (k,) int64, wheel position in pitches
    run: np.ndarray  # (k,) int64, run id
    runs: tuple[RunStart, ...] = ()

    @staticmethod
    def empty() -> Knots:
        return Knots(np.empty(0), np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64))


@dataclass(frozen=True)
class DecoderState:
    """Carried between :func:`decode_edges` calls (arrays are never modified in place).

    ``buf`` holds edges not yet committed; when synced, ``buf[0]`` is the
    last committed edge (or the gap start while a sync is being confirmed),
    its tooth count is ``c0`` and ``r_prev`` the per-pitch interval ending at it.
    """

    buf: np.ndarray = field(default_factory=lambda: np.empty(0))
    synced: bool = False
    confirmed: bool = False
    c0: int = 0
    r_prev: float = math.nan
    run: int = -1
    run_base_n: int = 0
    last_t: float = math.nan  # last committed knot: time (s), position, per-pitch interval (s)
    last_n: int = 0
    last_r: float = math.nan
    lost_reason: str = ""
    # filled holes and edges not reported yet, and when the last report was (s)
    fill_holes: int = 0
    fill_edges: int = 0
    fill_reported_s: float = -math.inf


def _position(c: np.ndarray, teeth: int, gap: int) -> np.ndarray:
    """Wheel position (pitches) of tooth count ``c`` (tooth 0 = first after the gap)."""
    per_rev = teeth - gap
    return (c // per_rev) * teeth + (c % per_rev)


def _find_sync(d: np.ndarray, cfg: TachoConfig) -> int:
    """Index ``g`` of the first interval that looks like the gap (or -1).

    The tooth after the gap ends interval ``g``. For pulses (M = 0) any
    interval whose neighbours agree within the tolerance will do.
    """
    tol = cfg.tolerance
    m1 = cfg.gap_teeth + 1
    if d.size < 3:
        return -1
    a = d[1:-1] / d[:-2]  # gap / before
    b = d[2:] / d[1:-1]  # after / gap
    ok = (a >= m1 * (1 - tol)) & (a <= m1 * (1 + tol))
    ok &= (b >= 1 / (m1 * (1 + tol))) & (b <= 1 / (m1 * (1 - tol)))
    hits = np.flatnonzero(ok)
    return int(hits[0]) + 1 if hits.size else -1


def decode_edges(
    state: DecoderState, times_s: np.ndarray, cfg: TachoConfig
) -> tuple[DecoderState, Knots, list[SourceEvent]]:
    """Advance the wheel decoder by a block of edge times.

    Parameters
    ----------
    state : DecoderState
    times_s : (k,) float64, s
        Rising-edge times, increasing, continuing the previous call's.
    cfg : TachoConfig

    Returns
    -------
    state : DecoderState
    knots : Knots
        Newly committed knots, in time order.
    events : list of SourceEvent
        Sync, loss of sync (missed / extra edge, dropout), uncertain bridging.
    """
    teeth, gap, tol = cfg.teeth_per_rev, cfg.gap_teeth, cfg.tolerance
    per_rev = teeth - gap
    buf = np.concatenate((state.buf, np.asarray(times_s, dtype=float)))
    out_t: list[np.ndarray] = []
    out_n: list[np.ndarray] = []
    out_r: list[np.ndarray] = []
    runs: list[RunStart] = []
    events: list[SourceEvent] = []
    deferred: list[SourceEvent] = []
    st = evolve(state, buf=buf)
    while True:
        buf = st.buf
        if not st.synced:
            d = np.diff(buf)
            g = _find_sync(d, cfg)
            if g < 0:
                st = evolve(st, buf=buf[-3:])  # keep what a gap straddling the next block needs
                break
            # buf[g] is the last tooth before the gap (count -1), buf[g + 1] tooth 0
            st = evolve(
                st,
                buf=buf[g:],
                synced=True,
                confirmed=False,
                c0=-1,
                r_prev=float(d[g]) / (gap + 1),
            )
            continue
        d = buf[1:] - buf[:-1]  # np.diff's subtraction, without its Python wrapper
        if d.size < 2:
            break
        intervals = kernels.wheel_intervals if kernels.USE else wheel_intervals  # same bits
        c, n_rel, r, prev, ratio, b = intervals(buf, d, st.c0, teeth, gap, st.r_prev, tol)
        # a full revolution, up to the next gap's tooth 0, must pass before anything commits
        need = per_rev + 1 if gap else max(per_rev, 3) + 1
        if b >= 0 and (st.confirmed or b >= need) and ratio[b] > 1 + tol:
            # edges missing (a lost CAN frame of edges): fill them from the neighbouring teeth
            if b + 1 >= d.size:
                break  # the interval after the hole decides: wait for it
            filled = fill_missing_edges(buf, c, b, float(prev[b]), cfg)
            if filled is not None:
                times, count = filled
                holes, edges = st.fill_holes + 1, st.fill_edges + count
                st = evolve(st, fill_holes=holes, fill_edges=edges)
                if buf[b] - st.fill_reported_s >= FILL_REPORT_S:
                    # one line per FILL_REPORT_S of edges at most (a lossy bus fills often),
                    # counting the holes since the last one
                    since = "" if holes == 1 else f" in {holes} holes since the last report"
                    # (before the run is confirmed the fill is reported after its sync event,
                    # as when the two come in different blocks)
                    (events if st.confirmed else deferred).append(
                        SourceEvent(
                            "tacho_filled",
                            f"{edges} tacho edge(s) missing{since}, the last after t = "
                            f"{buf[b]:.6f} s ({d[b] * 1e3:.2f} ms): filled from the "
                            "neighbouring teeth",
                            float(buf[b]),
                            edges,
                        )
                    )
                    st = evolve(st, fill_holes=0, fill_edges=0, fill_reported_s=float(buf[b]))
                st = evolve(st, buf=np.concatenate((buf[: b + 1], times, buf[b + 1 :])))
                continue
        if not st.confirmed:
            if b >= 0 and b < need:
                st = evolve(st, buf=buf[b + 1 :], synced=False)
                continue
            if d.size < need:
                break
            st = _start_run(st, buf, r, cfg, events, runs)
            events += deferred
            deferred.clear()
        # commit every edge whose following interval passed (not buf[0]: already committed)
        end = b if b >= 0 else d.size  # intervals 0 .. end-1 passed, edges 1 .. end-1 commit
        if end >= 2 or (end >= 1 and not st.confirmed):
            lo = 1 if st.confirmed else 0
            sl = slice(lo, end)
            n_abs = st.run_base_n + n_rel[sl]
            out_t.append(buf[sl])
            out_n.append(n_abs)
            out_r.append(np.full(end - lo, st.run, dtype=np.int64))
        if not st.confirmed:
            st = evolve(st, confirmed=True)
        if b < 0:
            keep = buf.size - 2
            st = evolve(
                st,
                buf=buf[keep:],
                c0=int(c[keep]),
                r_prev=float(r[keep - 1]) if keep >= 1 else st.r_prev,
                last_t=float(buf[keep]),
                last_n=int(st.run_base_n + n_rel[keep]),
                last_r=float(r[keep - 1]) if keep >= 1 else st.last_r,
            )
            break
        # pattern broken at interval b
        last = max(end - 1, 0)
        st = evolve(
            st,
            last_t=float(buf[last]),
            last_n=int(st.run_base_n + n_rel[last]),
            last_r=float(prev[b]),
        )
        q = float(ratio[b])
        if q > 2.0 * (gap + 2):
            kind, what = "no_tacho", f"no tacho edge for {d[b] * 1e3:.1f} ms ({q:.1f} pitches)"
        elif q > 1:
            kind, what = "tacho_missing_edge", f"tooth interval {q:.2f} x the previous: missed edge"
        else:
            kind, what = "tacho_extra_edge", f"tooth interval {q:.2f} x the previous: extra edge"
        events.append(
            SourceEvent(
                kind,
                f"{what} at t = {buf[b]:.6f} s; re-synchronising at the next gap",
                float(buf[b]),
            )
        )
        st = evolve(st, buf=buf[b + 1 :], synced=False, lost_reason=kind)
    if len(out_t) == 1:  # the rule: one stretch of committed edges per block
        knots = Knots(out_t[0], out_n[0].astype(np.int64, copy=False), out_r[0], tuple(runs))
    elif out_t:
        knots = Knots(
            np.concatenate(out_t),
            np.concatenate(out_n).astype(np.int64),
            np.concatenate(out_r),
            tuple(runs),
        )
    else:
        knots = replace(Knots.empty(), runs=tuple(runs))
    return st, knots, events


def fill_missing_edges(
    buf: np.ndarray, c: np.ndarray, b: int, r_before: float, cfg: TachoConfig
) -> tuple[np.ndarray, int] | None:
    """The edge times missing in interval ``b`` of ``buf`` (tooth counts ``c``), or None.

    The interval is taken to skip ``k - 1 >= MIN_FILL_EDGES`` teeth when its length is
    within ``FILL_TOLERANCE`` pitches of the ``P_k`` pitches those teeth span (the wheel's
    gap counted), at the per-pitch interval of the neighbouring teeth (the mean of the one
    before and the one after), no other count comes as close, and the interval after it
    agrees with the one before within the decoder's tolerance. The missing edges go on a
    cubic in time over wheel position through the two edges around the hole, with the
    neighbouring per-pitch intervals as its slopes (each half a pitch off its end: at
    constant angular acceleration ``t''`` the times err by at most ``4/27 P t''``).
    """
    teeth, gap = cfg.teeth_per_rev, cfg.gap_teeth
    per_rev = teeth - gap
    if c[b] < 0 or b + 2 >= buf.size:
        return None
    d = buf[b + 1] - buf[b]
    d_after = buf[b + 2] - buf[b + 1]
    ks = np.arange(MIN_FILL_EDGES + 1, min(MAX_FILL_PITCHES, per_rev) + 1)
    if ks.size == 0:
        return None
    pos = _position(c[b] + np.arange(0, ks[-1] + 2), teeth, gap) - _position(
        np.array([c[b]]), teeth, gap
    )
    span = pos[ks]  # pitches from edge b to the edge after the hole, per candidate
    after = pos[ks + 1] - pos[ks]  # pitches of the interval after the hole
    r_after = d_after / after
    pitch = 0.5 * (r_before + r_after)
    # only counts under which the interval after the hole is a plausible pitch count
    # (else a count that puts the wheel's gap right after the hole fits any hole)
    miss = np.where(
        np.abs(r_after / r_before - 1.0) <= cfg.tolerance, np.abs(d / pitch - span), np.inf
    )
    best = int(np.argmin(miss))
    others = np.delete(miss, best)
    if not (miss[best] <= FILL_TOLERANCE and (others > 2 * FILL_TOLERANCE).all()):
        return None
    k = int(ks[best])
    # cubic Hermite t(p) on p in [0, P] through (0, t_b) and (P, t_b + d), slopes r_before, r_after
    big_p = float(span[best])
    s = pos[1:k] / big_p
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    times = h00 * buf[b] + h10 * big_p * r_before + h01 * buf[b + 1] + h11 * big_p * r_after[best]
    return times, k - 1


def _start_run(
    st: DecoderState,
    buf: np.ndarray,
    r: np.ndarray,
    cfg: TachoConfig,
    events: list[SourceEvent],
    runs: list[RunStart],
) -> DecoderState:
    """Number a freshly confirmed run: its absolute position, bridged from the last run."""
    teeth = cfg.teeth_per_rev
    t0 = float(buf[1])  # tooth 0 (first after the gap)
    run = st.run + 1
    if st.run < 0:
        base, reason, bridged = 0, "start", True
        message = f"tacho synchronised at t = {t0:.6f} s"
    else:
        # pitches elapsed at the mean of the tooth rates on both sides of the lost stretch
        pitch_s = 0.5 * (st.last_r + float(r[1]))
        est = st.last_n + (t0 - st.last_t) / pitch_s
        step = (
            teeth if cfg.gap_teeth else 1
        )  # tooth 0 sits on a whole revolution (wheel) or a pitch
        base = round(est / step) * step
        # the angle must keep increasing even when the count is a guess
        # (the gap's first edge, M + 1 pitches before tooth 0, is a knot of the new run too)
        base = max(base, -(-(st.last_n + cfg.gap_teeth + 2) // step) * step)
        slip = abs(est - base) / teeth
        revs = (t0 - st.last_t) / (pitch_s * teeth)
        bridged = slip < 0.25 * step / teeth and revs < MAX_BRIDGE_REVS
        reason = st.lost_reason or "tacho_resync"
        message = (
            f"tacho re-synchronised at t = {t0:.6f} s after {t0 - st.last_t:.3f} s "
            f"({revs:.2f} rev) without angle"
        )
        if not bridged:
            why = (
                f"longer than {MAX_BRIDGE_REVS:g} rev"
                if revs >= MAX_BRIDGE_REVS
                else f"{slip:.2f} rev off a whole count"
            )
            message += f"; revolution count uncertain ({why}): angle rebased"
    events.append(SourceEvent("tacho_sync", message, t0))
    if not bridged:
        # an outage: the lost stretch itself, as a span (the result document lists these)
        events.append(
            SourceEvent(
                "angle_gap",
                f"no crank angle from t = {st.last_t:.3f} s to {t0:.3f} s ({revs:.1f} rev); "
                + "angle re-acquired at the wheel gap",
                st.last_t,
                1,
                t0,
            )
        )
    runs.append(RunStart(run, t0, base, reason, bridged))
    return evolve(st, run=run, run_base_n=base)
