"""The amplitude table of the simulated bench: ``X(rpm)`` tabulated once per sweep segment.

The bench model (:class:`AmplitudeModel`) is slow compared with the sample rate, so
``X(rpm)`` is tabulated once per segment of the rpm profile: piecewise polynomials in
rpm on adaptively bisected intervals, each accepted only when it matches the model to
``rtol`` (default 1e-10) at check points between its Chebyshev nodes. A block then
costs one real matmul per interval it crosses (:mod:`acquisition.sim.synthesis`); a
hold is exact.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Protocol

import numpy as np
import numpy.typing as npt

from acquisition.sim.compact_design import CompactDesign, compact_design
from acquisition.sim.sweep import RpmProfile
from acquisition.stream import SourceError


class AmplitudeModel(Protocol):
    """What the simulator needs from a bench model (``powertrain.model.BenchModel``)."""

    @property
    def channel_names(self) -> tuple[str, ...]: ...

    def channel_amplitudes(self, rpm: np.ndarray, orders: npt.ArrayLike) -> np.ndarray:
        """(n_rpm, n_orders, n_ch) complex, m/s^2, ``x(t) = Re{X exp(i h phi(t))}``."""
        ...

    def pressure(self, phi_rad: np.ndarray) -> np.ndarray | None:
        """Cylinder-1 pressure (Pa) at crank angles from its firing TDC, or None."""
        ...


class AmplitudeTable:
    """Piecewise-polynomial ``X(rpm)`` per profile segment, within ``rtol`` of the model.

    Parameters
    ----------
    model : AmplitudeModel
    orders : (n_o,) float
    profile : RpmProfile
    degree : int
        Polynomial degree per interval (in the interval's normalised rpm ``u``).
    rtol : float
        Accepted error per interval: ``max |P - X| / max_h |X_h|`` per channel
        at check points between the Chebyshev nodes and at the ends.

    Attributes
    ----------
    edges : list of (n_int + 1,) float, rpm
        Interval edges per segment (a hold has one interval of zero width).
    coeffs : list of (n_int, degree + 1, n_o, n_ch) complex
        Monomial coefficients in ``u = (rpm - centre) / half_width``, highest last.
    max_error : float
        Largest accepted check-point error (relative, as ``rtol``).
    max_intervals : int
        Per segment; beyond it the model is not smooth enough for ``rtol`` (SourceError).
    n_model_rpm : int
        Number of rpm values the model was evaluated at.
    """

    def __init__(
        self,
        model: AmplitudeModel,
        orders: np.ndarray,
        profile: RpmProfile,
        degree: int = 4,
        rtol: float = 1e-10,
        initial_width_rpm: float = 100.0,
        max_intervals: int = 100_000,
    ) -> None:
        self.orders = np.asarray(orders, dtype=float)
        self.degree = degree
        self.max_intervals = max_intervals
        self.n_model_rpm = 0
        self.max_error = 0.0
        self._model = model
        n = degree + 1
        self._nodes = np.cos(np.pi * (np.arange(n) + 0.5) / n)
        self._checks = np.cos(np.pi * np.arange(n + 1) / n)  # ends and mid-node points
        self._vinv = np.linalg.inv(np.vander(self._nodes, n, increasing=True))
        self.edges: list[np.ndarray] = []
        self.coeffs: list[np.ndarray] = []
        cache: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}
        for seg in profile.segments:
            lo, hi = sorted((seg.rpm_from, seg.rpm_to))
            if (lo, hi) not in cache:
                cache[(lo, hi)] = self._build(lo, hi, initial_width_rpm, rtol)
            e, c = cache[(lo, hi)]
            self.edges.append(e)
            self.coeffs.append(c)
        # real form for the synthesis: Re{X e} = Re X cos - Im X sin
        self.real_coeffs = [_real_design(c) for c in self.coeffs]
        self._centre = [0.5 * (e[:-1] + e[1:]) for e in self.edges]
        # 1 / half width; 0 at a hold so that u = 0 there
        self._inv_half = [
            np.divide(2.0, np.diff(e), out=np.zeros(len(e) - 1), where=np.diff(e) > 0)
            for e in self.edges
        ]

    def _model_eval(self, rpm: np.ndarray) -> np.ndarray:
        self.n_model_rpm += rpm.size
        x = np.asarray(self._model.channel_amplitudes(rpm, self.orders))
        if x.ndim != 3 or x.shape[:2] != (rpm.size, self.orders.size):
            raise SourceError(
                "model channel_amplitudes: expected shape "
                f"({rpm.size}, {self.orders.size}, n_ch), got {x.shape}"
            )
        return x

    def _build(
        self, lo: float, hi: float, width: float, rtol: float
    ) -> tuple[np.ndarray, np.ndarray]:
        n = self.degree + 1
        if hi == lo:
            x = self._model_eval(np.array([lo]))
            # a hold is exact: one constant term
            return np.array([lo, hi]), x[None, :1].copy()
        k = max(1, math.ceil((hi - lo) / width))
        pending = np.stack(
            [lo + (hi - lo) * np.arange(k) / k, lo + (hi - lo) * np.arange(1, k + 1) / k], 1
        )
        pending[-1, 1] = hi
        min_width = 1e-9 * hi
        done_iv: list[np.ndarray] = []
        done_c: list[np.ndarray] = []
        floor = 0.0
        while len(pending):
            mid = 0.5 * (pending[:, 0] + pending[:, 1])
            half = 0.5 * (pending[:, 1] - pending[:, 0])
            u = np.concatenate([self._nodes, self._checks])
            rpm = (mid[:, None] + half[:, None] * u[None, :]).ravel()
            x = self._model_eval(rpm).reshape(len(pending), u.size, self.orders.size, -1)
            coef = np.einsum("kj,ijoc->ikoc", self._vinv, x[:, :n])
            xc = x[:, n:]
            fit = np.einsum("pk,ikoc->ipoc", np.vander(self._checks, n, increasing=True), coef)
            scale = np.abs(xc).max(axis=2)  # (n_int, n_check, n_ch)
            floor = max(floor, 1e-12 * float(scale.max(initial=0.0)))
            err = (np.abs(fit - xc).max(axis=2) / np.maximum(scale, floor or 1.0)).max(axis=(1, 2))
            ok = (err <= rtol) | (half * 2 <= min_width)
            if np.any(ok):
                self.max_error = max(self.max_error, float(err[ok].max()))
                done_iv.append(pending[ok])
                done_c.append(coef[ok])
            bad = pending[~ok]
            n_done = sum(len(d) for d in done_iv)
            if n_done + 2 * len(bad) > self.max_intervals:
                raise SourceError(
                    f"amplitude table: more than {self.max_intervals} intervals needed for a "
                    f"relative error of {rtol:g} over {lo:g}..{hi:g} rpm (worst {err.max():.2g}); "
                    "the model is not smooth in rpm at that level: raise table_rtol"
                )
            m = 0.5 * (bad[:, 0] + bad[:, 1])
            pending = np.concatenate([np.stack([bad[:, 0], m], 1), np.stack([m, bad[:, 1]], 1)])
        iv = np.concatenate(done_iv)
        c = np.concatenate(done_c)
        order = np.argsort(iv[:, 0])
        iv, c = iv[order], c[order]
        return np.concatenate([iv[:, 0], iv[-1:, 1]]), c

    def locate(self, segment: int, rpm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interval index and normalised rpm ``u`` in ``[-1, 1]`` of each rpm of a segment."""
        e = self.edges[segment]
        if len(e) == 2:  # one interval (a hold, or a smooth short ramp)
            j = np.zeros(np.shape(rpm), dtype=np.intp)
        else:
            j = np.searchsorted(e, rpm, side="right") - 1
            np.clip(j, 0, len(e) - 2, out=j)
        return j, (rpm - self._centre[segment][j]) * self._inv_half[segment][j]

    @cached_property
    def compact(self) -> CompactDesign:
        """The compiled synthesis' operands (:mod:`acquisition.sim.compact_design`)."""
        return compact_design(self.coeffs, self.real_coeffs)

    def intervals(self, segment: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Edges (rpm), centres (rpm) and inverse half widths (1/rpm, 0 at a hold) of a
        segment's intervals: what :meth:`locate` reads (``acquisition.sim.kernels.locate`` too)."""
        return self.edges[segment], self._centre[segment], self._inv_half[segment]

    def evaluate(self, segment: int, rpm: np.ndarray) -> np.ndarray:
        """Tabulated ``X`` at rpm values of one segment: (n, n_o, n_ch) complex, m/s^2."""
        rpm = np.atleast_1d(np.asarray(rpm, dtype=float))
        j, u = self.locate(segment, rpm)
        c = self.coeffs[segment][j]  # (n, degree+1, n_o, n_ch)
        out = c[:, -1]
        for k in range(c.shape[1] - 2, -1, -1):
            out = out * u[:, None, None] + c[:, k]
        return out


def _real_design(c: np.ndarray) -> np.ndarray:
    """(n_int, deg+1, n_o, n_ch) complex -> (n_int, (deg+1) n_ch, 2 n_o) real matmul operands.

    Row ``k n_ch + c`` holds ``Re C_k, -Im C_k`` of channel ``c`` interleaved per
    order, matching the columns ``cos h phi, sin h phi`` of :func:`order_basis`.
    """
    n_int, n_k, n_o, n_ch = c.shape
    d = np.stack([c.real, -c.imag], axis=3)  # (n_int, n_k, n_o, 2, n_ch)
    return np.ascontiguousarray(d.transpose(0, 1, 4, 2, 3).reshape(n_int, n_k * n_ch, 2 * n_o))
