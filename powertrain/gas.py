"""Cylinder gas: pressure over the 720 deg cycle, or the gas torque per order.

Angles are in rad from cylinder 1's firing TDC, periodic over ``4 pi``. Three
models, matching the bench file's ``[gas]`` table:

* :class:`ParametricGas` -- a closed cycle from IVC to EVO with polytropic
  compression and expansion and a Wiebe heat release entered through the
  first law, ``dp = ((g - 1) / V) dQ - g p dV / V``; gas exchange at the
  exhaust and intake pressures in between.
* :class:`TraceGas` -- a measured or computed cylinder-1 pressure trace.
* :class:`OrdersGas` -- the gas torque on the crank given per order; no pressure.

The first two give a :class:`PressureCycle`, which the engine turns into a
torque with the slider-crank lever arm.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.integrate import cumulative_simpson
from scipy.interpolate import CubicSpline

from powertrain.errors import PhysicsError
from powertrain.slider_crank import piston_motion

CYCLE = 4.0 * np.pi  # one four-stroke cycle, rad


@dataclass(frozen=True)
class CylinderGeometry:
    """What the gas needs of a cylinder, SI.

    Parameters
    ----------
    bore, stroke, conrod_length : m.
    """

    bore: float
    stroke: float
    conrod_length: float

    @property
    def area(self) -> float:
        """m^2, piston crown area."""
        return 0.25 * np.pi * self.bore**2

    @property
    def displacement(self) -> float:
        """m^3, swept volume of one cylinder."""
        return self.area * self.stroke

    def volume(
        self, theta: npt.ArrayLike, compression_ratio: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Cylinder volume and its derivative at crank angles ``theta`` (rad from TDC).

        Returns
        -------
        V : m^3, ``V_c + A (r + l - x)`` with ``V_c = V_d / (cr - 1)``.
        dV/dtheta : m^3/rad.
        """
        r = 0.5 * self.stroke
        x, x_t = piston_motion(theta, r, self.conrod_length)
        clearance = self.displacement / (compression_ratio - 1.0)
        return clearance + self.area * (r + self.conrod_length - x), -self.area * x_t


class PressureCycle:
    """A periodic cylinder pressure over one cycle, sampled uniformly and splined.

    Parameters
    ----------
    pressure : (n,) Pa at ``phi_j = 4 pi j / n``, j = 0..n-1.
    """

    def __init__(self, pressure: np.ndarray) -> None:
        p = np.asarray(pressure, dtype=float)
        if p.ndim != 1 or p.size < 8:
            raise PhysicsError(f"pressure cycle needs at least 8 samples, got shape {p.shape}")
        if not np.all(np.isfinite(p)) or p.min() <= 0:
            raise PhysicsError(f"pressure must be finite and positive (min {p.min():.4g} Pa)")
        grid = np.linspace(0.0, CYCLE, p.size + 1)
        self._spline = CubicSpline(grid, np.append(p, p[0]), bc_type="periodic")
        self._grid = grid
        self._per_rad = p.size / CYCLE
        self._c = [np.ascontiguousarray(c) for c in self._spline.c]  # highest power first
        # read-only: one cycle may serve many engines (ParametricGas.cycle)
        self.samples = p.copy()
        for a in (self.samples, grid, *self._c):
            a.flags.writeable = False

    @property
    def pieces(self) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Grid (rad, n + 1 points from 0 to 4 pi), intervals per rad, and the coefficients
        ``c0 .. c3`` (n,) of ``s^3 .. s^0``, ``s`` rad from the interval's start."""
        c0, c1, c2, c3 = self._c
        return self._grid, self._per_rad, c0, c1, c2, c3

    def __call__(self, phi: npt.ArrayLike) -> np.ndarray:
        """Pa at crank angles ``phi`` (rad, any range: the cycle repeats every 4 pi).

        The spline's own evaluation, bit for bit (scipy's ``PPoly``: the interval
        ``grid[i] <= x < grid[i + 1]``, the last one closed, and the power sum
        ``c3 + c2 s + c1 s^2 + c0 s^3`` in that order), with the interval found from
        the uniform grid instead of by bisection: a simulated minute of pressure at
        25.6 kHz costs 0.03 s of CPU with scipy's, 0.01 s so.
        """
        x = np.mod(np.asarray(phi, dtype=float), CYCLE)
        last = self._grid.size - 2
        i = np.minimum((x * self._per_rad).astype(np.intp), last)
        # the product can round across a grid point: step back or on to the interval holding x
        i -= x < self._grid[i]
        i += (x >= self._grid[i + 1]) & (i < last)
        s = x - self._grid[i]
        c0, c1, c2, c3 = (c[i] for c in self._c)
        z = s.copy()
        out = c3 + c2 * z
        z *= s
        out += c1 * z
        z *= s
        out += c0 * z
        return out


def smoothstep(z: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, ``3 z^2 - 2 z^3`` between: a C1 blend between two levels."""
    z = np.clip(z, 0.0, 1.0)
    return z * z * (3.0 - 2.0 * z)


def wiebe(
    theta: npt.ArrayLike, start: float, duration: float, a: float, m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Wiebe mass fraction burned and its derivative.

    ``x_b = 1 - exp(-a y^(m+1))``, ``y = (theta - start) / duration`` for
    ``y >= 0``. It is not cut at ``y = 1`` (where ``1 - exp(-a)`` has burned):
    the tail keeps the pressure smooth, so its spectrum decays fast.

    Returns
    -------
    x_b : (n,) fraction burned.
    dx_b/dtheta : (n,) 1/rad.
    """
    y = np.maximum((np.asarray(theta, dtype=float) - start) / duration, 0.0)
    e = np.exp(-a * y ** (m + 1))
    rate = np.where(y > 0, a * (m + 1) * y**m * e / duration, 0.0)
    return 1.0 - e, rate


@dataclass(frozen=True)
class ParametricGas:
    """A spark-ignition cycle from a few numbers, SI and rad.

    Valve events (not in the bench file, typical of a small SI engine):
    IVC 40 deg after BDC (580 deg = -140 deg), EVO 50 deg before BDC
    (130 deg). Blowdown blends the expansion pressure into the exhaust
    pressure from EVO to 30 deg after BDC; the valve overlap blends exhaust into
    intake pressure from 10 deg before to 20 deg after the gas-exchange TDC
    (360 deg). Both blends are C1, so the spectrum decays like ``1/h^3``.

    Parameters
    ----------
    compression_ratio : geometric.
    intake_pressure, exhaust_pressure : Pa.
    polytropic_exponent : ``g``, for compression and expansion alike.
    heat_release : J per cylinder and cycle.
    combustion_start, combustion_duration : rad (start from firing TDC).
    wiebe_a, wiebe_m : Wiebe shape.
    """

    compression_ratio: float = 10.5
    intake_pressure: float = 0.5e5
    exhaust_pressure: float = 1.05e5
    polytropic_exponent: float = 1.32
    heat_release: float = 150.0
    combustion_start: float = np.deg2rad(-8.0)
    combustion_duration: float = np.deg2rad(50.0)
    wiebe_a: float = 5.0
    wiebe_m: float = 2.0
    ivc: float = np.deg2rad(-140.0)
    evo: float = np.deg2rad(130.0)
    blowdown_end: float = np.deg2rad(210.0)
    overlap: tuple[float, float] = (np.deg2rad(350.0), np.deg2rad(380.0))

    def __post_init__(self) -> None:
        if not (self.ivc < self.combustion_start < self.evo):
            raise PhysicsError(
                f"combustion start {np.rad2deg(self.combustion_start):.1f} deg must lie between "
                f"IVC {np.rad2deg(self.ivc):.0f} and EVO {np.rad2deg(self.evo):.0f} deg"
            )
        if self.compression_ratio <= 1 or not 1 < self.polytropic_exponent < 2:
            raise PhysicsError(
                f"compression ratio {self.compression_ratio} must be > 1 and polytropic "
                f"exponent {self.polytropic_exponent} in (1, 2)"
            )

    def pressure(self, geometry: CylinderGeometry, phi: npt.ArrayLike) -> np.ndarray:
        """Pa at crank angles ``phi`` (rad, periodic over 4 pi)."""
        g = self.polytropic_exponent
        cr = self.compression_ratio
        # Unwrap onto [IVC, IVC + 4 pi) so the closed phase is one interval.
        u = self.ivc + np.mod(np.asarray(phi, dtype=float) - self.ivc, CYCLE)
        v_ivc, _ = geometry.volume(np.array([self.ivc]), cr)
        # p V^g = p_ivc V_ivc^g + (g - 1) integral(V^(g-1) dQ): the first law,
        # integrated once on a fine grid (Simpson), then read by a spline.
        fine = np.linspace(self.ivc, self.blowdown_end, 40_001)
        v_fine, _ = geometry.volume(fine, cr)
        _, rate = wiebe(
            fine, self.combustion_start, self.combustion_duration, self.wiebe_a, self.wiebe_m
        )
        integrand = v_fine ** (g - 1.0) * self.heat_release * rate
        heat_term = CubicSpline(fine, cumulative_simpson(integrand, x=fine, initial=0.0))
        v, _ = geometry.volume(u, cr)
        closed_u = np.minimum(u, self.blowdown_end)
        p_closed = (self.intake_pressure * v_ivc[0] ** g + (g - 1.0) * heat_term(closed_u)) / v**g
        w_blow = smoothstep((u - self.evo) / (self.blowdown_end - self.evo))
        p = (1.0 - w_blow) * p_closed + w_blow * self.exhaust_pressure
        w_over = smoothstep((u - self.overlap[0]) / (self.overlap[1] - self.overlap[0]))
        exchange = (1.0 - w_over) * self.exhaust_pressure + w_over * self.intake_pressure
        return np.where(u >= self.blowdown_end, exchange, p)

    def cycle(self, geometry: CylinderGeometry, samples: int) -> PressureCycle:
        """The pressure sampled on ``phi_j = 4 pi j / samples`` (shared: see
        :func:`_parametric_cycle`)."""
        return _parametric_cycle(self, geometry, samples)


# A run's model-input derivatives take engines that differ in a mass or the crankcase
# pressure only (the same gas and geometry), and a campaign or a study runs the same engine
# again and again: each pressure cycle (its first law on a 40001-point grid, ~3-7 ms) is
# computed once per process. The gas and the geometry are frozen dataclasses of numbers;
# the cycle's arrays are read-only.
@functools.lru_cache(maxsize=16)
def _parametric_cycle(
    gas: ParametricGas, geometry: CylinderGeometry, samples: int
) -> PressureCycle:
    return PressureCycle(gas.pressure(geometry, np.arange(samples) * CYCLE / samples))


@dataclass(frozen=True)
class TraceGas:
    """A cylinder-1 pressure trace over the cycle.

    Parameters
    ----------
    crank_angle : (n,) rad from firing TDC, strictly increasing, within [0, 4 pi].
        A last point at 4 pi repeating the first is allowed and dropped.
    pressure : (n,) Pa, absolute.
    """

    crank_angle: np.ndarray = field(repr=False)
    pressure: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        a = np.asarray(self.crank_angle, dtype=float)
        p = np.asarray(self.pressure, dtype=float)
        if a.shape != p.shape or a.ndim != 1 or a.size < 8:
            raise PhysicsError(
                f"pressure trace needs matching 1-D angle and pressure arrays of >= 8 points, "
                f"got {a.shape} and {p.shape}"
            )
        if np.any(np.diff(a) <= 0) or a[0] < 0 or a[-1] > CYCLE + 1e-9:
            raise PhysicsError("pressure trace angles must increase strictly within 0..720 deg")
        if not np.all(np.isfinite(p)) or p.min() <= 0:
            raise PhysicsError(f"pressure trace must be positive (min {p.min():.4g} Pa)")

    def pressure_at(self, phi: npt.ArrayLike) -> np.ndarray:
        """Pa at ``phi`` (rad, periodic), by a periodic cubic spline through the trace."""
        a = np.asarray(self.crank_angle, dtype=float)
        p = np.asarray(self.pressure, dtype=float)
        if a[-1] >= CYCLE - 1e-9:  # the closing point repeats the first
            a, p = a[:-1], p[:-1]
        spline = CubicSpline(np.append(a, a[0] + CYCLE), np.append(p, p[0]), bc_type="periodic")
        return spline(a[0] + np.mod(np.asarray(phi, dtype=float) - a[0], CYCLE))

    def cycle(self, geometry: CylinderGeometry, samples: int) -> PressureCycle:
        """The trace resampled on ``phi_j = 4 pi j / samples`` (geometry unused)."""
        return PressureCycle(self.pressure_at(np.arange(samples) * CYCLE / samples))


@dataclass(frozen=True)
class OrdersGas:
    """Gas torque on the crank per order: ``T(phi) = Re{sum T_h exp(i h phi)}``.

    Parameters
    ----------
    orders : (n,) engine orders, > 0.
    torque : (n,) complex N m, about the crank axis (right hand).
    """

    orders: tuple[float, ...]
    torque: tuple[complex, ...]

    def __post_init__(self) -> None:
        if len(self.orders) != len(self.torque):
            raise PhysicsError(f"{len(self.orders)} orders but {len(self.torque)} torques")
        if any(h <= 0 for h in self.orders):
            raise PhysicsError(f"gas torque orders must be > 0, got {list(self.orders)}")

    def torque_orders(self, orders: npt.ArrayLike, tol: float = 1e-9) -> np.ndarray:
        """(n_orders,) complex N m: the table's value at each order, 0 where absent."""
        table = np.asarray(self.orders, dtype=float)
        values = np.asarray(self.torque, dtype=complex)
        wanted = np.atleast_1d(np.asarray(orders, dtype=float))
        out = np.zeros(wanted.size, dtype=complex)
        for i, h in enumerate(wanted):
            hit = np.abs(table - h) <= tol
            out[i] = values[hit].sum()
        return out

    def torque_at(self, phi: npt.ArrayLike) -> np.ndarray:
        """N m at ``phi`` (rad)."""
        phi = np.asarray(phi, dtype=float)
        h = np.asarray(self.orders, dtype=float)
        return np.real(
            np.exp(1j * np.multiply.outer(phi, h)) @ np.asarray(self.torque, dtype=complex)
        )


GasModel = ParametricGas | TraceGas | OrdersGas
