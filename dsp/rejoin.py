"""After a tacho outage too long to count the revolutions across: the angle re-acquired.

The wheel re-synchronises at its gap, so the angle after an outage is right modulo one
revolution (:mod:`dsp.wheel`: ``bridged=False``, a new parity chain); every integer
order is then exact. What is unknown is the 720 deg cycle, i.e. the sign of the half
orders relative to the stream before the outage:

* a cam or pressure reference decides it per chain (:mod:`dsp.assemble`): such frames
  are as good as any;
* without one the half orders are continued across the outage: along the mass line an
  order's amplitude pattern over the channels changes slowly with rpm, while a slipped
  cycle turns every half order by 180 deg. The first frame of the new chain whose half
  orders are measured is compared with the last one before (the normalised correlation
  of the half-order amplitudes over every channel); beyond ``MIN_CORRELATION`` either
  way the chain's sign is decided, its half orders turned to the stream's convention and
  its crank angle by a revolution where they flip.

Until decided (or where the tacho cannot give the angle modulo a revolution: N pulses,
rpm) frames keep the ``angle_rebased`` flag and the estimator does not use them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dsp.frame_constants import frame_constants
from dsp.frames import OrderFrame
from dsp.immutable import evolve
from dsp.state import TWO_PI, TrackerState

MIN_CORRELATION = 0.5


def rejoin(
    st: TrackerState, frames: list[OrderFrame], chains: np.ndarray, rebased: bool | None = None
) -> tuple[TrackerState, list[OrderFrame]]:
    """Frames of re-synchronised chains with their angle re-acquired where it can be.

    ``rebased``: whether any frame has the ``angle_rebased`` flag, if the caller knows
    (None: the frames' flags are looked at)."""
    half = frame_constants(st.plan).half
    if rebased is None:
        rebased = any("angle_rebased" in f.flags for f in frames)
    if not rebased:
        # the rule: nothing to re-acquire; only the reference moves on to the last frame
        # whose half orders were measured (found from the end: usually the last one)
        if half.size:
            for f in reversed(frames):
                last = f.amplitudes[half]
                if _measured(last):
                    return evolve(st, half_ref=last), frames
        return st, frames
    tc = st.plan.config.tacho
    once_per_rev = tc.kind in ("wheel", "pulses") and (tc.gap_teeth > 0 or tc.teeth_per_rev == 1)
    signs = st.chain_sign
    ref = st.half_ref
    out = []
    for frame, chain in zip(frames, chains.tolist(), strict=True):
        if "angle_rebased" in frame.flags and once_per_rev:
            if "cycle_ambiguous" not in frame.flags or half.size == 0:
                frame = replace(frame, flags=frame.flags - {"angle_rebased"})
            else:
                if chain not in signs and ref is not None:
                    sign = _continue(ref, frame.amplitudes[half])
                    if sign:
                        signs = {**signs, chain: sign}
                if chain in signs:
                    frame = _turned(frame, half, signs[chain])
        if half.size and "angle_rebased" not in frame.flags and _measured(frame.amplitudes[half]):
            ref = frame.amplitudes[half]
        out.append(frame)
    if signs is not st.chain_sign or ref is not st.half_ref:
        st = evolve(st, chain_sign=signs, half_ref=ref)
    return st, out


def _measured(x: np.ndarray) -> bool:
    """Half-order amplitudes with at least half of them finite (a frame to continue from)."""
    return int(np.isfinite(x).sum()) >= x.size // 2


def _continue(ref: np.ndarray, x: np.ndarray) -> int:
    """+1 or -1: the sign that continues the half orders ``ref`` into ``x``; 0: undecided."""
    ok = np.isfinite(ref) & np.isfinite(x)
    if ok.sum() < 3:
        return 0
    a, b = ref[ok], x[ok]
    norm = float(np.linalg.norm(a) * np.linalg.norm(b))
    if norm <= 0.0:
        return 0
    corr = float(np.real(np.vdot(a, b))) / norm
    if corr >= MIN_CORRELATION:
        return 1
    if corr <= -MIN_CORRELATION:
        return -1
    return 0


def _turned(frame: OrderFrame, half: np.ndarray, sign: int) -> OrderFrame:
    """The frame in the stream's cycle convention: half orders times ``sign``, the crank
    angle a revolution on where they flip, the flag gone."""
    amp = frame.amplitudes
    angle = frame.crank_angle_rad
    if sign < 0:
        amp = amp.copy()
        amp[half] *= -1.0
        angle = angle + TWO_PI
    return replace(
        frame, amplitudes=amp, crank_angle_rad=angle, flags=frame.flags - {"angle_rebased"}
    )
