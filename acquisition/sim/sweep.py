"""Rpm profiles: piecewise-linear rpm, the exact crank angle and its inverse.

A profile is a chain of segments, each a linear rpm ramp over a duration
(a hold is a ramp with equal ends; a step is two segments whose ends differ).
Within a segment the angular speed is ``omega(tau) = w0 + a tau`` so the crank
angle is exactly quadratic, ``phi = phi_k + w0 tau + a tau^2 / 2``, and
continuous across segments. The inverse ``t(phi)`` is the positive root of
that quadratic, written ``tau = 2 dphi / (w0 + sqrt(w0^2 + 2 a dphi))`` because
the textbook ``(-w0 + sqrt(...)) / a`` cancels catastrophically at small
``a`` (a slow sweep) and divides by zero at a hold.

Angles are radians of crank angle ``phi`` (cylinder 1, zero at its firing TDC
unless ``phi0_rad`` says otherwise), times are seconds from the profile start.
Outside ``[0, duration_s]`` the profile holds its end speeds, so ``phi`` stays
strictly increasing and invertible everywhere.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.stream import SourceError

RPM_TO_RAD_S = 2.0 * math.pi / 60.0


@dataclass(frozen=True)
class Segment:
    """A linear rpm ramp ``rpm_from -> rpm_to`` over ``duration_s`` (a hold if equal)."""

    duration_s: float
    rpm_from: float
    rpm_to: float

    @property
    def is_hold(self) -> bool:
        return self.rpm_from == self.rpm_to


def hold(rpm: float, duration_s: float) -> Segment:
    """Constant ``rpm`` for ``duration_s`` seconds."""
    return Segment(float(duration_s), float(rpm), float(rpm))


def ramp(rpm_from: float, rpm_to: float, duration_s: float) -> Segment:
    """Linear ramp from ``rpm_from`` to ``rpm_to`` over ``duration_s`` seconds."""
    return Segment(float(duration_s), float(rpm_from), float(rpm_to))


class RpmProfile:
    """Piecewise-linear rpm with the exact crank angle and its exact inverse.

    Parameters
    ----------
    segments : sequence of Segment
        In time order; the rpm may jump between segments (a step), the crank
        angle never does.
    phi0_rad : float
        Crank angle at ``t = 0`` (rad).

    Raises
    ------
    SourceError
        A segment with a non-positive duration or rpm (the angle must increase
        strictly for the tacho edge times to exist).
    """

    def __init__(self, segments: Sequence[Segment], phi0_rad: float = 0.0) -> None:
        if not segments:
            raise SourceError("rpm profile: expected at least one segment, got none")
        for i, s in enumerate(segments):
            if not (s.duration_s > 0 and math.isfinite(s.duration_s)):
                raise SourceError(
                    f"rpm profile segment {i}: duration must be > 0 s, got {s.duration_s}"
                )
            if not (s.rpm_from > 0 and s.rpm_to > 0):
                raise SourceError(
                    f"rpm profile segment {i}: rpm must stay > 0, got {s.rpm_from} -> {s.rpm_to}"
                )
        self.segments: tuple[Segment, ...] = tuple(segments)
        dur = np.array([s.duration_s for s in segments])
        # w0 (rad/s) at each segment start, a (rad/s^2) its angular acceleration
        self._w0 = np.array([s.rpm_from for s in segments]) * RPM_TO_RAD_S
        self._w1 = np.array([s.rpm_to for s in segments]) * RPM_TO_RAD_S
        self._a = (self._w1 - self._w0) / dur
        self.t_start = np.concatenate([[0.0], np.cumsum(dur)[:-1]])
        # exact segment angles: trapezoid of a linear speed
        dphi = 0.5 * (self._w0 + self._w1) * dur
        self.phi_start = float(phi0_rad) + np.concatenate([[0.0], np.cumsum(dphi)[:-1]])
        self.duration_s = float(np.sum(dur))
        self.phi_end = float(phi0_rad + np.sum(dphi))

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def sweep(
        cls, rpm_start: float, rpm_end: float, duration_s: float, hold_s: float = 0.0
    ) -> RpmProfile:
        """The default sweep of a simulated bench.

        An optional hold at ``rpm_start`` for ``hold_s``, then the ramp
        ``rpm_start -> rpm_end`` over ``duration_s``.
        """
        segments = []
        if hold_s > 0:
            segments.append(hold(rpm_start, hold_s))
        segments.append(ramp(rpm_start, rpm_end, duration_s))
        return cls(segments)

    @classmethod
    def from_points(cls, times_s: Sequence[float], rpm: Sequence[float]) -> RpmProfile:
        """Through the points ``(t_k, rpm_k)``; a repeated time makes a step.

        ``times_s`` must start at 0 and not decrease.
        """
        t = np.asarray(times_s, dtype=float)
        r = np.asarray(rpm, dtype=float)
        if t.shape != r.shape or t.ndim != 1 or len(t) < 2:
            raise SourceError(
                f"rpm profile points: expected two equal-length lists of >= 2 values, "
                f"got {t.shape} times and {r.shape} rpm"
            )
        if t[0] != 0.0 or np.any(np.diff(t) < 0):
            raise SourceError("rpm profile points: times must start at 0 s and not decrease")
        segs = [ramp(r[k], r[k + 1], t[k + 1] - t[k]) for k in range(len(t) - 1) if t[k + 1] > t[k]]
        return cls(segs)

    # -- evaluation ---------------------------------------------------------------------------

    def segment_index(self, t: np.ndarray) -> np.ndarray:
        """Index of the segment holding each time (ends extended), int array like ``t``."""
        idx = np.searchsorted(self.t_start, np.asarray(t, dtype=float), side="right") - 1
        return np.clip(idx, 0, len(self.segments) - 1)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Segment index, crank angle (rad) and angular speed (rad/s) at times ``t`` (s).

        One pass for the synthesis, which needs all three at every sample.
        """
        t = np.asarray(t, dtype=float)
        k = self.segment_index(t)
        tau = t - self.t_start[k]
        w0 = self._w0[k]
        a = self._a[k]
        phi_ref = self.phi_start[k]
        outside = (t < 0.0) | (t > self.duration_s)
        if np.any(outside):
            # beyond the ends the speed holds: a = 0, and after the end the reference moves
            after = t > self.duration_s
            a = np.where(outside, 0.0, a)
            w0 = np.where(after, self._w1[-1], w0)
            tau = np.where(after, t - self.duration_s, tau)
            phi_ref = np.where(after, self.phi_end, phi_ref)
        return k, phi_ref + tau * (w0 + 0.5 * a * tau), w0 + a * tau

    @property
    def pieces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per segment: start time (s), start angle (rad), start speed (rad/s), acceleration
        (rad/s^2): what :meth:`evaluate` reads (``acquisition.sim.kernels.motion`` too)."""
        return self.t_start, self.phi_start, self._w0, self._a

    def omega(self, t: np.ndarray) -> np.ndarray:
        """Crank angular speed (rad/s) at times ``t`` (s)."""
        return self.evaluate(t)[2]

    def rpm(self, t: np.ndarray) -> np.ndarray:
        """Crank speed (rpm) at times ``t`` (s)."""
        return self.evaluate(t)[2] / RPM_TO_RAD_S

    def phi(self, t: np.ndarray) -> np.ndarray:
        """Crank angle (rad) at times ``t`` (s); continuous, strictly increasing."""
        return self.evaluate(t)[1]

    def t_of_phi(self, phi: np.ndarray) -> np.ndarray:
        """Exact inverse of :meth:`phi`: the time (s) at which the crank reaches ``phi`` (rad)."""
        phi = np.asarray(phi, dtype=float)
        n = len(self.segments)
        k = np.clip(np.searchsorted(self.phi_start, phi, side="right") - 1, 0, n - 1)
        after = phi > self.phi_end
        before = phi < self.phi_start[0]
        dphi = np.where(after, phi - self.phi_end, phi - self.phi_start[k])
        w0 = np.where(after, self._w1[-1], self._w0[k])
        a = np.where(after | before, 0.0, self._a[k])
        t0 = np.where(after, self.duration_s, self.t_start[k])
        # positive root of a/2 tau^2 + w0 tau - dphi = 0, cancellation-free form
        disc = np.maximum(w0 * w0 + 2.0 * a * dphi, 0.0)
        return t0 + 2.0 * dphi / (w0 + np.sqrt(disc))

    # -- summaries ----------------------------------------------------------------------------

    @property
    def rpm_min(self) -> float:
        return float(min(min(s.rpm_from, s.rpm_to) for s in self.segments))

    @property
    def rpm_max(self) -> float:
        return float(max(max(s.rpm_from, s.rpm_to) for s in self.segments))

    def describe(self) -> list[dict[str, Any]]:
        """The segments as plain dicts (for metadata)."""
        return [
            {"duration_s": s.duration_s, "rpm_from": s.rpm_from, "rpm_to": s.rpm_to}
            for s in self.segments
        ]

    def __repr__(self) -> str:
        segs = ", ".join(
            f"{s.rpm_from:g}->{s.rpm_to:g} rpm/{s.duration_s:g} s" for s in self.segments
        )
        return f"RpmProfile({segs})"


def parse_sweep(text: str) -> tuple[float, float]:
    """``"1500:4500"`` -> (1500, 4500); ``"3000"`` -> (3000, 3000), a constant speed.

    Raises
    ------
    SourceError
        Not one or two positive numbers separated by ``:``.
    """
    parts = text.split(":")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or not all(v > 0 and math.isfinite(v) for v in values):
        raise SourceError(f"sweep {text!r}: expected RPM or RPM_START:RPM_END with rpm > 0")
    return values[0], values[-1]
