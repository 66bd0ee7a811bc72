"""The loads a running engine puts on its block, per engine order.

Frame and angles
----------------
``s`` is the crank axis (the crank turns right-handed about it), ``c`` the
cylinder axis turned by ``tilt`` about ``s`` (right hand), ``t = s x c``.
``phi`` is cylinder 1's crank angle, zero at its firing TDC. Cylinder k sits on
the crank at ``C_k = ref + a_k s``, reaches TDC at ``phi = alpha_k`` (its throw
angle) and its crank pin points along ``cos(theta) c + sin(theta) t`` with
``theta = phi - alpha_k``. Cylinder ``firing_order[j]`` fires at
``phi = 720 j / n`` deg, counted from cylinder 1.

Loads on the block (``physics-notes.md``)
-----------------------------------------
With the block held still and the crank turning at constant ``omega``:

* force ``F = -dp/dt`` of every moving part (pistons, rods, unbalances,
  balance-shaft masses). Gas pushes the head and the piston equally: it is
  internal to block + piston and never appears as a force.
* moment about Q ``M_Q = -dL_Q/dt - T_crank s``: the angular momentum of the
  translating masses and of the rods' own rotation, minus the torque ``T_crank``
  the pistons deliver to the crank (gas plus reciprocating and rod inertia,
  ``T_crank omega = P_gas - dKE/dt``). The load on the output shaft takes
  ``T_crank`` out of the powertrain; the block reacts it.

Order decomposition (:mod:`powertrain.half_orders`): one 720 deg cycle,
``samples_per_cycle`` points, FFT into ``x(phi) = Re{sum_h X_h exp(i h phi)}`` for
every half order ``h``. Inertia loads scale with ``omega^2``, so they are decomposed
once at unit speed and cached; the gas part does not depend on speed. The balancing
masses and their loads are in :mod:`powertrain.balancing`.

Crankcase pressure: the piston sees ``p - p_crankcase``; a constant
crankcase pressure does no work over a cycle but has orders of its own
(order 2 on an inline 4), so it is kept (``crankcase_pressure``, default 1 atm).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import numpy.typing as npt

from powertrain.balancing import BalanceShaft, Unbalance, add_balancing_loads
from powertrain.errors import PhysicsError
from powertrain.gas import CYCLE, CylinderGeometry, GasModel, OrdersGas, PressureCycle
from powertrain.half_orders import (
    OrderExcitation,
    half_order_index,
    half_order_spectrum,
    rpm_to_omega,
)
from powertrain.inertia_spectra import shared_spectra
from powertrain.rigidbody import rotation_matrix
from powertrain.slider_crank import SliderCrank


@dataclass(frozen=True, eq=False)
class Engine:
    """A multi-cylinder reciprocating engine, SI and rad.

    Parameters
    ----------
    cylinders : n.
    bore, stroke, conrod_length, conrod_cog_from_big_end : m.
    conrod_mass, piston_mass : kg per cylinder.
    reference_point : (3,) m, bench frame; cylinder positions are along ``s`` from it.
    cylinder_positions : (n,) m.
    throw_angles : (n,) rad, ``alpha_k``; cylinder 1's must be 0.
    firing_order : (n,) cylinder numbers 1..n.
    gas : a gas model, or None for a motored-free engine (no gas torque).
    conrod_inertia : kg m^2 about the rod cog, None for the two-mass rod.
    crank_axis, cylinder_axis : (3,) unit vectors, perpendicular.
    tilt : rad, bank lean about ``s``.
    crank_spin_inertia : kg m^2 about ``s`` of everything that spins with the crank.
    unbalances, balance_shafts : see :class:`Unbalance`, :class:`BalanceShaft`.
    crankcase_pressure : Pa under the pistons.
    samples_per_cycle : FFT length over 720 deg (even; orders up to a quarter of it).
    """

    cylinders: int
    bore: float
    stroke: float
    conrod_length: float
    conrod_mass: float
    conrod_cog_from_big_end: float
    piston_mass: float
    reference_point: np.ndarray = field(repr=False)
    cylinder_positions: np.ndarray = field(repr=False)
    throw_angles: np.ndarray = field(repr=False)
    firing_order: tuple[int, ...]
    gas: GasModel | None = None
    conrod_inertia: float | None = None
    crank_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]), repr=False)
    cylinder_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]), repr=False)
    tilt: float = 0.0
    crank_spin_inertia: float = 0.0
    unbalances: tuple[Unbalance, ...] = ()
    balance_shafts: tuple[BalanceShaft, ...] = ()
    crankcase_pressure: float = 101325.0
    samples_per_cycle: int = 8192

    def __post_init__(self) -> None:
        n = int(self.cylinders)
        for name in ("reference_point", "crank_axis", "cylinder_axis"):
            v = np.array(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise PhysicsError(f"{name} must be a finite (3,) vector, got {v.tolist()}")
            object.__setattr__(self, name, v)
        for name in ("cylinder_positions", "throw_angles"):
            v = np.array(getattr(self, name), dtype=float)
            if v.shape != (n,):
                raise PhysicsError(f"{name}: expected {n} values (one per cylinder), got {v.size}")
            object.__setattr__(self, name, v)
        order = tuple(int(k) for k in self.firing_order)
        if sorted(order) != list(range(1, n + 1)):
            raise PhysicsError(f"firing order must be a permutation of 1..{n}, got {list(order)}")
        object.__setattr__(self, "firing_order", order)
        s, c0 = self.crank_axis, self.cylinder_axis
        if abs(np.linalg.norm(s) - 1) > 1e-9 or abs(np.linalg.norm(c0) - 1) > 1e-9:
            raise PhysicsError("crank_axis and cylinder_axis must be unit vectors")
        if abs(float(s @ c0)) > 1e-9:
            raise PhysicsError(
                f"cylinder axis must be perpendicular to the crank axis (cos = {s @ c0:.3g})"
            )
        if self.samples_per_cycle < 64 or self.samples_per_cycle % 4:
            raise PhysicsError(
                f"samples_per_cycle must be a multiple of 4 >= 64, got {self.samples_per_cycle}"
            )
        if abs(_wrap(self.throw_angles[0], 2 * np.pi)) > 1e-9:
            raise PhysicsError(
                f"cylinder 1's throw angle must be 0 (phi is zero at its TDC), got "
                f"{np.rad2deg(self.throw_angles[0]):g} deg"
            )
        for k in range(n):
            gap = _wrap(self.firing_angles[k] - self.throw_angles[k], 2 * np.pi)
            if abs(gap) > 1e-9:
                raise PhysicsError(
                    f"cylinder {k + 1} fires at {np.rad2deg(self.firing_angles[k]):g} deg but its throw "
                    f"is at {np.rad2deg(self.throw_angles[k]):g} deg (they must agree modulo 360)"
                )
        for b in self.balance_shafts:
            if b.order not in (1, 2) or b.direction not in (1, -1):
                raise PhysicsError(
                    f"balance shaft order must be 1 or 2 and direction +1 or -1, got {b.order}, {b.direction}"
                )
        if self.bore <= 0:
            raise PhysicsError(f"bore must be positive, got {self.bore} m")
        self.slider_crank  # noqa: B018 - validates lambda and the masses now, not at first use

    # -- geometry -----------------------------------------------------------------------------

    @cached_property
    def slider_crank(self) -> SliderCrank:
        """The moving parts of one cylinder."""
        return SliderCrank(
            0.5 * self.stroke,
            self.conrod_length,
            self.conrod_cog_from_big_end,
            self.piston_mass,
            self.conrod_mass,
            self.conrod_inertia,
        )

    @cached_property
    def geometry(self) -> CylinderGeometry:
        return CylinderGeometry(self.bore, self.stroke, self.conrod_length)

    @cached_property
    def frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, c, t)``: crank axis, tilted cylinder axis, ``s x c``; unit (3,) vectors."""
        s = self.crank_axis
        c = rotation_matrix(s, self.tilt) @ self.cylinder_axis
        return s, c, np.cross(s, c)

    @cached_property
    def crank_centres(self) -> np.ndarray:
        """(n, 3) m: where each cylinder's axis meets the crank axis."""
        return self.reference_point + np.outer(self.cylinder_positions, self.crank_axis)

    @cached_property
    def firing_angles(self) -> np.ndarray:
        """(n,) rad in [0, 4 pi): crank angle phi at which each cylinder fires."""
        n = self.cylinders
        first = self.firing_order.index(1)
        out = np.empty(n)
        for j, cyl in enumerate(self.firing_order):
            out[cyl - 1] = CYCLE * ((j - first) % n) / n
        return out

    @cached_property
    def pressure_cycle(self) -> PressureCycle | None:
        """Cylinder-1 pressure over the cycle, or None for a torque-table or gas-free model."""
        if self.gas is None or isinstance(self.gas, OrdersGas):
            return None
        return self.gas.cycle(self.geometry, self.samples_per_cycle)

    def cylinder_pressure(self, phi: npt.ArrayLike) -> np.ndarray | None:
        """Pa, cylinder 1 at crank angles ``phi`` (rad), or None when the model has no pressure."""
        cycle = self.pressure_cycle
        return None if cycle is None else cycle(phi)

    # -- time domain -----------------------------------------------------------------------------

    def gas_torque(self, phi: npt.ArrayLike) -> np.ndarray:
        """N m about ``s``: gas torque delivered to the crank at crank angles ``phi`` (rad)."""
        phi = np.asarray(phi, dtype=float)
        if self.gas is None:
            return np.zeros_like(phi)
        if isinstance(self.gas, OrdersGas):
            return self.gas.torque_at(phi)
        cycle = self.pressure_cycle
        assert cycle is not None
        area = self.geometry.area
        total = np.zeros_like(phi)
        for k in range(self.cylinders):
            x_t = self.slider_crank.piston_motion(phi - self.throw_angles[k])[1]
            p = cycle(phi - self.firing_angles[k])
            # Virtual work: the piston force -(p - p_cc) A c moves by x_t dtheta along c.
            total -= (p - self.crankcase_pressure) * area * x_t
        return total

    def inertia_torque(
        self, phi: npt.ArrayLike, rpm: float = 0.0, omega: float | None = None
    ) -> np.ndarray:
        """N m about ``s`` delivered to the crank by piston and rod inertia."""
        w = float(rpm_to_omega(rpm)) if omega is None else omega
        phi = np.asarray(phi, dtype=float)
        return sum(
            (self.slider_crank.inertia_torque(phi - a, w) for a in self.throw_angles),
            start=np.zeros_like(phi),
        )

    def crank_torque(self, phi: npt.ArrayLike, rpm: float) -> np.ndarray:
        """N m about ``s``: ``T_crank`` = gas + inertia torque delivered to the crank."""
        return self.gas_torque(phi) + self.inertia_torque(phi, rpm)

    def inertia_loads(
        self, phi: npt.ArrayLike, about: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray]:
        """Inertia force and moment on the block at unit crank speed (1 rad/s).

        Parameters
        ----------
        phi : (n,) rad.
        about : (3,) m, the point Q moments are taken about.

        Returns
        -------
        force : (n, 3) N per (rad/s)^2.
        moment : (n, 3) N m per (rad/s)^2 about Q, including ``-T_inertia s``.
        """
        return self._inertia_parts(phi, about)[:2]

    def _inertia_parts(
        self, phi: npt.ArrayLike, about: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`inertia_loads` and :meth:`inertia_torque` at 1 rad/s from one evaluation
        of each cylinder's kinematics (the same sums, in the same order)."""
        phi = np.asarray(phi, dtype=float)
        q = np.asarray(about, dtype=float)
        s, c, t = self.frame
        sc = self.slider_crank
        m_p, m_r, j_r = sc.piston_mass, sc.conrod_mass, sc.rod_inertia
        force = np.zeros((phi.size, 3))
        moment = np.zeros((phi.size, 3))
        roll = np.zeros(phi.size)  # moment about s, N m
        torque = np.zeros_like(phi)
        for k in range(self.cylinders):
            kin = sc.kinematics(phi - self.throw_angles[k])
            arm = self.crank_centres[k] - q
            # Inertia forces -m a of the piston (along c) and of the rod cog.
            f_piston = np.outer(-m_p * kin.x_tt, c)
            f_rod = np.outer(-m_r * kin.gc_tt, c) + np.outer(-m_r * kin.gt_tt, t)
            rod_cog = arm + np.outer(kin.gc, c) + np.outer(kin.gt, t)
            force += f_piston + f_rod
            moment += np.cross(arm, f_piston) + np.cross(rod_cog, f_rod)
            # -d(J psi_dot)/dt of the rod's own rotation, then minus the inertia torque on the crank.
            torque_k = sc.inertia_torque_of(kin)
            roll += -j_r * kin.psi_tt - torque_k
            torque += torque_k
        add_balancing_loads(
            force, moment, self.unbalances, self.balance_shafts, phi, self.frame,
            self.reference_point, q,
        )  # fmt: skip
        moment += np.outer(roll, s)
        return force, moment, torque

    def block_loads(
        self, phi: npt.ArrayLike, rpm: float, about: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray]:
        """Total force (n, 3) N and moment (n, 3) N m about ``about`` on the block at ``phi``."""
        w2 = float(rpm_to_omega(rpm)) ** 2
        f, m = self.inertia_loads(phi, about)
        return w2 * f, w2 * m - np.outer(self.gas_torque(phi), self.crank_axis)

    # -- orders -------------------------------------------------------------------------------------

    @cached_property
    def _grid(self) -> np.ndarray:
        return np.arange(self.samples_per_cycle) * CYCLE / self.samples_per_cycle

    @cached_property
    def _unit_inertia_spectra(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """FFT at unit speed of force, moment about the reference point, inertia torque
        (read-only, shared by engines of the same inertia: :mod:`powertrain.inertia_spectra`)."""
        return shared_spectra(self)

    @cached_property
    def _gas_spectrum(self) -> np.ndarray | None:
        if self.gas is None or isinstance(self.gas, OrdersGas):
            return None
        return half_order_spectrum(self.gas_torque(self._grid))

    def _index(self, orders: npt.ArrayLike) -> np.ndarray:
        return half_order_index(orders, self.samples_per_cycle)

    def gas_torque_orders(self, orders: npt.ArrayLike) -> np.ndarray:
        """(n_orders,) complex N m: gas torque delivered to the crank, per order."""
        h = np.atleast_1d(np.asarray(orders, dtype=float))
        if self.gas is None:
            return np.zeros(h.size, dtype=complex)
        if isinstance(self.gas, OrdersGas):
            return self.gas.torque_orders(h)
        assert self._gas_spectrum is not None
        return self._gas_spectrum[self._index(h)]

    def inertia_torque_orders(self, rpm: float, orders: npt.ArrayLike) -> np.ndarray:
        """(n_orders,) complex N m: piston and rod inertia torque delivered to the crank."""
        return float(rpm_to_omega(rpm)) ** 2 * self._unit_inertia_spectra[2][self._index(orders)]

    def crank_torque_orders(self, rpm: float, orders: npt.ArrayLike) -> np.ndarray:
        """(n_orders,) complex N m: ``T_crank`` per order (gas + inertia)."""
        return self.gas_torque_orders(orders) + self.inertia_torque_orders(rpm, orders)

    def unit_inertia_orders(
        self, orders: npt.ArrayLike, about: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray]:
        """Inertia force and moment about ``about`` per order at 1 rad/s.

        Returns
        -------
        force : (n_orders, 3) complex N / (rad/s)^2.
        moment : (n_orders, 3) complex N m / (rad/s)^2.
        """
        k = self._index(orders)
        f_spec, m_spec, _ = self._unit_inertia_spectra
        f = f_spec[k]
        # M_Q = M_ref + (ref - Q) x F: a force moved to another point adds its moment.
        m = m_spec[k] + np.cross(self.reference_point - np.asarray(about, dtype=float), f)
        return f, m

    def gas_excitation(self, orders: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Gas force (always zero) and moment (``-T_gas s``, the same about every point), per order.

        Returns
        -------
        force, moment : (n_orders, 3) complex, N and N m.
        """
        t = self.gas_torque_orders(orders)
        return np.zeros((t.size, 3), dtype=complex), -np.outer(t, self.crank_axis)

    def excitation_parts(
        self, rpm: float, orders: npt.ArrayLike, about: npt.ArrayLike
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``{"gas": (F, M), "inertia": (F, M)}``, each (n_orders, 3) complex, N and N m about ``about``."""
        w2 = float(rpm_to_omega(rpm)) ** 2
        f, m = self.unit_inertia_orders(orders, about)
        return {"gas": self.gas_excitation(orders), "inertia": (w2 * f, w2 * m)}

    def excitation(
        self, rpm: float, orders: npt.ArrayLike, about: npt.ArrayLike
    ) -> tuple[np.ndarray, np.ndarray]:
        """Force and moment on the block per order (paper eq. 1, gas + inertia).

        Parameters
        ----------
        rpm : crank speed, rev/min.
        orders : (n_orders,) multiples of 0.5.
        about : (3,) m, the point the moment is taken about (pass the cog).

        Returns
        -------
        force : (n_orders, 3) complex N, ``F(t) = Re{F_h exp(i h phi)}``.
        moment : (n_orders, 3) complex N m about ``about``.
        """
        return self.order_excitation(orders, about).at(rpm)

    def order_excitation(self, orders: npt.ArrayLike, about: npt.ArrayLike) -> OrderExcitation:
        """The speed-independent parts of :meth:`excitation` for these orders, to reuse."""
        fg, mg = self.gas_excitation(orders)
        fi, mi = self.unit_inertia_orders(orders, about)
        return OrderExcitation(fg, mg, fi, mi)


def _wrap(angle: float, period: float) -> float:
    """``angle`` folded into [-period/2, period/2)."""
    return float((angle + 0.5 * period) % period - 0.5 * period)
