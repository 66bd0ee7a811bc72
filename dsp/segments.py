"""Samples to segment sums: the per-sample work of the order tracker.

Samples wait in their group until the tacho has given an angle to their time
(:func:`process_group`); then each gets ``phi`` and ``omega`` and is added to
its segment's sums (:func:`dsp.sums.add_samples`). Sample gaps and jumps
between wheel runs are recorded as :class:`dsp.state.Invalid` stretches; the
cylinder-pressure votes for the 720 deg cycle are collected here too (:mod:`dsp.pressure_votes`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from acquisition.stream import SourceEvent
from dsp import angle as ang
from dsp import kernels
from dsp.config import GroupPlan
from dsp.gap_fit import fill_holes
from dsp.immutable import evolve
from dsp.pressure_votes import add_pressure, silent_pressure, steps_per_rev
from dsp.state import (
    TACHO_REASONS,
    GroupState,
    Invalid,
    TrackerState,
    last_complete_frame,
    set_group,
)
from dsp.sum_sets import Cut, SumSet
from dsp.sums import cut_samples, merge_rows, packed_rows

CHUNK = 16384


# (t0_s, rate_hz, spans) -> (indices, times, ok, phi, omega, run), spans as (first index, count),
# and the cuts of those samples (dsp.sums.cut_samples) by (first, end) sample: what groups on
# one sample clock share in a step
Shared = dict[tuple[int, int], Cut]
Angles = dict[
    tuple[float, float, tuple[tuple[int, int], ...]], tuple[tuple[np.ndarray, ...], Shared]
]


def process_groups(st: TrackerState, events: list[SourceEvent]) -> TrackerState:
    """:func:`process_group` for every group.

    Groups on one sample clock (accelerometers and cylinder pressure from one DAQ)
    usually wait for the same samples: their angles are looked up once.
    """
    angles: Angles = {}
    for gi in range(len(st.plan.groups)):
        st = process_group(st, gi, events, angles)
    return st


def process_group(
    st: TrackerState, gi: int, events: list[SourceEvent], angles: Angles | None = None
) -> TrackerState:
    """Give an angle to every waiting sample of group ``gi`` that the tacho has reached.

    ``angles`` carries lookups between the groups of one step (same table).
    """
    angles = {} if angles is None else angles
    gs = st.groups[gi]
    g = st.plan.groups[gi]
    if not gs.pend:
        return st
    first_new, rows_new = gs.pend[-1]
    t_new = g.t0_s + (first_new + rows_new.shape[1] - 1) / g.rate_hz
    # samples the tacho has not reached within max_wait_s are dropped: memory stays bounded
    t_stale = t_new - st.plan.config.max_wait_s
    t_end = st.table.t_end
    t_first = g.t0_s + gs.pend[0][0] / g.rate_hz
    if max(t_end, t_stale) <= t_first:
        return st  # the tacho has reached none of the samples and none is stale yet
    keep: list[tuple[int, np.ndarray]] = []
    spans: list[tuple[int, np.ndarray]] = []  # ready samples, CHUNK at most per span
    dropped = None
    for first, rows in gs.pend:
        n = rows.shape[1]
        n_ready = _count_before(first, n, g.t0_s, g.rate_hz, t_end)
        n_stale = _count_before(first, n, g.t0_s, g.rate_hz, t_stale)
        if n_stale > n_ready and dropped is None:
            dropped = g.t0_s + (first + n_ready) / g.rate_hz
        # in pieces of CHUNK samples: temporaries stay small enough to be recycled by
        # the allocator instead of mapped and faulted in afresh (1.7x faster at 25.6 kHz)
        for a in range(0, n_ready, CHUNK):
            spans.append((first + a, rows[:, a : min(a + CHUNK, n_ready)]))
        start = max(n_ready, n_stale)
        if start < n:
            keep.append((first + start, rows[:, start:]))
    if dropped is None and spans and _can_wait(st, g, gs, spans[-1]):
        # cut where the tacho stands now, as a pass now would: the same pieces later
        return set_group(st, gi, evolve(gs, pend=(*spans, *keep)))
    # The tacho stops a few teeth short of a block's end, so a step usually finds the
    # previous block's last samples and the new block: one pass over both, not two.
    for batch in _batches(spans):
        looked, shared = _look_up(st, g, batch, angles)
        st, gs = accumulate(st, gi, gs, looked, [rows for _, rows in batch], events, shared)
    if dropped is not None:
        if not gs.starved:
            events.append(
                SourceEvent(
                    "no_tacho",
                    f"group {g.name!r}: no crank angle for samples from t = {dropped:.3f} s "
                    f"(> {st.plan.config.max_wait_s:g} s behind): dropping them until the tacho "
                    "is back",
                    float(dropped),
                )
            )
        gs = evolve(gs, starved=True, pend=tuple(keep))
    elif gs.starved and len(keep) < len(gs.pend):
        gs = evolve(gs, starved=False, pend=tuple(keep))
    else:
        gs = evolve(gs, pend=tuple(keep))
    return set_group(st, gi, gs)


def _can_wait(st: TrackerState, g: GroupPlan, gs: GroupState, last: tuple[int, np.ndarray]) -> bool:
    """Whether the ready samples (the ``last`` span the newest) can wait for the next step:
    none of them can complete a frame. The next tacho edges usually reach the last teeth
    of the previous sample block, a pass over some twenty samples with the fixed cost of
    a whole block (a fifth of the tracker's time at 0.5 s blocks). Held back, and cut
    from the samples not yet reached, they are summed with the next samples as pieces of
    their own, which round as this pass would (dsp.sums): the frames are the same, bit
    for bit, and none comes later. Only inside one wheel run (the newest sample then has
    the largest angle) and never for a group whose pressure votes for the cycle."""
    table = st.table
    if not (
        st.next_frame is not None
        and g.pressure_at is None
        and gs.last_index >= 0
        and not gs.starved
        and table.run[0] == table.run[-1] == gs.last_run
    ):
        return False
    phi = ang.angle_at_one(table, g.t0_s + (last[0] + last[1].shape[1] - 1) / g.rate_hz)
    return math.isfinite(phi) and last_complete_frame(st, phi) < st.next_frame


def _batches(spans: list[tuple[int, np.ndarray]]) -> list[list[tuple[int, np.ndarray]]]:
    """Consecutive spans in batches of at most CHUNK samples.

    A one-sample span stays alone: numpy computes a one-element array on another path
    than a longer one (the complex product differs in the last bit), so its carriers
    are then those of a block of one sample, as they always were.
    """
    out: list[list[tuple[int, np.ndarray]]] = []
    size = CHUNK
    for span in spans:
        n = span[1].shape[1]
        if size + n > CHUNK or n == 1 or size == 1:
            out.append([])
            size = 0
        out[-1].append(span)
        size += n
    return out


def _look_up(
    st: TrackerState, g: GroupPlan, batch: list[tuple[int, np.ndarray]], angles: Angles
) -> tuple[tuple[np.ndarray, ...], Shared]:
    """Grid indices, times and :func:`dsp.angle.lookup` of the samples of ``batch``, and
    their cuts so far."""
    spans = tuple((first, r.shape[1]) for first, r in batch)
    key = (g.t0_s, g.rate_hz, spans)
    found = angles.get(key)
    if found is None:
        (first, _), (last, count) = spans[0], spans[-1]
        if last + count - first == sum(n for _, n in spans):  # no sample missing in between
            idx = np.arange(first, last + count, dtype=np.int64)
            looked = ang.lookup_grid(st.table, g.t0_s, g.rate_hz, idx)
        else:
            idx = np.concatenate([np.arange(f, f + n, dtype=np.int64) for f, n in spans])
            t = g.t0_s + idx / g.rate_hz
            looked = (t, *ang.lookup(st.table, t))
        found = angles[key] = ((idx, *looked), {})
    return found


def _count_before(first: int, n: int, t0: float, rate: float, t_lim: float) -> int:
    """How many of the grid indices ``first .. first+n-1`` have ``t0 + k / rate < t_lim``."""
    if not math.isfinite(t_lim):
        return n if t_lim > 0 else 0
    k = min(max(math.floor((t_lim - t0) * rate) - first, 0), n)
    # settle the boundary with the exact expression used for the times themselves
    while k < n and t0 + (first + k) / rate < t_lim:
        k += 1
    while k > 0 and not t0 + (first + k - 1) / rate < t_lim:
        k -= 1
    return k


def accumulate(
    st: TrackerState,
    gi: int,
    gs: GroupState,
    looked: tuple[np.ndarray, ...],
    pieces: list[np.ndarray],
    events: list[SourceEvent],
    shared: Shared | None = None,
) -> tuple[TrackerState, GroupState]:
    """Add samples to group ``gi``'s sums.

    ``looked`` = (grid indices, times, ok, phi, omega, run) of the samples, which come
    in ``pieces`` (kept rows, (n_keep, n_i)), the blocks they arrived in: the sums are
    split where pieces meet, so they round exactly as they would block by block.
    ``shared``: the cuts of these samples (:func:`dsp.sums.cut_samples`) that other
    groups on the same samples made in this step, and where this one leaves its own.
    """
    g = st.plan.groups[gi]
    cfg = st.plan.config
    idx, t, ok, phi, omega, run = looked
    if not ok.all():
        # samples without an angle (stream start, a tacho gap): rare, so piece by piece,
        # as the blocks came, and without them
        if len(pieces) > 1:
            p0 = 0
            for p in pieces:
                p1 = p0 + p.shape[1]
                one = tuple(v[p0:p1] for v in looked)
                st, gs = accumulate(st, gi, gs, one, [p], events)  # no cut shared
                p0 = p1
            return st, gs
        sel = np.flatnonzero(ok)
        if sel.size == 0:
            return st, gs
        pieces = [pieces[0][:, sel]]
        shared = None  # other samples than the looked-up ones
        idx, t = idx[sel], t[sel]
        phi, omega, run = phi[sel], omega[sel], run[sel]
    # breaks against the previous sample with an angle: a sample gap or a new wheel run
    # (indices increase and runs never go back, so the ends tell when there is none)
    started = gs.last_index >= 0
    smooth = int(idx[-1] - idx[0]) == idx.size - 1 and run[0] == run[-1]
    smooth &= not started or (idx[0] == gs.last_index + 1 and run[0] == gs.last_run)
    brk = np.empty(0, np.int64)
    if not smooth:
        prev_idx = np.concatenate(([gs.last_index], idx[:-1]))
        prev_run = np.concatenate(([gs.last_run], run[:-1]))
        brk = np.flatnonzero((idx - prev_idx != 1) | (run != prev_run))
        if brk.size and brk[0] == 0 and not started:
            brk = brk[1:]
    if brk.size:
        prev_phi = np.concatenate(([gs.last_phi], phi[:-1]))
        prev_t = np.concatenate(([gs.last_t], t[:-1]))
        inv = list(st.invalid)
        for b in brk:
            if run[b] != prev_run[b]:
                reason = st.runs[int(run[b])].reason if int(run[b]) in st.runs else "tacho_resync"
                reason = reason if reason in TACHO_REASONS else "tacho_resync"
                group = None
            else:
                reason, group = "missing_channel", gi
            inv.append(
                Invalid(
                    float(prev_phi[b]), float(phi[b]), float(prev_t[b]), float(t[b]), reason, group
                )
            )
        st = evolve(st, invalid=tuple(inv))
    # where each piece begins (Python ints: a list of two costs np.cumsum some microseconds)
    bounds = list(itertools.accumulate((p.shape[1] for p in pieces), initial=0))
    if g.pressure_at is not None:
        steps = steps_per_rev(st)
        skip_a, skip_b = silent_pressure(st, phi) if steps == 1 else (0, 0)
        for p, p0, p1 in zip(pieces, bounds[:-1], bounds[1:], strict=True):
            for a, b in ((p0, min(p1, skip_a)), (max(p0, skip_b), p1)):
                if b > a:
                    gs = add_pressure(gs, phi[a:b], p[g.pressure_at, a - p0 : b - p0], steps)
    acc, spec, holes, recent = gs.acc, gs.spec, gs.holes, gs.recent
    n_track = len(g.track_rows)
    at = g.spectrum_at
    if n_track or at is not None:
        # consecutive pieces only (a gap or a new run in between is an Invalid stretch)
        cuts: list[int] = [0, *brk.tolist(), int(idx.size)]
        for c0, c1 in itertools.pairwise(cuts):
            if c1 <= c0:
                continue
            x = [
                p[:, max(c0, p0) - p0 : min(c1, p1) - p0]
                for p, p0, p1 in zip(pieces, bounds[:-1], bounds[1:], strict=True)
                if p0 < c1 and p1 > c0
            ]
            sets = []
            if n_track:
                raw = [p[:n_track] for p in x]
                sets.append(SumSet(acc, raw, st.plan.k2, cfg.clip_level))
            if at is not None:
                # no clip check (clip_level is in the tracked channels' unit), no mean square
                sk2 = st.plan.spectrum_k2
                assert sk2 is not None
                sets.append(SumSet(spec, [p[at : at + 1] for p in x], sk2, tracked=False))
            args = (phi[c0:c1], omega[c0:c1], int(idx[c0]), g.rate_hz, cfg.frames_per_rev)
            cut = _cut(shared, c0, c1, [xi.shape[1] for xi in x], *args, cfg.taper_deg)
            packed = packed_rows(sets, cut, int(idx[c0]), cfg.frames_per_rev, kernels.USE)
            if n_track:
                # missing samples (a lost CAN frame) are filled from the previous engine
                # cycle, or summed as zeros and solved for (dsp.gap_fit), and remembered.
                # A non-finite sample makes its segment's sums non-finite: finite sums
                # (of these samples: earlier rows were checked when they came) spare the
                # pass over the samples, and a hole costs the sums twice
                tracked, holes, recent = fill_holes(
                    raw, phi[c0:c1], omega[c0:c1], g.rate_hz, holes, recent,
                    known_finite=bool(np.isfinite(packed[0]).all()),
                )  # fmt: skip
                if tracked is not raw:
                    sets[0] = SumSet(acc, tracked, st.plan.k2, cfg.clip_level)
                    packed = packed_rows(sets, cut, int(idx[c0]), cfg.frames_per_rev, kernels.USE)
            sums = [merge_rows(s.rows, cut.seg.mu, w) for s, w in zip(sets, packed, strict=True)]
            if n_track:
                acc = sums[0]
            if at is not None:
                spec = sums[-1]
    gs = evolve(
        gs,
        first_phi=float(phi[0]) if math.isnan(gs.first_phi) else gs.first_phi,
        last_index=int(idx[-1]),
        last_phi=float(phi[-1]),
        last_t=float(t[-1]),
        last_run=int(run[-1]),
        acc=acc,
        spec=spec,
        holes=holes,
        recent=recent,
    )
    return st, gs


def _cut(
    shared: Shared | None,
    c0: int,
    c1: int,
    sizes: list[int],
    phi: np.ndarray,
    omega: np.ndarray,
    first_index: int,
    rate_hz: float,
    frames_per_rev: int,
    taper_deg: float,
) -> Cut:
    """:func:`dsp.sums.cut_samples` of samples ``c0 .. c1 - 1`` (in pieces of ``sizes``),
    made once for every group on them (the samples and the cut where pieces meet are the
    same: the pieces are the spans of the lookup)."""
    cut = None if shared is None else shared.get((c0, c1))
    if cut is None:
        cut = cut_samples(phi, omega, sizes, rate_hz, frames_per_rev, taper_deg, kernels.USE)
        if shared is not None:
            shared[(c0, c1)] = cut
    return cut
