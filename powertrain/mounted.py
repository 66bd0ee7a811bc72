"""The powertrain as a rigid body on elastic mounts, with the crank train's spin.

Coordinates ``q = [u_G (3) m, theta (3) rad]``: small translation of the cog
and small rotation, bench frame. A point P moves by ``u_G + theta x GP``, so
``u_P = T_P q`` with ``T_P = [1, -skew(GP)]``. A mount with local axes ``R``
(rows, bench frame) and stiffness ``k`` pushes back with
``-R^T diag(k (1 + i eta)) R u_P``; its generalised force is ``T_P^T`` of that.

The spinning crank train (inertia ``J`` about ``s``) carries ``H = J omega s``;
the rotation equation ``I Omega' + Omega x H = M`` gives, with ``Omega = theta'``,
the skew gyroscopic matrix ``G = [[0, 0], [0, -skew(H)]]``. At order ``h`` of a
crank speed ``omega`` (``W = h omega``)::

    (-W^2 M + i W G + K) Q = [F; M_G]

and the acceleration of a point P is ``-W^2 (u_G + theta x GP)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from powertrain.errors import PhysicsError
from powertrain.rigidbody import RigidBody, skew

DOFS = ("x", "y", "z", "rx", "ry", "rz")


@dataclass(frozen=True)
class Mount:
    """One elastic mount.

    Parameters
    ----------
    name : label.
    position : (3,) m, bench frame (the elastic centre).
    axes : (3, 3) rows = the mount's local axes in the bench frame, orthonormal.
    stiffness : (3,) N/m along the local axes, >= 0.
    loss_factor : eta, stiffness becomes ``k (1 + i eta)``.
    """

    name: str
    position: np.ndarray = field(repr=False)
    axes: np.ndarray = field(repr=False)
    stiffness: np.ndarray = field(repr=False)
    loss_factor: float = 0.0

    def __post_init__(self) -> None:
        pos = np.array(self.position, dtype=float)
        axes = np.array(self.axes, dtype=float)
        k = np.array(self.stiffness, dtype=float)
        if pos.shape != (3,) or axes.shape != (3, 3) or k.shape != (3,):
            raise PhysicsError(
                f"mount {self.name}: position (3,), axes (3, 3), stiffness (3,) expected, "
                f"got {pos.shape}, {axes.shape}, {k.shape}"
            )
        err = float(np.abs(axes @ axes.T - np.eye(3)).max())
        if err > 1e-6:
            raise PhysicsError(
                f"mount {self.name}: axes rows must be orthonormal (|A A^T - 1| = {err:.3g})"
            )
        if np.any(k < 0) or self.loss_factor < 0:
            raise PhysicsError(
                f"mount {self.name}: stiffness {k.tolist()} N/m and loss factor {self.loss_factor} must be >= 0"
            )
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "stiffness", k)


def transfer_matrix(point: npt.ArrayLike, cog: npt.ArrayLike) -> np.ndarray:
    """(3, 6): displacement of ``point`` from ``q``, ``u_P = u_G + theta x GP``."""
    return np.hstack(
        [np.eye(3), -skew(np.asarray(point, dtype=float) - np.asarray(cog, dtype=float))]
    )


def mass_matrix(body: RigidBody) -> np.ndarray:
    """(6, 6) ``blockdiag(m 1, I_G)``, kg and kg m^2."""
    m = np.zeros((6, 6))
    m[:3, :3] = body.mass * np.eye(3)
    m[3:, 3:] = body.inertia
    return m


def stiffness_matrix(
    mounts: tuple[Mount, ...], cog: npt.ArrayLike, damped: bool = True
) -> np.ndarray:
    """(6, 6) complex ``sum T^T R^T diag(k (1 + i eta)) R T`` (real part only if not ``damped``)."""
    k = np.zeros((6, 6), dtype=complex)
    for mount in mounts:
        t = mount.axes @ transfer_matrix(mount.position, cog)
        eta = mount.loss_factor if damped else 0.0
        k += t.T @ (np.diag(mount.stiffness * (1 + 1j * eta)) @ t)
    return k


def gyroscopic_matrix(spin_inertia: float, omega: float, axis: npt.ArrayLike) -> np.ndarray:
    """(6, 6) real skew: ``G = [[0, 0], [0, -skew(J omega s)]]``, N m s."""
    g = np.zeros((6, 6))
    g[3:, 3:] = -skew(spin_inertia * omega * np.asarray(axis, dtype=float))
    return g


def dof_labels(crank_axis: np.ndarray) -> tuple[str, ...]:
    """Names of the six DOF as in the paper's Fig. 3: rotation about the crank axis is roll.

    Translations: X fore-aft, Y lateral, Z bounce. Rotations: about Z yaw, about
    the horizontal bench axis nearest the crank axis roll, about the other pitch.
    """
    s = np.abs(np.asarray(crank_axis, dtype=float))
    roll_about_y = s[1] >= s[0]
    return (
        "fore-aft",
        "lateral",
        "bounce",
        "pitch" if roll_about_y else "roll",
        "roll" if roll_about_y else "pitch",
        "yaw",
    )


@dataclass(frozen=True)
class Modes:
    """Rigid-body modes, ascending frequency.

    Attributes
    ----------
    frequency_hz : (6,) Hz (damped frequency ``Im(s) / 2 pi`` for complex modes).
    damping_ratio : (6,) ``-Re(s) / |s|``, zero for the undamped real modes.
    shapes : (6, 6) columns = mode shapes in ``q`` (m, rad), unit kinetic energy norm.
    energy : (6, 6) column j = share of mode j's kinetic energy per DOF
        (``Re(conj(v) * (M v)) / v^H M v``), sums to 1.
    labels : the DOF names for rows of ``shapes`` and ``energy``.
    """

    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    shapes: np.ndarray
    energy: np.ndarray
    labels: tuple[str, ...]

    def dominant(self) -> list[str]:
        """Per mode, the label of the DOF holding most of its kinetic energy."""
        return [self.labels[int(np.argmax(self.energy[:, j]))] for j in range(self.energy.shape[1])]


class MountedPowertrain:
    """Rigid body + mounts + crank-train spin (see module docstring).

    Parameters
    ----------
    body : mass, cog, inertia about the cog.
    mounts : the elastic mounts (may be empty: a free body).
    spin_inertia : J, kg m^2 about ``spin_axis`` of everything spinning with the crank.
    spin_axis : (3,) unit crank axis ``s``.
    """

    def __init__(
        self,
        body: RigidBody,
        mounts: tuple[Mount, ...] = (),
        spin_inertia: float = 0.0,
        spin_axis: npt.ArrayLike = (0.0, 1.0, 0.0),
    ) -> None:
        if spin_inertia < 0:
            raise PhysicsError(f"spin inertia must be >= 0, got {spin_inertia} kg m^2")
        self.body = body
        self.mounts = tuple(mounts)
        self.spin_inertia = float(spin_inertia)
        self.spin_axis = np.asarray(spin_axis, dtype=float)
        self.M = mass_matrix(body)  # (6, 6) kg, kg m^2
        self.K = stiffness_matrix(self.mounts, body.cog)  # (6, 6) complex N/m, N m/rad
        # G per unit crank speed: G(omega) = omega * G1, N m s per rad/s.
        self.G1 = gyroscopic_matrix(self.spin_inertia, 1.0, self.spin_axis)

    def dynamic_matrix(self, omega: npt.ArrayLike, orders: npt.ArrayLike) -> np.ndarray:
        """(..., n_orders, 6, 6) complex ``-W^2 M + i W G(omega) + K`` for ``W = h omega``.

        ``omega`` (rad/s) may be an array; it broadcasts against the orders axis.
        """
        w = np.asarray(omega, dtype=float)[..., None, None, None]
        h = np.asarray(orders, dtype=float)[:, None, None]
        # -W^2 M + i W (omega G1) + K = K + omega^2 (-h^2 M + i h G1)
        return self.K + w**2 * (-(h**2) * self.M + 1j * h * self.G1)

    def response(
        self, omega: npt.ArrayLike, orders: npt.ArrayLike, load: npt.ArrayLike
    ) -> np.ndarray:
        """Harmonic response ``Q`` per order.

        Parameters
        ----------
        omega : () or (n,) crank speed, rad/s.
        orders : (n_orders,).
        load : (..., n_orders, 6) complex ``[F (N); M_G (N m)]`` about the cog.

        Returns
        -------
        (..., n_orders, 6) complex ``[u_G (m); theta (rad)]``.
        """
        a = self.dynamic_matrix(omega, orders)
        b = np.broadcast_to(np.asarray(load, dtype=complex), a.shape[:-1])
        if self.mounts == () and np.any(np.asarray(orders) == 0):
            raise PhysicsError("a free body (no mounts) has no static response at order 0")
        return np.linalg.solve(a, b[..., None])[..., 0]

    def response_sweep(
        self,
        omega: npt.ArrayLike,
        orders: npt.ArrayLike,
        load_per_omega2: npt.ArrayLike,
        load_fixed: npt.ArrayLike,
    ) -> np.ndarray:
        """Harmonic response over many speeds, for loads ``omega^2 L1 + L0``.

        Same result as :meth:`response`, faster on long sweeps: per order,
        ``K + omega^2 B`` (``B = -h^2 M + i h G1``) is diagonalised once as
        ``B (B^-1 K + omega^2) = B V (Lambda + omega^2) V^-1``, so each speed costs a
        diagonal solve. Falls back to batched solves when ``V`` is ill-conditioned.

        Parameters
        ----------
        omega : (n,) rad/s.
        orders : (n_orders,).
        load_per_omega2 : (n_orders, 6) complex, the part scaling with ``omega^2`` (N s^2, N m s^2).
        load_fixed : (n_orders, 6) complex, the speed-independent part (N, N m).

        Returns
        -------
        (n, n_orders, 6) complex.
        """
        w2 = np.asarray(omega, dtype=float) ** 2
        h = np.asarray(orders, dtype=float)
        l1 = np.asarray(load_per_omega2, dtype=complex)
        l0 = np.asarray(load_fixed, dtype=complex)
        b = -(h[:, None, None] ** 2) * self.M + 1j * h[:, None, None] * self.G1
        if np.any(h == 0):
            return self.response(np.sqrt(w2), h, w2[:, None, None] * l1 + l0)
        lam, vec = np.linalg.eig(np.linalg.solve(b, np.broadcast_to(self.K, b.shape)))
        if np.max(np.linalg.cond(vec)) > 1e8:
            return self.response(np.sqrt(w2), h, w2[:, None, None] * l1 + l0)
        # y = V^-1 B^-1 L for both load parts, once per order.
        to_modal = np.linalg.solve(vec, np.linalg.inv(b))
        y1 = np.einsum("oij,oj->oi", to_modal, l1)
        y0 = np.einsum("oij,oj->oi", to_modal, l0)
        z = (w2[:, None, None] * y1 + y0) / (lam + w2[:, None, None])
        return np.einsum("oij,roj->roi", vec, z)

    def point_acceleration(
        self, q: np.ndarray, omega: npt.ArrayLike, orders: npt.ArrayLike, point: npt.ArrayLike
    ) -> np.ndarray:
        """(..., n_orders, 3) complex m/s^2 at ``point``: ``-W^2 (u_G + theta x GP)``."""
        w = (
            np.asarray(omega, dtype=float)[..., None, None]
            * np.asarray(orders, dtype=float)[:, None]
        )
        u = q @ transfer_matrix(point, self.body.cog).T
        return -(w**2) * u

    def modes(self, omega: float | None = None) -> Modes:
        """Rigid-body modes.

        With ``omega`` None: undamped modes at zero speed (mount loss ignored),
        real shapes from ``K v = w^2 M v``. With ``omega`` (rad/s, may be 0):
        complex modes of ``s^2 M + s G(omega) + K(1 + i eta)``, the six roots with
        ``Im(s) > 0`` (hysteretic damping is meant for positive frequencies).
        """
        labels = dof_labels(self.spin_axis)
        if omega is None:
            from scipy.linalg import eigh

            lam, vec = eigh(self.K.real, self.M)
            freq = np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi)
            shapes = vec.astype(complex)
            damping = np.zeros(6)
        else:
            m_inv = np.linalg.inv(self.M)
            a = np.zeros((12, 12), dtype=complex)
            a[:6, 6:] = np.eye(6)
            a[6:, :6] = -m_inv @ self.K
            a[6:, 6:] = -m_inv @ (omega * self.G1)
            roots, vec = np.linalg.eig(a)
            keep = np.argsort(-roots.imag)[:6]
            roots, shapes = roots[keep], vec[:6, keep]
            order = np.argsort(roots.imag)
            roots, shapes = roots[order], shapes[:, order]
            freq = roots.imag / (2 * np.pi)
            mag = np.abs(roots)
            damping = np.where(mag > 0, -roots.real / np.where(mag > 0, mag, 1.0), 0.0)
        mv = self.M @ shapes
        norm = np.einsum("ij,ij->j", shapes.conj(), mv).real
        energy = (shapes.conj() * mv).real / norm
        shapes = shapes / np.sqrt(norm)
        if omega is not None:
            # Rotate each complex shape so its largest entry is real and positive.
            big = shapes[np.argmax(np.abs(shapes), axis=0), np.arange(6)]
            shapes = shapes * (np.abs(big) / big)
        return Modes(freq, damping, shapes, energy, labels)
