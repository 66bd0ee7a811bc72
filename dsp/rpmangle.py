"""Crank angle from an rpm channel anchored by once-per-revolution TDC pulses.

Between two consecutive pulses (exactly one revolution apart) the angle
follows the integral of the rpm channel, rescaled so the revolution is
exactly 2 pi:

    phi(t) = phi_a + 2 pi (R(t) - R(t_a)) / (R(t_b) - R(t_a)),   R = int rpm dt,

with the rpm linearly interpolated between its samples. The points
``(t, phi(t))`` at the rpm sample times become extra knots of the angle table,
so the same cubic interpolation as for a wheel applies. A pair of pulses is
expanded once the rpm channel has reached the second pulse.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

RPM_KEEP_S = 2.0


def _f() -> np.ndarray:
    return np.empty(0)


@dataclass(frozen=True)
class RpmAngleState:
    """rpm samples and pulse knots waiting to be expanded (arrays never modified in place)."""

    rpm_t: np.ndarray = field(default_factory=_f)  # (k,) s
    rpm: np.ndarray = field(default_factory=_f)  # (k,) rpm
    pulse_t: np.ndarray = field(default_factory=_f)  # (p,) s
    pulse_phi: np.ndarray = field(default_factory=_f)  # (p,) rad
    pulse_run: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))

    def with_rpm(self, t: np.ndarray, rpm: np.ndarray) -> RpmAngleState:
        good = np.isfinite(rpm) & (rpm > 0)
        return replace(
            self,
            rpm_t=np.concatenate((self.rpm_t, t[good])),
            rpm=np.concatenate((self.rpm, rpm[good])),
        )


def rpm_knots(
    state: RpmAngleState, t: np.ndarray, phi: np.ndarray, run: np.ndarray
) -> tuple[RpmAngleState, np.ndarray, np.ndarray, np.ndarray]:
    """Add pulse knots; return the knots (pulses and rpm points) now complete, in time order."""
    pt = np.concatenate((state.pulse_t, t))
    pp = np.concatenate((state.pulse_phi, phi))
    pr = np.concatenate((state.pulse_run, run))
    rpm_end = state.rpm_t[-1] if state.rpm_t.size else -np.inf
    out_t: list[np.ndarray] = []
    out_p: list[np.ndarray] = []
    out_r: list[np.ndarray] = []
    done = 0
    spacing = float(np.median(np.diff(state.rpm_t))) if state.rpm_t.size > 1 else 0.0
    for a in range(pt.size - 1):
        tb = pt[a + 1]
        if tb > rpm_end:
            break
        out_t.append(pt[a : a + 1])
        out_p.append(pp[a : a + 1])
        out_r.append(pr[a : a + 1])
        done = a + 1
        if pr[a] != pr[a + 1]:
            continue
        # rpm samples too close to a pulse would make a knot pair nearly coincident
        # (ill-conditioned cubic): keep a quarter of the rpm sample spacing clear
        margin = 0.25 * spacing
        inside = (state.rpm_t > pt[a] + margin) & (state.rpm_t < tb - margin)
        ts = state.rpm_t[inside]
        if ts.size == 0 or state.rpm_t[0] > pt[a]:
            continue  # no rpm sample before the pair: the cubic through the pulses alone
        nodes = np.concatenate(([pt[a]], ts, [tb]))
        vals = np.interp(nodes, state.rpm_t, state.rpm)
        cum = np.concatenate(([0.0], np.cumsum(0.5 * (vals[1:] + vals[:-1]) * np.diff(nodes))))
        frac = cum[1:-1] / cum[-1]
        out_t.append(ts)
        out_p.append(pp[a] + (pp[a + 1] - pp[a]) * frac)
        out_r.append(np.full(ts.size, pr[a], dtype=np.int64))
    # keep one rpm sample before the oldest pending pulse, for interpolation; before the
    # first pulse, the last RPM_KEEP_S seconds (the pulses may come later than the rpm)
    keep_t = pt[done] if pt.size else rpm_end - RPM_KEEP_S
    first = max(int(np.searchsorted(state.rpm_t, keep_t, side="left")) - 1, 0)
    new = RpmAngleState(
        rpm_t=state.rpm_t[first:],
        rpm=state.rpm[first:],
        pulse_t=pt[done:],
        pulse_phi=pp[done:],
        pulse_run=pr[done:],
    )
    if not out_t:
        return new, np.empty(0), np.empty(0), np.empty(0, dtype=np.int64)
    return new, np.concatenate(out_t), np.concatenate(out_p), np.concatenate(out_r)
