"""Gas torque orders from a measured cylinder-1 pressure spectrum.

With a cylinder-pressure channel on the bench, the gas torque need not come
from a model: the dsp gives the pressure's complex amplitudes ``P_k`` at every
half order ``k / 2`` (``p(phi) = P_0 + sum_k Re{P_k exp(i k phi / 2)}``, phi
from cylinder 1's firing TDC), and the torque the pistons deliver to the crank,

    T(phi) = -sum_c (p(phi - f_c) - p_cc) A x_t(phi - alpha_c)

(:meth:`powertrain.engine.Engine.gas_torque`, every cylinder firing like
cylinder 1 at its firing angle ``f_c``), is linear in the ``P_k``. Its order
``h`` is a convolution of the pressure orders with the orders of the
slider-crank lever ``x_t``, which fall off like ``(r / l)^n``: pressure orders up
to 6 give the inline 3's order 1.5 to 1.4e-6 (its order 3 needs 7.5 for 2e-6).

The map is built once per engine: each unit cosine and sine pressure order times the
lever is, on the cycle's grid, the lever's DFT shifted by that order (see
:func:`pressure_torque_map`); the tests check it against putting the unit orders through
the time-domain torque and decomposing the result. Applying it costs one small matrix
product per frame.

Assumptions the user must know (``docs/bench-file.md``): every cylinder has
cylinder 1's pressure, shifted by its firing interval; the channel is the
absolute pressure (pegged), since its mean times the lever's orders enters the
even orders (order 2 of an inline 4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from powertrain.engine import Engine
from powertrain.errors import PhysicsError
from powertrain.gas import CYCLE


@dataclass(frozen=True)
class PressureTorqueMap:
    """``T_h = constant_h + sum_k (from_re[h, k] Re P_k + from_im[h, k] Im P_k)``, N m.

    Attributes
    ----------
    orders : (n_orders,) torque orders.
    constant : (n_orders,) complex N m, the crankcase pressure's share.
    from_re, from_im : (n_orders, n_half) complex N m / Pa.
    """

    orders: np.ndarray
    constant: np.ndarray
    from_re: np.ndarray
    from_im: np.ndarray

    @property
    def n_half(self) -> int:
        """How many pressure half orders (0, 0.5, ...) the map takes."""
        return int(self.from_re.shape[1])

    def torque(self, spectrum: npt.ArrayLike) -> np.ndarray:
        """Gas torque per order (N m, complex) from pressure spectra (Pa).

        ``spectrum`` is (n_half,) or (n_frames, n_half) complex; higher half
        orders than the map takes are ignored, fewer are an error.
        """
        p = np.asarray(spectrum)
        if p.shape[-1] < self.n_half:
            raise PhysicsError(
                f"pressure spectrum: need half orders 0..{self.n_half - 1}, got {p.shape[-1]}"
            )
        p = p[..., : self.n_half]
        return self.constant + p.real @ self.from_re.T + p.imag @ self.from_im.T


def pressure_torque_map(
    engine: Engine, orders: npt.ArrayLike, max_pressure_order: float = 6.0
) -> PressureTorqueMap:
    """The linear map from cylinder-1 pressure orders ``0 .. max_pressure_order`` to the
    gas torque of ``engine`` at ``orders`` (see the module docstring)."""
    h = np.atleast_1d(np.asarray(orders, dtype=float))
    n_half = round(2 * max_pressure_order) + 1
    if n_half < 1 or abs(2 * max_pressure_order - (n_half - 1)) > 1e-9:
        raise PhysicsError(
            f"max_pressure_order: expected a multiple of 0.5 >= 0, got {max_pressure_order}"
        )
    n = engine.samples_per_cycle
    if 2 * (n_half - 1) >= n // 4 or np.any(2 * h >= n // 4):
        raise PhysicsError(f"orders too high for {n} samples per cycle")
    phi = np.arange(n) * CYCLE / n
    area = engine.geometry.area
    # lever[c] = -A x_t of cylinder c on the grid
    lever = np.stack(
        [-area * engine.slider_crank.piston_motion(phi - a)[1] for a in engine.throw_angles]
    )
    # Unit pressure order k of cylinder c is cos (Re P_k) or -sin (Im P_k) of
    # k (phi - f_c) / 2, and k phi_j / 2 = 2 pi k j / n: on the grid, the product with the
    # lever shifts the lever's DFT F_c by k bins, turned by e^{-+i k f_c / 2}:
    #   DFT[cos term][m] = 1/2 sum_c (e^{-i k f_c/2} F_c[m - k] + e^{i k f_c/2} F_c[m + k])
    #   DFT[-sin term][m] = i/2 sum_c (e^{-i k f_c/2} F_c[m - k] - e^{i k f_c/2} F_c[m + k])
    # the same numbers as multiplying on the grid and transforming (the test keeps that
    # construction as the reference), with one FFT per cylinder instead of 2 n_half
    # (cos and sin of n_half x n_cyl x n points): 10 -> 1.5 ms for the default map.
    spectra = np.fft.fft(lever, axis=1)  # (n_cyl, n)
    index = np.rint(2 * h).astype(int)  # DFT bin m of each torque order
    k = np.arange(n_half)
    turn = np.exp(-0.5j * k[None, :] * engine.firing_angles[:, None])[:, None, :]
    below = spectra[:, (index[:, None] - k[None, :]) % n]  # (n_cyl, n_orders, n_half)
    above = spectra[:, (index[:, None] + k[None, :]) % n]
    from_cos = 0.5 * np.sum(turn * below + np.conj(turn) * above, axis=0)
    from_sin = 0.5j * np.sum(turn * below - np.conj(turn) * above, axis=0)
    constant = np.sum(spectra[:, index], axis=0)
    # the mean torque (order 0) is real: exactly, as the real FFT of the grid gives it
    mean = index == 0
    for part in (from_cos, from_sin, constant):
        part[mean] = part[mean].real
    # half_order_spectrum's scaling: 2 / n, the mean 1 / n
    scale = np.where(mean, 1.0 / n, 2.0 / n)
    return PressureTorqueMap(
        orders=h,
        constant=-engine.crankcase_pressure * constant * scale,
        from_re=from_cos * scale[:, None],
        from_im=from_sin * scale[:, None],
    )
