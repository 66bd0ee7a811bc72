"""The elastic-mode tail: inertia and cog extrapolated to 0 Hz once an elastic mode is confirmed.

Below an elastic mode its response grows like (f / f_e)^2, and the part of its
shape that looks rigid at the sensors biases the fit long before the rigidity
residual sees the mode. Once the residual gate has confirmed a mode
(:mod:`estimator.gating`: ``ELASTIC_CONFIRM`` of the last ``ELASTIC_WINDOW``
gated frames of one order non-rigid), the inertia and cog are fitted as
``theta + (f / ELASTIC_F_REF_HZ)^2 a`` and ``theta``, the rigid value
extrapolated to f = 0, is reported (as the mass line's residual stiffness term
does for a modal test). The f^2 columns are accumulated from the first frame
on, so the frames added before the detection are corrected too; without a
detection they are not used. Measured on the simulated i3 with a 140 Hz mode,
6 seeds of the realistic errors: largest cog error 1.0-4.7 mm -> 1.7-2.8 mm.
"""

from __future__ import annotations

import numpy as np

from acquisition.stream import SourceEvent
from estimator.compiled_sums import kernel_tail_sums
from estimator.hypotheses import Accumulator, Redundancy, add_frames, add_frames_redundant

ELASTIC_F_REF_HZ = 100.0
ELASTIC_TERMS = 9  # the six inertia terms and G, the first nine entries of theta


def with_tail(H: np.ndarray, f_hz: np.ndarray) -> np.ndarray:
    """Rows (P, 12, n) with the tail columns appended: (P, 12, n + ELASTIC_TERMS), the
    inertia and cog columns times ``(f / ELASTIC_F_REF_HZ)^2`` (``f_hz`` (P,) per pair)."""
    phi = tail_factors(f_hz)[:, None, None]
    return np.concatenate([H, H[:, :, :ELASTIC_TERMS] * phi], axis=2)


def tail_factors(f_hz: np.ndarray) -> np.ndarray:
    """Each pair's factor ``(f / ELASTIC_F_REF_HZ)^2`` on the tail's columns (``f_hz`` (P,)):
    one formula for the widened rows and the compiled sums, which must agree bit for bit."""
    return (f_hz / ELASTIC_F_REF_HZ) ** 2


def add_with_tail(
    acc: Accumulator,
    H: np.ndarray,
    y: np.ndarray,
    dr: np.ndarray,
    bounds: np.ndarray,
    forgetting: float,
    f_hz: np.ndarray,
    compiled: bool = False,
    redundancy: Redundancy | None = None,
) -> Accumulator:
    """Consecutive frames' rows (:func:`estimator.hypotheses.add_frames`' arguments, H
    without the tail) added, with their tail columns (:func:`with_tail`, ``f_hz`` per
    pair), to a state over theta and the tail; with their ``redundancy`` rows when
    self-calibrating. ``compiled`` (and no redundancy rows): the sums by
    :func:`estimator.compiled_sums.kernel_tail_sums`, the tail's scaled from theta's
    (no widened copy of H; why: :mod:`estimator.compiled_sums`)."""
    if compiled and redundancy is None:
        return kernel_tail_sums(
            acc, H, y, dr, bounds, forgetting, tail_factors(f_hz), ELASTIC_TERMS
        )
    Ha = with_tail(H, f_hz)
    if redundancy is not None:
        return add_frames_redundant(acc, Ha, y, dr, bounds, forgetting, redundancy)
    return add_frames(acc, Ha, y, dr, bounds, forgetting)


def effective_state(acc: Accumulator, n: int, scale: np.ndarray, elastic: bool) -> Accumulator:
    """The state of theta (``n`` parameters, ``scale`` theirs) in an accumulator over
    theta and the tail: with ``elastic`` (a confirmed mode) the tail fitted alongside,
    otherwise left out."""
    if not elastic:
        return acc.leading(n)
    return acc.marginal(n, np.concatenate([scale, scale[:ELASTIC_TERMS]]))


def elastic_mode_event(mode: dict[str, float], time_s: float) -> SourceEvent:
    """What the estimator tells the sinks when the residual gate confirms a mode
    (``mode``: order and frequency_hz where it was confirmed)."""
    return SourceEvent(
        "elastic_mode",
        f"elastic mode confirmed: H{mode['order']:g} non-rigid from "
        f"{mode['frequency_hz']:.0f} Hz; inertia and cog now extrapolated to 0 Hz",
        time_s,
    )
