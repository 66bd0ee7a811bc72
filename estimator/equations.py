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
unbalance of the crank: the static part ``F_unb = w^2 z (c - i t)``,
``z = m r exp(-i beta)``, acting at ``P_u`` (``setup.unbalance_point``, on the
crank axis), and the couple part ``i w^2 q (c - i t)`` (kg m^2). A point
unbalance z at ``a`` m along s from ``P_u`` is the static part z at ``P_u`` and
the couple ``a s x F_unb = i w^2 (a z) (c - i t)`` (``s x (c - i t) = i (c - i
t)``), so q = a z; a two-plane (dynamic) unbalance adds a q of any phase. Both
are linear: the location is ``a = Re(q conj z) / |z|^2`` (:mod:`estimator.result`).

Unknowns theta: the six inertia terms, G, [z and q as two reals each], [1/m],
[crank offset d]. Everything is linear in theta except ``G x F_unb`` and the offset;
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

import functools
from dataclasses import dataclass

import numpy as np

from estimator.setup import EstimatorSetup
from estimator.vec import cross, skew
from powertrain.rigidbody import inertia_matrix

INERTIA_TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def inertia_columns(omega_dot: np.ndarray) -> np.ndarray:
    """(3, 6) matrix A with ``I @ omega_dot == A @ [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]``."""
    return inertia_columns_batch(np.asarray(omega_dot)[None, :])[0]


@dataclass(frozen=True)
class ParameterLayout:
    """Where each unknown sits in theta."""

    unbalance: bool
    mass: bool
    offset: bool
    couple: bool = False  # the unbalance's couple q too (with ``unbalance``)
    mount_scales: tuple[str, ...] = ()  # mounts whose stiffness scale is estimated
    calibrate: tuple[str, ...] = ()  # systematic parameters estimated (sensor gains, alignment)

    @functools.cached_property  # (frozen: built once; index() is called per flush)
    def names(self) -> tuple[str, ...]:
        names = [*INERTIA_TERMS, "Gx", "Gy", "Gz"]
        if self.unbalance:
            names += ["unb_re", "unb_im"]
            if self.couple:
                names += ["unb_couple_re", "unb_couple_im"]
        if self.mass:
            names += ["inv_mass"]
        if self.offset:
            names += ["crank_offset"]
        names += [f"kscale:{m}" for m in self.mount_scales]
        names += [f"cal:{c}" for c in self.calibrate]
        return tuple(names)

    @property
    def size(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)


def parameter_scale(
    layout: ParameterLayout, inertia_nominal: np.ndarray, mass_nominal: float
) -> np.ndarray:
    """(n,) the size each parameter is expected to have (rank decisions, convergence)."""
    scale = []
    inertia = float(np.trace(inertia_nominal) / 3)
    for name in layout.names:
        if name.startswith("I"):
            scale.append(inertia)
        elif name.startswith("G"):
            scale.append(0.1)
        elif name.startswith("unb_couple"):
            scale.append(1e-4)  # 1 g m 0.1 m off P_u, kg m^2 (not divided by m: no force)
        elif name.startswith("unb"):
            scale.append(1e-3 / (mass_nominal if layout.mass else 1.0))
        elif name == "inv_mass":
            scale.append(1.0 / mass_nominal)
        elif name.startswith("kscale:"):
            scale.append(1.0)
        else:
            scale.append(0.01)
    return np.array(scale)


@dataclass(frozen=True)
class Linearisation:
    """Current estimates used in the linearised terms and the row weighting."""

    cog: np.ndarray
    inertia: np.ndarray
    mass: float
    mount_scale: np.ndarray | None = None  # (n_mounts,) current stiffness scales; None: 1


def linearisation_at(
    layout: ParameterLayout, theta: np.ndarray, observable: np.ndarray, mass: float
) -> Linearisation:
    """The linearisation point of an estimate ``theta``: its inertia and cog, its mass
    (``mass`` where 1/m is not determined or not positive) and its mount stiffness
    scales (1 where not determined)."""
    if layout.mass and observable[layout.index("inv_mass")]:
        inv = theta[layout.index("inv_mass")]
        if inv > 0:
            mass = 1.0 / inv
    scales = None
    if layout.mount_scales:
        at = [layout.index(f"kscale:{m}") for m in layout.mount_scales]
        scales = np.where(observable[at], theta[at], 1.0)
    return Linearisation(
        cog=theta[6:9].copy(), inertia=inertia_matrix(*theta[:6]), mass=mass, mount_scale=scales
    )


@dataclass(frozen=True)
class FrameRows:
    """Whitened rows of the orders of one frame (leading axis: order).

    ``H`` (n_o, 12, n) and ``y`` (n_o, 12) are whitened; ``whiten`` (n_o, 12, 12)
    maps raw residuals to whitened ones; ``d_meas`` (n_o, 12, 12) is the
    derivative of the raw residual with respect to the real measurement vector
    ``[Re gamma_O, Re Omega', Im gamma_O, Im Omega']``.
    """

    H: np.ndarray
    y: np.ndarray
    whiten: np.ndarray
    d_meas: np.ndarray


def skew_batch(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of (..., 3) vectors."""
    out = np.zeros((*v.shape[:-1], 3, 3), dtype=v.dtype)
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def inertia_columns_batch(w: np.ndarray) -> np.ndarray:
    """(n_o, 3, 6): ``I @ w == A @ [Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` for each row of w (n_o, 3)."""
    a = np.zeros((w.shape[0], 3, 6), dtype=w.dtype)
    wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
    a[:, 0, 0], a[:, 0, 3], a[:, 0, 4] = wx, -wy, -wz
    a[:, 1, 1], a[:, 1, 3], a[:, 1, 5] = wy, -wx, -wz
    a[:, 2, 2], a[:, 2, 4], a[:, 2, 5] = wz, -wx, -wy
    return a


_EYE3 = np.eye(3)
_EYE12 = np.eye(12)


def _scales(lin: Linearisation, n: int) -> np.ndarray:
    return np.ones(n) if lin.mount_scale is None else np.asarray(lin.mount_scale, float)[:n]


def frame_rows(
    setup: EstimatorSetup,
    layout: ParameterLayout,
    lin: Linearisation,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    origin: np.ndarray,
    cov_unit: np.ndarray,
    orders: np.ndarray,
    rpm: float | np.ndarray,
    force: np.ndarray,
    moment_r: np.ndarray,
    noise_var: np.ndarray,
    measured_moment: np.ndarray | None = None,
) -> FrameRows:
    """Rows of the given (frame, order) pairs: one row block per pair.

    The pairs may come from several frames (the estimator assembles a few frames
    at once: the per-call overhead of numpy dominates at these sizes); then
    ``rpm``, ``origin`` and ``cov_unit`` are given per pair.

    Parameters
    ----------
    gamma_o, omega_dot : (n_o, 3) complex
        Fitted rigid motion per order (acceleration of ``origin``, angular acceleration).
    origin : (3,) or (n_o, 3) m; cov_unit : (6, 6) or (n_o, 6, 6) unit covariance of the fit.
    orders : (n_o,) float.
    rpm : scalar or (n_o,).
    force, moment_r : (n_o, 3) complex
        Known excitation force (N) and moment about ``setup.reference_point`` (N m).
    noise_var : (n_o,) float
        Channel noise variance (m/s^2)^2 per order; scales ``cov_unit``.
    measured_moment : (n_o, 3) complex or None
        The part of ``moment_r`` measured in the frames' crank angle (the gas moment
        from a pressure channel): a reference offset turns it like the motion.
    """
    n_o = len(orders)
    n = layout.size
    h = np.asarray(orders, float)
    w = np.broadcast_to(np.asarray(rpm, float) * 2 * np.pi / 60.0, (n_o,))
    big_w2 = (h * w) ** 2
    o = np.broadcast_to(np.asarray(origin, float), (n_o, 3))
    sk_cog_o = skew_batch(lin.cog - o)  # (n_o, 3, 3)
    corr = setup.corrections
    bt = setup.frame_constants
    eye = np.broadcast_to(_EYE3, (n_o, 3, 3))

    # Mount reactions f_i = K_i gamma_i / W^2 and their derivatives w.r.t. [gamma_O, Omega'],
    # every mount at once (axis 0); sums over the mounts in mount order (np.add.reduce
    # along the first axis adds them one after the other).
    f_mounts = np.zeros((n_o, 3), complex)
    m_mounts_origin = np.zeros((n_o, 3), complex)  # sum p_i x f_i
    zeros = np.zeros((n_o, 3, 3), complex)
    df_dgo, df_dw, dmp_dgo, dmp_dw = zeros, zeros, zeros, zeros
    scale_cols = []  # per estimated mount scale: its reaction f_i at nominal stiffness
    if corr.suspension and setup.mounts:
        p, stiff, sk_p = bt.mount_positions, bt.mount_stiffness, bt.skew_p
        s_m = np.ones(len(p)) if lin.mount_scale is None else np.asarray(lin.mount_scale, float)
        sk_r = skew_batch(p[:, None, :] - o[None])  # (M, n_o, 3, 3)
        kw = s_m[:, None, None, None] * stiff[:, None] / big_w2[None, :, None, None]
        # row-vector forms: a x v = a @ skew(v), v x a = a @ skew(v).T
        gamma_i = gamma_o[None] + np.einsum("oi,moij->moj", omega_dot, sk_r)
        f_i = np.einsum("moij,moj->moi", kw, gamma_i)  # (M, n_o, 3)
        if layout.mount_scales:
            scale_cols = [(f_i[m] / s_m[m], p[m]) for m in range(len(p))]
        else:
            f_mounts = f_mounts + np.add.reduce(f_i, axis=0)
            m_mounts_origin = m_mounts_origin + np.add.reduce(f_i @ bt.skew_p_t, axis=0)
        dfi_dw = -kw @ sk_r
        df_dgo = zeros + np.add.reduce(kw, axis=0)
        df_dw = zeros + np.add.reduce(dfi_dw, axis=0)
        dmp_dgo = zeros + np.add.reduce(sk_p @ kw, axis=0)
        dmp_dw = zeros + np.add.reduce(sk_p @ dfi_dw, axis=0)

    spin = (setup.spin_inertia / (1j * h)) if corr.gyroscopic else np.zeros(n_o, complex)
    gyro = spin[:, None] * (omega_dot @ bt.skew_s)
    dgyro_dw = -spin[:, None, None] * bt.skew_s[None]

    ht = np.zeros((n_o, 3, n), complex)  # translation rows
    hr = np.zeros((n_o, 3, n), complex)  # rotation rows
    m_hat = lin.mass
    f_known = force + f_mounts
    # With estimated scales s_i the reactions sum s_i f_i are unknowns: f_known holds none
    # of them, and G x sum s_i f_i is linearised about the current (G0, s0):
    # G x F0 + G0 x sum s_i f_i - G0 x F0, F0 = sum s0_i f_i.
    f_scaled = np.zeros((n_o, 3), complex)  # F0
    for (f_nom, _), s0 in zip(scale_cols, _scales(lin, len(scale_cols)), strict=True):
        f_scaled += s0 * f_nom
    sk_w = skew_batch(omega_dot)
    sk_wo = np.einsum("oij,oj->oi", sk_w, o)

    if layout.mass:
        # gamma_O + Omega' x (G - O) = mu (F_exc + F_m) + w^2 mu z (c - i t)
        ht[:, :, 6:9] = sk_w
        ht[:, :, layout.index("inv_mass")] = -f_known
        yt = -gamma_o + sk_wo
        dt_dgo = eye - df_dgo / m_hat
        dt_dw = -sk_cog_o - df_dw / m_hat
        unb_scale = m_hat  # F_unb = w^2 m (z/m) (c - i t) in the rotation rows
    else:
        # m (gamma_O + Omega' x (G - O)) - w^2 z (c - i t) = F_exc + F_m
        ht[:, :, 6:9] = m_hat * sk_w
        yt = f_known - m_hat * gamma_o + m_hat * sk_wo
        dt_dgo = m_hat * eye - df_dgo
        dt_dw = -m_hat * sk_cog_o - df_dw
        unb_scale = 1.0

    # I Omega' + G x (F_exc + F_m) - (P_u - G) x F_unb = M_R + R x F_exc + sum p_i x f_i - gyro
    hr[:, :, :6] = inertia_columns_batch(omega_dot)
    hr[:, :, 6:9] = -skew_batch(f_known + f_scaled)
    yr = moment_r + force @ bt.skew_ref_t + m_mounts_origin - gyro
    if scale_cols:
        if layout.mass:
            raise ValueError("mount stiffness scales need a known mass")
        yr = yr + cross(lin.cog, f_scaled)
        for name, (f_nom, p_i) in zip(layout.mount_scales, scale_cols, strict=True):
            j = layout.index(f"kscale:{name}")
            ht[:, :, j] = -f_nom
            hr[:, :, j] = cross(lin.cog - p_i, f_nom)
    sk_g = skew(lin.cog)
    dr_dgo = sk_g @ df_dgo - dmp_dgo
    dr_dw = lin.inertia[None] + dgyro_dw + sk_g @ df_dw - dmp_dw

    if layout.unbalance:
        first = np.flatnonzero(h == 1.0)
        if first.size:
            col_a = (w[first] ** 2)[:, None] * bt.c_it  # z = a + i b: F_unb = a col_a + b (i col_a)
            col_b = 1j * col_a
            arm = setup.unbalance_point - lin.cog
            ia, ib = layout.index("unb_re"), layout.index("unb_im")
            ht[first, :, ia], ht[first, :, ib] = -col_a, -col_b
            hr[first, :, ia] = -unb_scale * cross(arm, col_a)
            hr[first, :, ib] = -unb_scale * cross(arm, col_b)
            if layout.couple:  # i w^2 q (c - i t) = q_re col_b - q_im col_a, a moment only
                qa, qb = layout.index("unb_couple_re"), layout.index("unb_couple_im")
                hr[first, :, qa], hr[first, :, qb] = -col_b, col_a

    # d residual / d measurement, complex (n_o, 6, 6) on [gamma_O, Omega'].
    d_c = np.empty((n_o, 6, 6), complex)
    d_c[:, :3, :3], d_c[:, :3, 3:], d_c[:, 3:, :3], d_c[:, 3:, 3:] = dt_dgo, dt_dw, dr_dgo, dr_dw
    if layout.offset:
        # A reference offset d multiplies every measured amplitude by exp(-i h d):
        # d residual / d d = D (-i h m) at d = 0.
        meas = np.concatenate([gamma_o, omega_dot], axis=1)
        col = np.einsum("oij,oj->oi", d_c, -1j * h[:, None] * meas)
        ht[:, :, layout.index("crank_offset")] = col[:, :3]
        hr[:, :, layout.index("crank_offset")] = col[:, 3:]
        if measured_moment is not None:
            # moment_r enters the residual with -1 and turns by exp(-i h d) as well
            hr[:, :, layout.index("crank_offset")] += 1j * h[:, None] * measured_moment

    hc = np.concatenate([ht, hr], axis=1)  # (n_o, 6, n)
    yc = np.concatenate([yt, yr], axis=1)  # (n_o, 6)
    H = np.concatenate([hc.real, hc.imag], axis=1)
    y = np.concatenate([yc.real, yc.imag], axis=1)
    d_real = np.empty((n_o, 12, 12))
    d_real[:, :6, :6] = d_c.real
    d_real[:, :6, 6:] = -d_c.imag
    d_real[:, 6:, :6] = d_c.imag
    d_real[:, 6:, 6:] = d_c.real
    # Real and imaginary parts of the measurement are independent with the same
    # covariance: cov(rows) = D diag(C, C) D^T, C = noise_var * cov_unit.
    cov_unit = np.broadcast_to(np.asarray(cov_unit, float), (n_o, 6, 6))
    cu = cov_unit * np.asarray(noise_var, float)[:, None, None]
    da, db = d_real[:, :, :6], d_real[:, :, 6:]
    cov_rows = da @ cu @ da.transpose(0, 2, 1) + db @ cu @ db.transpose(0, 2, 1)
    # Whitening with the Cholesky factor of the row covariance (tiny jitter keeps
    # it positive definite when a row does not depend on the measurement at all).
    jitter = 1e-12 * np.trace(cov_rows, axis1=1, axis2=2) / 12 + 1e-300
    cov_rows += jitter[:, None, None] * _EYE12
    whiten = np.linalg.inv(np.linalg.cholesky(cov_rows))
    return FrameRows(
        H=whiten @ H, y=np.einsum("oij,oj->oi", whiten, y), whiten=whiten, d_meas=d_real
    )
