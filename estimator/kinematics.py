"""Rigid-body kinematics of one order frame (paper eqs. 14-15, generalised).

Every accelerometer channel c measures the component along its axis n_c of the
acceleration of its point P_c:

    a_c = n_c . (gamma_O + Omega' x OP_c) = n_c . gamma_O + (OP_c x n_c) . Omega'

which is linear in the six complex unknowns ``[gamma_O, Omega']``. With three
triaxial sensors that is 9 equations for 6 unknowns; weighted least squares
gives the motion and a residual that measures what does not fit a rigid body
(elastic modes, sensor faults). The reference point O is the centroid of the
channel positions: it keeps the columns well scaled.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from estimator.vec import cross


class KinematicsError(ValueError):
    """The sensor geometry cannot determine a rigid-body motion."""


class RigidMotion(NamedTuple):
    """Least-squares rigid-body motion of one frame, per order.

    (A named tuple: one is made per fitted frame, in a third of a frozen dataclass's
    time: 0.45 us a frame, 0.7 ms a minute of the 60 s log. Unlike a dataclass it is a
    tuple: it iterates, compares equal to a plain tuple of its values, and takes
    ``_replace`` rather than ``dataclasses.replace``.)

    Attributes
    ----------
    origin : (3,) float, m
        Reference point O (bench frame).
    gamma_o : (n_orders, 3) complex, m/s^2
        Acceleration of O.
    omega_dot : (n_orders, 3) complex, rad/s^2
        Angular acceleration.
    cov_unit : (6, 6) float
        ``(J^T W J)^-1`` of the real-valued problem per real/imag part: multiply
        by a channel noise variance to get the covariance of [gamma_O, Omega'].
    residual_rms : (n_orders,) float, m/s^2
        Weighted RMS of what the rigid fit leaves, per order.
    relative_residual : (n_orders,) float
        ``residual_rms / rms(measured)``: 0 for a perfectly rigid motion.
    noise_var : (n_orders,) float
        Estimated variance of the real (and of the imaginary) part of a
        unit-weight channel reading, ``sum w |r|^2 / (2 dof)``: with
        ``cov_unit`` it gives the covariance of the fitted motion.
    gain : (6, n_ch) float
        The fit is linear: ``[gamma_O, Omega'] = gain @ amplitudes`` per order.
    """

    origin: np.ndarray
    gamma_o: np.ndarray
    omega_dot: np.ndarray
    cov_unit: np.ndarray
    residual_rms: np.ndarray
    relative_residual: np.ndarray
    noise_var: np.ndarray
    gain: np.ndarray

    def point_acceleration(self, point: np.ndarray) -> np.ndarray:
        """(n_orders, 3) complex acceleration of ``point`` (3,) m under this motion."""
        r = np.asarray(point, dtype=float) - self.origin
        return self.gamma_o + cross(self.omega_dot, r)


def design_matrix(positions: np.ndarray, directions: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Rows ``[n_c, OP_c x n_c]`` (n_ch, 6) mapping ``[gamma_O, Omega']`` to channel readings."""
    r = np.asarray(positions, dtype=float) - origin
    n = np.asarray(directions, dtype=float)
    return np.hstack([n, cross(r, n)])


def check_geometry(positions: np.ndarray, directions: np.ndarray) -> None:
    """Raise :class:`KinematicsError` unless the channels determine all six rigid motions."""
    origin = np.mean(positions, axis=0)
    jac = design_matrix(positions, directions, origin)
    sv = np.linalg.svd(jac, compute_uv=False)
    if len(sv) < 6 or sv[-1] < 1e-6 * sv[0]:
        raise KinematicsError(
            f"{len(positions)} channels determine only {int(np.sum(sv > 1e-6 * sv[0]))} of 6 "
            "rigid-body motions: need three non-collinear triaxial sensors (or equivalent axes)"
        )


@dataclass(frozen=True)
class RigidFit:
    """The part of the rigid fit that depends only on the channel geometry and weights.

    A bench keeps the same channels frame after frame: decompose once, then a
    frame's fit is two small matrix products (:meth:`fit`).
    """

    origin: np.ndarray  # (3,) m
    jw: np.ndarray  # (n_ch, 6) weighted design matrix
    sw: np.ndarray  # (n_ch,) square roots of the weights
    pinv: np.ndarray  # (6, n_ch) of the weighted problem
    cov_unit: np.ndarray  # (6, 6)
    gain: np.ndarray  # (6, n_ch): motion = gain @ amplitudes
    mean_w: float
    channels: np.ndarray | None = None  # (n_ch,) which channels of a larger set, if any
    # (6,) unit [gamma_O, Omega'] direction the channels do not see (two triaxial
    # sensors: the rotation about the line through them); None when they see all six
    null: np.ndarray | None = None
    # (n_ch, n_ch - rank) orthonormal basis of the weighted readings that no rigid
    # motion produces: where sensor errors and noise show (estimator.redundancy)
    redundancy: np.ndarray | None = None

    def on_channels(self, channels: np.ndarray) -> RigidFit:
        """This fit, labelled with the indices of its channels in the caller's channel set."""
        return replace(self, channels=np.asarray(channels))

    @classmethod
    def of(
        cls,
        positions: np.ndarray,
        directions: np.ndarray,
        weights: np.ndarray | None = None,
        allow_null: bool = False,
    ) -> RigidFit:
        """Decompose the geometry; :class:`KinematicsError` when it is degenerate.

        With ``allow_null``, a geometry that misses exactly one rigid-body motion
        (two triaxial sensors) gives the minimum-norm fit, with no component along
        the missed motion, and that motion in ``null``.
        """
        positions = np.asarray(positions, dtype=float)
        n_ch = positions.shape[0]
        w = np.ones(n_ch) if weights is None else np.asarray(weights, dtype=float)
        origin = positions.mean(axis=0)
        sw = np.sqrt(w)
        jw = design_matrix(positions, directions, origin) * sw[:, None]
        # Solve through the SVD: the geometry may be poorly conditioned, and the
        # same decomposition gives the unit covariance for free.
        u_all, s, vt = np.linalg.svd(jw, full_matrices=True)
        u = u_all[:, : len(s)]
        null = None
        if len(s) < 6 or s[-1] < 1e-9 * s[0]:
            seen = int(np.sum(s > 1e-9 * s[0]))
            if not (allow_null and seen == 5):
                raise KinematicsError(
                    "sensor geometry is degenerate: rigid-body motion not determined"
                )
            null = vt[5].copy()
            u, s, vt = u[:, :5], s[:5], vt[:5]
        pinv = (vt.T / s) @ u.T
        return cls(
            origin=origin,
            jw=jw,
            sw=sw,
            pinv=pinv,
            cov_unit=(vt.T / s**2) @ vt,
            gain=pinv * sw,
            mean_w=float(np.mean(w)),
            null=null,
            redundancy=u_all[:, len(s) :],
        )

    @functools.cached_property
    def residual_projector(self) -> np.ndarray:
        """(n_ch, n_ch) ``I - J_w J_w^+``: the weighted readings' part no rigid motion makes."""
        return np.eye(self.sw.size) - self.jw @ self.pinv

    @functools.cached_property
    def residual_projector_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """The diagonal of :attr:`residual_projector` and its elements squared
        (:func:`estimator.rigidity.noise_levels_many`: once per geometry, not per run)."""
        m = self.residual_projector
        return np.diag(m).copy(), m**2

    @functools.cached_property
    def omega_trace(self) -> float:
        """The trace of :attr:`cov_unit`'s Omega' block: the noise of a fitted Omega'
        per unit channel variance (:meth:`estimator.gating.OrderGates.curvature`)."""
        return float(np.trace(self.cov_unit[3:, 3:]))

    @property
    def rank(self) -> int:
        """How many rigid-body motions the channels determine (6, or 5 with ``null``)."""
        return 6 if self.null is None else 5

    def fit(self, amplitudes: np.ndarray) -> RigidMotion:
        """The motion per order from (n_orders, n_ch) complex amplitudes, m/s^2."""
        return self.fit_many(np.atleast_2d(np.asarray(amplitudes, dtype=complex))[None])[0]

    def fit_many(self, amplitudes: np.ndarray) -> list[RigidMotion]:
        """One motion per frame from (n_frames, n_orders, n_ch) complex amplitudes, m/s^2.

        The frames are fitted together (a few array operations for all of them);
        each frame's result depends on its own amplitudes only.
        """
        return self.motions(*self.fit_arrays(amplitudes))

    def fit_arrays(
        self, amplitudes: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`fit_many` as arrays: ``[gamma_O, Omega']`` (n_frames, n_orders, 6)
        complex, and the residual RMS, relative residual and noise variance
        (n_frames, n_orders) of :class:`RigidMotion`."""
        n_f, n_o, n_ch = amplitudes.shape
        # one matrix product per frame, as a frame alone gets it: a product over all
        # the frames' rows at once may take another BLAS kernel for another row count
        y3 = amplitudes * self.sw
        x3 = np.matmul(y3, self.pinv.T)  # (n_f, n_o, 6)
        resid3 = y3 - np.matmul(x3, self.jw.T)
        a = amplitudes.reshape(n_f * n_o, n_ch)
        x, resid = x3.reshape(n_f * n_o, 6), resid3.reshape(n_f * n_o, n_ch)
        dof = max(self.sw.size - self.rank, 1)
        resid_ss = np.add.reduce(resid.real**2 + resid.imag**2, axis=1)
        residual_rms = np.sqrt(resid_ss / dof / self.mean_w)
        # (np.mean's sum and division without its wrapper's checks: the same bits)
        signal_rms = np.sqrt(np.add.reduce(a.real**2 + a.imag**2, axis=1) / n_ch)
        with np.errstate(divide="ignore", invalid="ignore"):
            relative = np.where(signal_rms > 0, residual_rms / signal_rms, 0.0)
        noise_var = resid_ss / (2 * dof)
        shape = (n_f, n_o)
        return (
            x.reshape(n_f, n_o, 6),
            residual_rms.reshape(shape),
            relative.reshape(shape),
            noise_var.reshape(shape),
        )

    def motions(
        self, x: np.ndarray, residual_rms: np.ndarray, relative: np.ndarray, noise_var: np.ndarray
    ) -> list[RigidMotion]:
        """The :class:`RigidMotion` of each frame from :meth:`fit_arrays`."""
        # (positional fields, rows taken by iterating: a few hundred ns less per frame;
        # tuple.__new__ is what the named tuple's __new__ calls, without its frame)
        o, cov, gain, new = self.origin, self.cov_unit, self.gain, tuple.__new__
        return [
            new(RigidMotion, (o, g, w, cov, r, rel, nv, gain))
            for g, w, r, rel, nv in zip(
                x[:, :, :3], x[:, :, 3:], residual_rms, relative, noise_var, strict=True
            )
        ]


def fit_rigid_motion(
    amplitudes: np.ndarray,
    positions: np.ndarray,
    directions: np.ndarray,
    weights: np.ndarray | None = None,
) -> RigidMotion:
    """Fit ``gamma_O`` and ``Omega'`` to the channel amplitudes of one frame.

    Parameters
    ----------
    amplitudes : (n_orders, n_ch) complex, m/s^2
        Order amplitudes of the usable channels.
    positions : (n_ch, 3) float, m
        Channel (sensor) positions, bench frame.
    directions : (n_ch, 3) float
        Unit measuring axes, bench frame.
    weights : (n_ch,) float, optional
        Inverse noise variances (relative); default equal.
    """
    return RigidFit.of(positions, directions, weights).fit(amplitudes)
