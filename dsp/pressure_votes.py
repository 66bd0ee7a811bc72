"""The cylinder pressure's votes for the 720 deg cycle, collected as samples get their angle.

Each TDC candidate (one per revolution with a wheel, one per pulse otherwise) sums the
pressure within reach of it (:func:`add_pressure`, called by :func:`dsp.segments.accumulate`);
once the candidates of a whole cycle are complete, the firing TDC among them decides the
cycle of their chain (:func:`decide_pressure`, called before frames are assembled).
"""

from __future__ import annotations

import math

import numpy as np

from dsp import cycle
from dsp.immutable import evolve
from dsp.state import TWO_PI, GroupState, TrackerState, chains_at


def silent_pressure(st: TrackerState, phi: np.ndarray) -> tuple[int, int]:
    """Samples ``a .. b-1`` whose pressure can no longer vote for a cycle (a, b = 0, 0 if any can).

    A TDC candidate ``k`` votes at ``2 pi k`` and ``2 pi (k + 1)`` for the chain of the run
    there (:func:`decide_pressure`). When the table is one run whose cycle is known, the
    votes of the candidates inside it are ignored: their sums are not worth the
    arithmetic (a twentieth of the tracker's time at 25.6 kHz). Only the
    newest candidates, whose next TDC lies beyond the table, are still summed.
    """
    table = st.table
    if table.run.size < 3 or table.run[0] != table.run[-1]:
        return 0, 0
    if st.chain_of_run.get(int(table.run[0]), -1) not in st.parity:
        return 0, 0
    # candidates k_lo .. k_hi-1: both votes inside [phi_lo[1], phi_hi[-2]], where
    # chains_at gives the run's chain whatever the rounding (and so will any later table)
    k_lo = math.ceil(float(table.phi_lo[1]) / TWO_PI)
    k_hi = math.floor(float(table.phi_hi[-2]) / TWO_PI)
    if k_hi <= k_lo:
        return 0, 0
    # their samples lie within 60 deg of 2 pi k, so between the half-way angles
    a, b = phi.searchsorted((TWO_PI * (k_lo - 0.5), TWO_PI * (k_hi - 0.5))).tolist()
    return a, b


def add_pressure(gs: GroupState, phi: np.ndarray, p: np.ndarray, steps: int = 1) -> GroupState:
    k, total, count = cycle.pressure_sums(phi, p, steps)
    if k.size == 0:
        return gs
    cands = dict(gs.pressure)
    # as Python numbers at once (tolist), not numpy scalars converted one by one
    for kk, tt, cc in zip(k.tolist(), total.tolist(), count.tolist(), strict=True):
        s0, c0 = cands.get(kk, (0.0, 0))
        cands[kk] = (s0 + tt, c0 + cc)
    return evolve(gs, pressure=cands)


def steps_per_rev(st: TrackerState) -> int:
    """How many candidate TDCs per revolution the tacho leaves (cycle.offset_steps)."""
    tc = st.plan.config.tacho
    return cycle.offset_steps(tc.kind, tc.teeth)


def decide_pressure(st: TrackerState) -> TrackerState:
    """Decide the chains' offsets from complete pressure candidates (in crank-angle order).

    A vote takes the ``2 N`` consecutive candidates of one 720 deg cycle (N = 1 for a
    wheel: two TDCs a revolution apart; N pulses: one at each pulse) and names the
    firing TDC among them (:func:`dsp.cycle.pressure_offset`) for the chain of the run
    at the cycle's last candidate.
    """
    parity = None
    groups = list(st.groups)
    changed = False
    steps = steps_per_rev(st)
    step = TWO_PI / steps
    half = cycle.pressure_half_width(steps)
    span = 2 * steps  # candidates per 720 deg cycle
    # a vote names the chain of a run (chains_at: one of chain_of_run's, or -1): once every
    # chain's offset is decided (the rule after the stream's first cycles) none can decide
    # anything, and only the complete candidates are dropped
    undecided = any(c not in st.parity for c in st.chain_of_run.values())
    for gi, g in enumerate(st.plan.groups):
        if g.pressure_row is None:
            continue
        gs = groups[gi]
        if not gs.pressure:
            continue
        done = sorted(k for k in gs.pressure if step * k + half < gs.last_phi)
        cands = gs.pressure
        complete = set(done)
        votes = []  # (last candidate of the cycle, offset) of the cycles that decide
        for k in done if undecided else ():
            if any(k + i not in complete for i in range(span)):
                continue
            means = np.array([cands[k + i][0] / max(cands[k + i][1], 1) for i in range(span)])
            s = cycle.pressure_offset(means, k, steps)
            if s is not None:
                votes.append((k + span - 1, s))
        if votes:
            # every vote's chain in one call: a block holds one cycle per two revolutions
            chains = chains_at(st, step * np.array([k for k, _ in votes]))
            parity = dict(st.parity) if parity is None else parity
            for (k, s), chain in zip(votes, chains.tolist(), strict=True):
                if chain >= 0 and chain not in parity:
                    parity[chain] = (s, step * k + half)
        if len(done) >= span:
            # the newest complete candidates still begin cycles with the next ones: keep them
            drop = set(done[: len(done) - (span - 1)])
            kept = {k: v for k, v in cands.items() if k not in drop}
            groups[gi] = evolve(gs, pressure=kept)
            changed = True
    if parity is not None:
        return evolve(st, groups=tuple(groups), parity=parity)
    return evolve(st, groups=tuple(groups)) if changed else st
