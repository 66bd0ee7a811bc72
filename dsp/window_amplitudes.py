"""Raw order amplitudes of consecutive frames, from the window sums of each tracked group.

Each frame's window sums (:func:`dsp.sum_rows.window_sums`) are normalised by the window's
weight, NaN where the tacho or the group is unusable, and flagged (``nan``, ``clipped``,
the reasons of the unsynchronised stretches they overlap). The leakage correction
(:func:`dsp.leakage.ramp_correction`) and the frame objects (:mod:`dsp.assemble`) come after.
On the compiled path a group without holes goes through :func:`dsp.kernels.group_amplitudes`
(the same bits in one call instead of some twenty array operations).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from dsp import angle as ang
from dsp import kernels
from dsp.gap_fit import refit
from dsp.state import TWO_PI, TrackerState
from dsp.sum_rows import window_sums


def window_amplitudes(st: TrackerState, js: np.ndarray) -> dict[str, np.ndarray]:
    """Window sums of frames ``js`` for every tracked group, normalised, with flags."""
    plan = st.plan
    cfg = plan.config
    n = cfg.frames_per_rev
    spacing = TWO_PI / n
    tw = math.radians(cfg.taper_deg)
    f, n_ch, n_int = js.size, len(plan.channels), plan.k2.size
    # a frame's flags: one shared empty set until it gets one (most frames never do)
    flags: list[frozenset[str]] = [frozenset()] * f
    tacho_bad = np.zeros(f, bool)
    bad_group = np.zeros((f, len(plan.groups)), bool)
    if st.invalid:
        lo_phi, hi_phi = (js - n) * spacing - 0.5 * tw, (js + n) * spacing + 0.5 * tw
    for inv in st.invalid:
        hit = np.flatnonzero((inv.phi_a < hi_phi) & (inv.phi_b > lo_phi))
        # a gap in a group that holds nothing but the spectrum channel only NaNs the spectrum
        if inv.group is None or not plan.groups[inv.group].spectrum_only:
            _flag(flags, hit, inv.reason)
        if inv.group is None:
            tacho_bad[hit] = True
        else:
            bad_group[hit, inv.group] = True
    # window start, centre and end of consecutive frames: f + 2 n distinct angles (the
    # compiled path: each frame's three in one call, the same bits)
    table = st.table
    finite = False
    if kernels.USE:
        times, omegas = np.empty((f, 3)), np.empty((f, 3))
        finite = kernels.window_times(
            js, n, spacing, table.t_lo, table.t_hi, table.phi_lo, table.phi_hi, table.c1,
            table.c2, table.c3, times, omegas,
        )  # fmt: skip
    if not finite:
        span = np.arange(int(js[0]) - n, int(js[-1]) + n + 1)
        at = (js[:, None] + np.array([-n - span[0], -span[0], n - span[0]])).ravel()
        times, omegas = ang.time_at(table, span * spacing)
        if not np.isfinite(times).all():
            times = interpolate_times(st, span * spacing, times)
        times, omegas = times[at].reshape(f, 3), omegas[at].reshape(f, 3)
    # every column is a tracked channel of exactly one group (dsp.config.make_plan), whose
    # branch below writes all of its rows: nothing to fill beforehand
    x = np.empty((f, n_int, n_ch), complex)
    ms = np.empty((f, n_ch))
    ok = np.empty((f, n_ch), bool)
    variance = np.ones((f, n_ch))
    for gi, g in enumerate(plan.groups):
        if not g.track_rows:
            continue
        holes = st.groups[gi].holes
        if kernels.USE and not holes[0].size:
            # sums, amplitudes and flags in one compiled call: the same bits as below
            # (without an unsynchronised stretch every frame is usable)
            usable = ~(tacho_bad | bad_group[:, gi]) if st.invalid else np.ones(f, bool)
            nan_rows, clip_rows, code = kernels.group_amplitudes(
                st.groups[gi].acc, js, n, n_int, usable, _cols_array(g.track_cols), x, ms, ok
            )
            if code & 1:
                _flag(flags, np.flatnonzero(nan_rows), "nan")
            if code & 2:
                _flag(flags, np.flatnonzero(clip_rows), "clipped")
            continue
        cols = _columns(g.track_cols)
        sums = kernels.window_sums if kernels.USE else window_sums  # the same bits
        s, w, msg, clipped = sums(
            st.groups[gi].acc, int(js[0]), int(js[-1]), n, len(g.track_rows), n_int
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            xg = 2.0 * s / w[:, None, None]  # (f, n_ch_g, n_int)
        if holes[0].size:
            # windows with missing samples: filled from the cycle before or fitted over the
            # samples present (dsp.gap_fit)
            lo_w, hi_w = (js - n) * spacing - 0.5 * tw, (js + n) * spacing + 0.5 * tw
            xg, factor = refit(xg, w, holes, lo_w, hi_w, plan.k2, plan.out, tw)
            variance[:, cols] = factor
        usable = ~(tacho_bad | bad_group[:, gi])
        if not usable.all():
            xg[~usable] = np.nan
            msg[~usable] = np.nan
        x[:, :, cols] = xg.transpose(0, 2, 1)
        ms[:, cols] = msg
        nan = ~np.isfinite(xg).all(axis=2) & usable[:, None]
        clip = clipped & usable[:, None]
        ok[:, cols] = usable[:, None] & ~nan & ~clip
        if nan.any():
            _flag(flags, np.flatnonzero(nan.any(axis=1)), "nan")
        if clip.any():
            _flag(flags, np.flatnonzero(clip.any(axis=1)), "clipped")
    return {
        "x": x,
        "ms": ms,
        "ok": ok,
        "variance": variance,
        "flags": np.array(flags, dtype=object),
        "times": times,
        "omegas": omegas,
        "tacho_bad": tacho_bad,
        "bad_group": bad_group,
    }


def _flag(flags: list[frozenset[str]], frames: np.ndarray, reason: str) -> None:
    """Add ``reason`` to the flags of ``frames`` (indices into ``flags``)."""
    for i in frames.tolist():
        flags[i] |= {reason}


@functools.cache
def _cols_array(cols: tuple[int, ...]) -> np.ndarray:
    """A group's channel columns as the compiled call takes them, made once (never
    modified; left writeable: numba compiles a read-only array as another type)."""
    return np.array(cols, dtype=np.int64)


def _columns(cols: tuple[int, ...]) -> slice | list[int]:
    """``cols`` as a slice when consecutive (a view to assign to, not a scatter)."""
    if cols == tuple(range(cols[0], cols[0] + len(cols))):
        return slice(cols[0], cols[0] + len(cols))
    return list(cols)


def interpolate_times(st: TrackerState, phis: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Times of angles inside an unsynchronised stretch, linear across it."""
    out = times.copy()
    for i in np.flatnonzero(~np.isfinite(times)):
        for inv in st.invalid:
            if inv.group is None and inv.phi_a <= phis[i] <= inv.phi_b and inv.phi_b > inv.phi_a:
                f = (phis[i] - inv.phi_a) / (inv.phi_b - inv.phi_a)
                out[i] = inv.t_a + f * (inv.t_b - inv.t_a)
                break
    return out
