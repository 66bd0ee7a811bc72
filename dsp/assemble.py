"""From segment sums to order frames: readiness, leakage correction, flags.

The window amplitudes come from :mod:`dsp.window_amplitudes`, the ramp correction
from :func:`dsp.leakage.ramp_correction`.

Frame ``j`` (window ``c_j +- 360 deg``, ``c_j = j * 360 / frames_per_rev`` deg in
the wheel angle) is ready once every watched group has processed a sample past
the window's end, and, with a cam or pressure reference, once the 720 deg
cycle is known or ``cycle_wait_revs`` have passed. Both conditions are in crank
angle, not arrival time, so any block cut gives the same frames. Frames whose
centre falls in an unsynchronised tacho stretch are not produced; frames that
overlap one carry its flag and NaN amplitudes.

All ready frames of a step are computed together (array operations over
frames): at 4500 rpm a one-second block completes 75 of them.
"""

from __future__ import annotations

import math

import numpy as np

from dsp import angle as ang
from dsp import cycle, kernels
from dsp.frame_constants import frame_constants, rotation
from dsp.frame_figures import frame_codes_numpy, frame_figures_numpy
from dsp.frames import OrderFrame
from dsp.gap_fit import forget_holes
from dsp.immutable import evolve
from dsp.leakage import ramp_correction
from dsp.pressure_votes import decide_pressure
from dsp.rejoin import rejoin
from dsp.state import TWO_PI, TrackerState, last_complete_frame
from dsp.sum_rows import drop_before, window_sums
from dsp.window_amplitudes import window_amplitudes

CHUNK = 512  # frames computed together at most (bounds memory after a long dropout)
_SPECTRUM_COLUMN = np.zeros(1, np.int64)  # the spectrum channel's column in its x (never modified)
_new_frame = object.__new__
_set_dict = object.__setattr__
_NO_SPECTRUM = np.empty((0, 0, 1), complex)  # the compiled call's spectrum when there is none


def emit(st: TrackerState) -> tuple[TrackerState, list[OrderFrame]]:
    """Every frame that the data processed so far completes, in order."""
    plan = st.plan
    cfg = plan.config
    st = decide_pressure(st)
    tracked = [gi for gi, g in enumerate(plan.groups) if g.track_rows]
    watched = [
        gi
        for gi, g in enumerate(plan.groups)
        if g.track_rows or g.pressure_row is not None or g.spectrum_row is not None
    ]
    if not tracked:
        return st, []
    n = cfg.frames_per_rev
    spacing = TWO_PI / n
    tw = math.radians(cfg.taper_deg)
    if st.next_frame is None:
        firsts = [st.groups[gi].first_phi for gi in tracked]
        if any(math.isnan(f) for f in firsts):
            return st, []
        # the first window that starts after the first sample with an angle
        st = evolve(st, next_frame=math.ceil((max(firsts) + 0.5 * tw) / spacing) + n)
    front = min(st.groups[gi].last_phi for gi in watched)
    if not math.isfinite(front):
        return st, []  # a watched group (the spectrum's own, say) has had no angle yet
    assert st.next_frame is not None
    j_max = last_complete_frame(st, front)
    frames: list[OrderFrame] = []
    for a, b in _ranges(st, st.next_frame, j_max, spacing):
        for c0 in range(a, b + 1, CHUNK):
            js = np.arange(c0, min(c0 + CHUNK - 1, b) + 1)
            st, new, done = _batch(st, js, front)
            frames.extend(new)
            if not done:
                return st, frames
        if st.next_frame != b + 1:
            st = evolve(st, next_frame=b + 1)
    if st.next_frame is not None and j_max + 1 > st.next_frame:
        st = evolve(st, next_frame=j_max + 1)
    return st, frames


def _ranges(st: TrackerState, j0: int, j1: int, spacing: float) -> list[tuple[int, int]]:
    """``[j0, j1]`` without the frames centred in an unsynchronised tacho stretch."""
    if j1 < j0:
        return []
    cuts = sorted(
        (math.floor(inv.phi_a / spacing) + 1, math.ceil(inv.phi_b / spacing) - 1)
        for inv in st.invalid
        if inv.group is None
    )
    out = []
    lo = j0
    for a, b in cuts:
        if b < lo or a > b:
            continue
        if a > lo:
            out.append((lo, min(a - 1, j1)))
        lo = max(lo, b + 1)
        if lo > j1:
            break
    if lo <= j1:
        out.append((lo, j1))
    return [(a, b) for a, b in out if a <= b]


def _chains(st: TrackerState, js: np.ndarray, spacing: float) -> tuple[np.ndarray, int | None]:
    """Parity chain of the run holding each frame's centre ``js * spacing`` (rad; -1
    outside every run), and the chain when all of them lie inside one run's span (else
    None); ``js`` increasing."""
    table = st.table
    if table.run.size and table.run[0] == table.run[-1]:
        # one run in the table (no re-sync within reach): one chain, inside its angle span
        only = st.chain_of_run.get(int(table.run[0]), -1)
        lo, hi = table.phi_lo[0], table.phi_hi[-1]
        # (the first and last angle as numpy makes them: the integer made a float, times spacing)
        if js.size and int(js[0]) * spacing >= lo and int(js[-1]) * spacing <= hi:
            # increasing angles, all inside
            return np.full(js.size, only, dtype=np.int64), only
        phis = js * spacing
        return np.where((phis >= lo) & (phis <= hi), only, -1), None
    phis = js * spacing
    t, _ = ang.time_at(table, phis)
    out = np.full(phis.size, -1, dtype=np.int64)
    good = np.isfinite(t)
    if good.any():
        ok, _, _, run = ang.lookup(st.table, t[good])
        chain = np.array([st.chain_of_run.get(int(r), -1) for r in run], dtype=np.int64)
        out[good] = np.where(ok, chain, -1)
    return out, None


def _batch(
    st: TrackerState, js: np.ndarray, front: float
) -> tuple[TrackerState, list[OrderFrame], bool]:
    """Frames ``js`` (consecutive); stops early at the first one still waiting for the cycle."""
    cfg = st.plan.config
    n = cfg.frames_per_rev
    spacing = TWO_PI / n
    tw = math.radians(cfg.taper_deg)
    chains, only = _chains(st, js, spacing)
    referenced = cfg.tacho.phase_reference != "none"
    wait = cfg.cycle_wait_revs * TWO_PI if referenced else 0.0
    done = True
    settled = None if only is None else st.parity.get(only)
    # the first frame's end angle as numpy makes end_phi[0] below (the same bits)
    if settled is not None and settled[1] <= (int(js[0]) + n) * spacing + 0.5 * tw + wait:
        # the rule: one chain, its offset decided before the first frame's end, so before
        # every frame's (their ends increase): all decided, none waits, one parity
        parity = np.full(js.size, settled[0], dtype=np.int64)
        ambiguous = np.zeros(js.size, bool)
    else:
        # the chains' decided offsets, looked up once per frame (a batch holds one or two)
        end_phi = (js + n) * spacing + 0.5 * tw
        known = [st.parity.get(c) for c in chains.tolist()]
        ends = end_phi.tolist()
        decided = np.array(
            [k is not None and k[1] <= e + wait for k, e in zip(known, ends, strict=True)],
            dtype=bool,
        )
        if referenced:
            ready = decided | (front >= end_phi + wait)
            stop = int(np.argmin(ready)) if not ready.all() else js.size
            if stop < js.size:
                js, chains, decided, done = js[:stop], chains[:stop], decided[:stop], False
                known = known[:stop]
            if js.size == 0:
                return st, [], False
        use = zip(known, decided.tolist(), strict=True)
        parity = np.array([k[0] if k is not None and d else 0 for k, d in use], dtype=np.int64)
        ambiguous = ~decided
    raw = window_amplitudes(st, js)
    st, x, corrected = _correct(st, js, chains, raw["x"], raw["tacho_bad"])
    st, spectrum = _spectrum(st, js, chains, raw)
    frames = _finish(st, js, raw, x, corrected, parity, ambiguous, chains, spectrum)
    # (a frame is rebased where its chain is above 0: _finish's flag bit 4)
    st, frames = rejoin(st, frames, chains, None if only is None else only > 0)
    return _forget(st, int(js[-1]) + 1), frames, done


def _correct(
    st: TrackerState, js: np.ndarray, chains: np.ndarray, x: np.ndarray, tacho_bad: np.ndarray
) -> tuple[TrackerState, np.ndarray, np.ndarray]:
    """Remove ramp leakage from the tracked channels (:func:`dsp.leakage.ramp_correction`)."""
    plan = st.plan
    history, x, good = ramp_correction(
        st.history, js, chains, x, tacho_bad, plan.same, plan.image,
        plan.config.frames_per_rev, plan.config.leakage_correction,
    )  # fmt: skip
    return evolve(st, history=history), x, good


def _spectrum(
    st: TrackerState, js: np.ndarray, chains: np.ndarray, raw: dict[str, np.ndarray]
) -> tuple[TrackerState, np.ndarray | None]:
    """The spectrum channel's orders 0, 0.5, .. of frames ``js``, leakage-corrected:
    ``(f, n_spec_internal, 1)`` complex, NaN in full where the window is not usable.

    Order 0 is the window mean, ``sum w x q / sum w q``: half the sum the other orders
    are taken with. The ramp correction then sees it with the right weight as a source
    (``Re{X_0}`` leaks like any order's real part); as a target its coupling rows are
    halved in the plan (:func:`dsp.config.make_plan`).
    """
    plan = st.plan
    gi = plan.spectrum_group
    if gi is None or plan.spectrum_k2 is None:
        return st, None
    assert plan.spectrum_same is not None and plan.spectrum_image is not None
    cfg = plan.config
    n = cfg.frames_per_rev
    spacing = TWO_PI / n
    tw = math.radians(cfg.taper_deg)
    sk2 = plan.spectrum_k2
    gs = st.groups[gi]
    # a window that begins before the channel's first sample (its group may start later
    # than the tracked ones) has missing sums, not zeros
    # (the rule: no unsynchronised stretch, from which alone window_amplitudes marks
    # frames bad, and the first window's start, so every one's, after the first sample)
    every = not st.invalid and (int(js[0]) - n) * spacing - 0.5 * tw >= gs.first_phi
    if every:
        usable = np.ones(js.size, bool)
    else:
        lo_phi = (js - n) * spacing - 0.5 * tw
        usable = ~(raw["tacho_bad"] | raw["bad_group"][:, gi]) & (lo_phi >= gs.first_phi)
    if kernels.USE:
        # sums and 2 s / w in one compiled call, as the tracked groups': the same bits
        x = np.empty((js.size, sk2.size, 1), complex)  # as the tracked channels' (f, n_int, n_ch)
        scratch = np.empty((js.size, 1)), np.empty((js.size, 1), bool)
        nan_rows, _, code = kernels.group_amplitudes(
            gs.spec, js, n, sk2.size, usable, _SPECTRUM_COLUMN, x, *scratch
        )
        x[:, 0, 0] *= 0.5
        if code & 1:
            usable &= ~nan_rows  # the halved mean keeps finite what was
            every = False
    else:
        s, w, _, _ = window_sums(gs.spec, int(js[0]), int(js[-1]), n, 1, sk2.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            x = 2.0 * s / w[:, None, None]  # (f, 1, n_spec)
        x[:, :, 0] *= 0.5
        x = x.transpose(0, 2, 1)  # (f, n_spec, 1), as the tracked channels' (f, n_int, n_ch)
        usable &= np.isfinite(x).all(axis=(1, 2))
        every = False
    if not every:
        x[~usable] = np.nan
    history, x, _ = ramp_correction(
        st.spec_history, js, chains, x, raw["tacho_bad"], plan.spectrum_same,
        plan.spectrum_image, n, cfg.leakage_correction,
    )  # fmt: skip
    return evolve(st, spec_history=history), x


def _finish(
    st: TrackerState,
    js: np.ndarray,
    raw: dict[str, np.ndarray],
    x: np.ndarray,
    corrected: np.ndarray,
    parity: np.ndarray,
    ambiguous: np.ndarray,
    chains: np.ndarray,
    spectrum: np.ndarray | None = None,
) -> list[OrderFrame]:
    plan = st.plan
    cfg = plan.config
    tc = cfg.tacho
    spacing = TWO_PI / cfg.frames_per_rev
    times, omegas = raw["times"], raw["omegas"]
    # from the wheel angle to the crank angle: half orders flip with the cycle; with N pulses
    # per revolution every order turns by the offset the cam found (cycle.offset_rotation)
    steps = cycle.offset_steps(tc.kind, tc.teeth)
    const = frame_constants(plan)
    # each frame's angle and flag bits (dsp.frame_figures.frame_codes_numpy: 16 a window
    # lost samples, 8 ambiguous cycle, 4 rebased, 2 rpm in range, 1 uncorrected); the
    # angle j * spacing + 2 pi p / steps as Python computes it for ints j, p: the same bits
    code_args = (js, parity, spacing, steps, chains, ambiguous)
    more = (raw["ok"], corrected, cfg.leakage_correction, raw["variance"])
    if kernels.USE:
        # figures, codes and the turn of a wheel's frames in one compiled call instead of
        # some thirty array operations: the same bits (dsp.frame_figures)
        f, n_ch = js.size, x.shape[2]
        k = const.spectrum_k if spectrum is not None else const.spectrum_k[:0]
        out, spec = np.empty((f, const.k2.size, n_ch), complex), np.empty((f, k.size), complex)
        rpm, rpm_change, leak = np.empty(f), np.empty(f), np.empty((f, n_ch))
        angles, codes = np.empty(f), np.empty(f, np.int64)
        kernels.frame_outputs(
            times, omegas, x, np.abs(x), raw["ms"], corrected, plan.out, const.signs,
            _NO_SPECTRUM if spectrum is None else spectrum, const.spectrum_signs,
            *code_args, cfg.rpm_min, cfg.rpm_max, raw["ok"], cfg.leakage_correction,
            raw["variance"], out, spec, rpm, rpm_change, leak, angles, codes,
        )  # fmt: skip
        if steps > 1:  # N pulses: numpy's complex exponentials, as below
            out = out * rotation(parity, const.k2, steps, const.signs)[:, :, None]
            spec = spec * rotation(parity, k, steps, const.spectrum_signs)
            spec[:, :1] = spec[:, :1].real
    else:
        out = x[:, plan.out, :]  # (f, n_orders, n_ch)
        rpm, rpm_change, leak = frame_figures_numpy(
            times, omegas, x, raw["ms"], corrected, plan.out
        )
        out = out * rotation(parity, const.k2, steps, const.signs)[:, :, None]
        if spectrum is not None:
            k = const.spectrum_k
            spec = spectrum[:, : k.size, 0] * rotation(parity, k, steps, const.spectrum_signs)
            spec[:, 0] = spec[:, 0].real  # the mean: real, its correction is real to rounding
        angles, codes = frame_codes_numpy(*code_args, rpm, (cfg.rpm_min, cfg.rpm_max), *more)
    spectra: list[np.ndarray | None] = [None] * js.size if spectrum is None else list(spec)
    # N pulses without a decided reference: phi is only known modulo 360/N deg
    pulses_unknown = steps > 1
    orders = const.orders
    cache: dict[int, frozenset[str]] = {}
    frames = []
    # a variance factor only where a window lost samples (most frames have none)
    variances: list[np.ndarray | None] = [None] * js.size
    code_list = codes.tolist()
    if max(code_list) >= 16:
        for i, code in enumerate(code_list):
            if code & 16:
                variances[i] = raw["variance"][i]
    columns = zip(
        angles.tolist(), times[:, 1].tolist(), rpm.tolist(), rpm_change.tolist(),
        list(out), list(raw["ok"]), list(leak), raw["flags"].tolist(), code_list, spectra,
        variances, strict=True,
    )  # fmt: skip
    channels, spectrum_channel = plan.channels, cfg.spectrum_channel
    for angle, t, r, dr, amp, ok, lk, raw_flags, code, sp, var in columns:
        # most frames share one set of flags: build each distinct set once
        flags = None if raw_flags else cache.get(code & 15)
        if flags is None:
            new = set(raw_flags)
            if code & 8:
                new.add("cycle_ambiguous")
                if pulses_unknown:
                    new.add("angle_ambiguous")
            if code & 4:
                # an unbridged re-sync: revolution count and cycle may differ from the stream start's
                new.add("angle_rebased")
            if not code & 2:
                new.add("rpm_out_of_range")
            if code & 1:
                # no frame one cycle earlier (stream start, long re-sync): sweep leakage remains
                new.add("leakage_uncorrected")
            flags = frozenset(new)
            if not raw_flags:
                cache[code & 15] = flags
        # the dataclass's fields set directly, its instance dict made whole: its generated
        # __init__ of a frozen class sets them one object.__setattr__ at a time (1.9 us a
        # frame against 0.3 us)
        frame = _new_frame(OrderFrame)
        _set_dict(
            frame,
            "__dict__",
            {
                "time_s": t,
                "rpm": r,
                "crank_angle_rad": angle,
                "orders": orders,
                "channels": channels,
                "amplitudes": amp,
                "channel_ok": ok,
                "rpm_change": dr,
                "leakage": lk,
                "flags": flags,
                "spectrum": sp,
                "spectrum_channel": spectrum_channel,
                "variance_factor": var,
            },
        )
        frames.append(frame)
    return frames


def _forget(st: TrackerState, j_next: int) -> TrackerState:
    """Drop sums, stretches and angle pieces that no frame from ``j_next`` on needs."""
    n = st.plan.config.frames_per_rev
    spacing = TWO_PI / n
    tw = math.radians(st.plan.config.taper_deg)
    lo_phi = (j_next - n) * spacing - 0.5 * tw
    groups = []
    for gs in st.groups:
        acc = drop_before(gs.acc, j_next - n)
        spec = drop_before(gs.spec, j_next - n)
        holes = forget_holes(gs.holes, lo_phi)
        if acc is not gs.acc or spec is not gs.spec or holes is not gs.holes:
            # a group with nothing to drop (the spectrum's own, a quiet one) stays as it is
            gs = evolve(gs, acc=acc, spec=spec, holes=holes)
        groups.append(gs)
    invalid = st.invalid
    if invalid and any(inv.phi_b < lo_phi for inv in invalid):
        invalid = tuple(inv for inv in invalid if inv.phi_b >= lo_phi)
    t_keep = ang.time_at_one(st.table, lo_phi - spacing)
    table = ang.trim(st.table, t_keep) if math.isfinite(t_keep) else st.table
    return evolve(st, groups=tuple(groups), invalid=invalid, table=table, next_frame=j_next)
