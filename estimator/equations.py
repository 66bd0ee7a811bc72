"""The equations of motion of one order of one frame, as real rows ``H theta = y``.

For order h at crank speed w (W = h w), with the rigid motion ``gamma_O``,
``Omega'`` fitted to the accelerometers (:mod:`estimator.kinematics`):

translation   m (gamma_O + Omega' x (G - O)) = F_exc + F_mounts + F_unb
rotation      I Omega' + Omega x H_spin = M_R + (R - G) x F_exc
                                         + sum_i (p_i - G) x f_i + (P_u - G) x F_unb

with the known excitation ``F_exc``, ``M_R`` (moment about the fixed point R),
mount reactions ``f_i = -K_i u_i = K_i gamma_i / W^2`` (complex stiffness,
``u_i = -gamma_i / W^2``), gyroscopic term ``Omega x H = (J / (i h)) Omega' x s``
(``Omega = Omega' / (i W)``, ``H = J w s``) and, at h = 1 only, the residual
static unbalance ``F_unb = w^2 z (c - i t)``, ``z = m r exp(-i beta)``.

Unknowns theta: the six inertia terms, G, [z as two reals], [1/m], [crank
offset d]. Everything is linear in theta except ``G x F_unb`` and the offset;
those two are linearised about the current estimate (both are small: a 1 mm
cog error times a 50 N unbalance force is 5e-5 of a 1000 N m H1 moment).
With an unknown mass the translation is divided by m and the unknowns become
``1/m`` and ``z/m``, which keeps it linear.

Each order gives 12 real rows (6 complex). They are whitened with the
covariance that the measurement noise of ``[gamma_O, Omega']`` induces in
them (full propagation through ``D = d rows / d measurement``), so rows in N
and in N m are weighed consistently and correlated rows are not over-counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.kinematics import RigidMotion
from estimator.setup import EstimatorSetup

INERTIA_TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix: ``skew(a) @ b == a x b`` (works for complex vectors)."""
    x, y, z = v
    return np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]], dtype=np.result_type(v, float))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` for two 3-vectors; np.cross costs ~20 us per call on vectors this small."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def inertia_columns(omega_dot: np.ndarray) -> np.ndarray:
    """(3, 6) matrix A with ``I @ omega_dot == A @ [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]``."""
    wx, wy, wz = omega_dot
    zero = 0 * wx
    return np.array(
        [
            [wx, zero, zero, -wy, -wz, zero],
            [zero, wy, zero, -wx, zero, -wz],
            [zero, zero, wz, zero, -wx, -wy],
        ]
    )


@dataclass(frozen=True)
class ParameterLayout:
    """Where each unknown sits in theta."""

    unbalance: bool
    mass: bool
    offset: bool

    @property
    def names(self) -> tuple[str, ...]:
        names = [*INERTIA_TERMS, "Gx", "Gy", "Gz"]
        if self.unbalance:
            names += ["unb_re", "unb_im"]
        if self.mass:
            names += ["inv_mass"]
        if self.offset:
            names += ["crank_offset"]
        return tuple(names)

    @property
    def size(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)


@dataclass(frozen=True)
class Linearisation:
    """Current estimates used in the linearised terms and the row weighting."""

    cog: np.ndarray
    inertia: np.ndarray
    mass: float


@dataclass(frozen=True)
class OrderRows:
    """Whitened rows of one order of one frame.

    ``H`` (12, n) and ``y`` (12,) are whitened; ``whiten`` (12, 12) maps raw
    residuals to whitened ones; ``d_meas`` (12, 12) is the derivative of the
    raw residual with respect to the real measurement vector
    ``[Re gamma_O, Re Omega', Im gamma_O, Im Omega']``.
    """

    H: np.ndarray
    y: np.ndarray
    whiten: np.ndarray
    d_meas: np.ndarray


def _real_rows(hc: np.ndarray, yc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.vstack([hc.real, hc.imag]), np.concatenate([yc.real, yc.imag])


def order_rows(
    setup: EstimatorSetup,
    layout: ParameterLayout,
    lin: Linearisation,
    motion: RigidMotion,
    k: int,
    order: float,
    rpm: float,
    force: np.ndarray,
    moment_r: np.ndarray,
    noise_var: float,
) -> OrderRows:
    """Rows of order ``order`` (index ``k`` in ``motion``) at ``rpm``.

    Parameters
    ----------
    force, moment_r : (3,) complex
        Known excitation force (N) and moment about ``setup.reference_point`` (N m).
    noise_var : float
        Channel noise variance (m/s^2)^2 of this order; scales ``motion.cov_unit``.
    """
    n = layout.size
    w = rpm * 2 * np.pi / 60.0
    big_w2 = (order * w) ** 2
    o = motion.origin
    gamma_o = motion.gamma_o[k]
    omega_dot = motion.omega_dot[k]
    corr = setup.corrections
    eye = np.eye(3)

    # Mount reactions f_i = K_i gamma_i / W^2 and their derivatives w.r.t. [gamma_O, Omega'].
    f_mounts = np.zeros(3, complex)
    m_mounts_origin = np.zeros(3, complex)  # sum p_i x f_i
    df_dgo = np.zeros((3, 3), complex)
    df_dw = np.zeros((3, 3), complex)
    dmp_dgo = np.zeros((3, 3), complex)  # d(sum p_i x f_i)/d gamma_O
    dmp_dw = np.zeros((3, 3), complex)
    if corr.suspension:
        for mount in setup.mounts:
            r = mount.position - o
            kw = mount.stiffness / big_w2
            gamma_i = gamma_o + cross(omega_dot, r)
            f_i = kw @ gamma_i
            f_mounts += f_i
            m_mounts_origin += cross(mount.position, f_i)
            dfi_dw = kw @ -skew(r)
            df_dgo += kw
            df_dw += dfi_dw
            dmp_dgo += skew(mount.position) @ kw
            dmp_dw += skew(mount.position) @ dfi_dw

    s = setup.crank_axis
    c = setup.cylinder_axis
    t = cross(s, c)
    gyro = (setup.spin_inertia / (1j * order)) * cross(omega_dot, s) if corr.gyroscopic else 0 * s
    dgyro_dw = -(setup.spin_inertia / (1j * order)) * skew(s) if corr.gyroscopic else 0 * eye

    ht = np.zeros((3, n), complex)  # translation rows
    hr = np.zeros((3, n), complex)  # rotation rows
    g_idx = slice(6, 9)
    m_hat = lin.mass
    f_known = force + f_mounts

    if layout.mass:
        # gamma_O + Omega' x (G - O) = mu (F_exc + F_m) + w^2 mu z (c - i t)
        ht[:, g_idx] = skew(omega_dot)
        ht[:, layout.index("inv_mass")] = -f_known
        yt = -gamma_o + skew(omega_dot) @ o
        dt_dgo = eye - df_dgo / m_hat
        dt_dw = -skew(lin.cog - o) - df_dw / m_hat
        unb_scale = m_hat  # F_unb = w^2 m (z/m) (c - i t) in the rotation rows
    else:
        # m (gamma_O + Omega' x (G - O)) - w^2 z (c - i t) = F_exc + F_m
        ht[:, g_idx] = m_hat * skew(omega_dot)
        yt = f_known - m_hat * gamma_o + m_hat * skew(omega_dot) @ o
        dt_dgo = m_hat * eye - df_dgo
        dt_dw = -m_hat * skew(lin.cog - o) - df_dw
        unb_scale = 1.0

    # I Omega' + G x (F_exc + F_m) - (P_u - G) x F_unb = M_R + R x F_exc + sum p_i x f_i - gyro
    hr[:, :6] = inertia_columns(omega_dot)
    hr[:, g_idx] = -skew(f_known)
    yr = moment_r + cross(setup.reference_point, force) + m_mounts_origin - gyro
    dr_dgo = skew(lin.cog) @ df_dgo - dmp_dgo
    dr_dw = lin.inertia + dgyro_dw + skew(lin.cog) @ df_dw - dmp_dw

    if layout.unbalance and order == 1.0:
        col_a = w**2 * (c - 1j * t)  # z = a + i b: F_unb = a col_a + b (i col_a)
        col_b = 1j * col_a
        arm = setup.unbalance_point - lin.cog
        ia, ib = layout.index("unb_re"), layout.index("unb_im")
        ht[:, ia], ht[:, ib] = -col_a, -col_b
        hr[:, ia] = -unb_scale * cross(arm, col_a)
        hr[:, ib] = -unb_scale * cross(arm, col_b)

    # d residual / d measurement, complex (6, 6) on [gamma_O, Omega'].
    d_c = np.block([[dt_dgo, dt_dw], [dr_dgo, dr_dw]])
    if layout.offset:
        # A reference offset d multiplies every measured amplitude by exp(-i h d):
        # d residual / d d = D (-i h m) at d = 0.
        meas = np.concatenate([gamma_o, omega_dot])
        col = d_c @ (-1j * order * meas)
        ht[:, layout.index("crank_offset")] = col[:3]
        hr[:, layout.index("crank_offset")] = col[3:]

    hc = np.vstack([ht, hr])
    yc = np.concatenate([yt, yr])
    H, y = _real_rows(hc, yc)
    d_real = np.block([[d_c.real, -d_c.imag], [d_c.imag, d_c.real]])
    cov_meas = np.kron(np.eye(2), motion.cov_unit) * noise_var
    cov_rows = d_real @ cov_meas @ d_real.T
    # Whitening with the Cholesky factor of the row covariance (tiny jitter keeps
    # it positive definite when a row does not depend on the measurement at all).
    jitter = 1e-12 * np.trace(cov_rows) / 12 + 1e-300
    chol = np.linalg.cholesky(cov_rows + jitter * np.eye(12))
    whiten = np.linalg.inv(chol)
    return OrderRows(H=whiten @ H, y=whiten @ y, whiten=whiten, d_meas=d_real)
