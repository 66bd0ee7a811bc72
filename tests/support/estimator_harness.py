"""An independent forward model for estimator tests: a rigid body on mounts, solved directly.

The estimator inverts the equations of motion; this module integrates them
the other way (6x6 harmonic solve for the displacement of G and the rotation),
written separately from ``powertrain`` so the estimator is checked against a
second derivation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimator.setup import (
    Corrections,
    EstimatorSetup,
    ExcitationFn,
    Gates,
    MountStiffness,
    Tolerances,
)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


@dataclass(frozen=True)
class Frame:
    time_s: float
    rpm: float
    orders: tuple[float, ...]
    channels: tuple[str, ...]
    amplitudes: np.ndarray
    channel_ok: np.ndarray
    rpm_change: float = 0.0
    flags: frozenset[str] = field(default_factory=frozenset)
    spectrum: np.ndarray | None = None  # a pressure channel's half orders 0, 0.5, ...
    variance_factor: np.ndarray | None = None  # per channel: a window that lost samples


@dataclass
class Body:
    mass: float = 110.0
    cog: np.ndarray = field(default_factory=lambda: np.array([0.035, -0.085, 0.105]))
    inertia: np.ndarray = field(
        default_factory=lambda: np.array(
            [[4.6, -0.28, 0.42], [-0.28, 3.1, -0.21], [0.42, -0.21, 4.2]]
        )
    )
    spin: float = 0.13
    unbalance: complex = 0.0  # z = m r exp(-i beta), kg m
    # more point unbalances on the crank: (z kg m, axial m along AXIS_S from UNB_POINT)
    point_unbalances: tuple[tuple[complex, float], ...] = ()


AXIS_S = np.array([0.0, 1.0, 0.0])
AXIS_C = np.array([0.0, 0.0, 1.0])
UNB_POINT = np.array([0.0, 0.0, 0.0])
REF = np.array([0.0, 0.0, 0.0])

SENSORS = np.array([[0.05, 0.30, 0.29], [0.02, -0.42, 0.25], [-0.26, -0.02, -0.12]])
MOUNT_POS = np.array([[0.06, 0.34, 0.31], [0.02, -0.46, 0.27], [-0.30, -0.02, -0.16]])
MOUNT_K = np.array([[110e3, 70e3, 190e3], [90e3, 60e3, 170e3], [300e3, 15e3, 15e3]])
ETA = 0.12


def mounts() -> tuple[MountStiffness, ...]:
    return tuple(
        MountStiffness(f"m{i}", MOUNT_POS[i], np.diag(MOUNT_K[i]) * (1 + 1j * ETA))
        for i in range(3)
    )


def excitation(rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fixed, rich load pattern: inertia-like parts scale with w^2, a gas-like roll at H1.5."""
    w2 = (rpm * 2 * np.pi / 60) ** 2
    rng = np.random.default_rng(7)
    forces, moments = [], []
    for h in orders:
        f = np.zeros(3, complex)
        m = w2 * 2e-3 * (rng.normal(size=3) + 1j * rng.normal(size=3))
        if h == 2.0:  # an inline-4-like free force, vertical
            f = w2 * np.array([0.0, 0.0, 0.02 * (1 + 0.3j)])
        if h == 1.5:
            m = m * 0.2 + np.array([0.0, -150.0 * np.exp(0.4j), 0.0])
        forces.append(f)
        moments.append(m)
    return np.array(forces), np.array(moments)


def channel_geometry() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rot = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    dirs = np.vstack([np.eye(3), rot, np.eye(3)])
    pos = np.repeat(SENSORS, 3, axis=0)
    return pos, dirs, np.repeat(np.arange(3), 3)


def respond(
    body: Body,
    rpm: float,
    orders: np.ndarray,
    with_mounts: bool = True,
    excitation_fn: ExcitationFn | None = None,
) -> np.ndarray:
    """Channel amplitudes (n_orders, 9) of the body driven by ``excitation_fn`` (default
    :func:`excitation`, looked up when called: tests replace it)."""
    w = rpm * 2 * np.pi / 60
    force, moment_r = (excitation_fn or excitation)(rpm, orders)
    g = body.cog
    pos, dirs, _ = channel_geometry()
    out = []
    for k, h in enumerate(orders):
        big_w = h * w
        f_unb = np.zeros(3, complex)
        if h == 1.0:
            f_unb = w**2 * body.unbalance * (AXIS_C - 1j * np.cross(AXIS_S, AXIS_C))
        # unknowns q = [u_G, theta]; equations: forces, moments about G
        a = np.zeros((6, 6), complex)
        b = np.zeros(6, complex)
        a[:3, :3] = -(big_w**2) * body.mass * np.eye(3)
        a[3:, 3:] = -(big_w**2) * body.inertia + 1j * big_w * (-_skew(body.spin * w * AXIS_S))
        b[:3] = force[k] + f_unb
        b[3:] = moment_r[k] + np.cross(REF - g, force[k]) + np.cross(UNB_POINT - g, f_unb)
        for z, axial in body.point_unbalances if h == 1.0 else ():
            # each a rotating force w^2 m r at its own point on the crank
            f_p = w**2 * z * (AXIS_C - 1j * np.cross(AXIS_S, AXIS_C))
            b[:3] += f_p
            b[3:] += np.cross(UNB_POINT + axial * AXIS_S - g, f_p)
        if with_mounts:
            for p, kk in zip(MOUNT_POS, MOUNT_K, strict=True):
                kc = np.diag(kk) * (1 + 1j * ETA)
                t = np.hstack([np.eye(3), -_skew(p - g)])  # u_p = u_G + theta x (p - G)
                a[:3] += kc @ t
                a[3:] += _skew(p - g) @ kc @ t
        q = np.linalg.solve(a, b)
        acc = -(big_w**2) * (q[:3][None, :] + np.cross(q[3:][None, :], pos - g))
        out.append(np.einsum("cj,cj->c", acc, dirs))
    return np.array(out)


def make_setup(body: Body, mass_known: bool = True, **kw: object) -> EstimatorSetup:
    pos, dirs, sensor = channel_geometry()
    return EstimatorSetup(
        channels=tuple(f"ch{i}" for i in range(9)),
        sensor_of_channel=sensor,
        positions=pos,
        directions=dirs,
        reference_point=REF,
        unbalance_point=UNB_POINT,
        crank_axis=AXIS_S,
        cylinder_axis=AXIS_C,
        spin_inertia=body.spin,
        excitation=kw.pop("excitation_fn", excitation),  # type: ignore[arg-type]
        mounts=mounts(),
        mass_nominal=body.mass if mass_known else body.mass * 1.1,
        mass_known=mass_known,
        cog_nominal=body.cog + np.array([0.01, -0.01, 0.01]),
        inertia_nominal=body.inertia * 1.1,
        mode_max_hz=None,
        corrections=kw.pop("corrections", Corrections()),  # type: ignore[arg-type]
        tolerances=kw.pop("tolerances", Tolerances()),  # type: ignore[arg-type]
        gates=kw.pop("gates", Gates()),  # type: ignore[arg-type]
    )


def frames(body: Body, rpms: np.ndarray, orders: tuple[float, ...] = (1.0, 1.5, 2.0), **kw: object):
    for i, rpm in enumerate(rpms):
        amps = respond(body, float(rpm), np.array(orders), **kw)  # type: ignore[arg-type]
        yield Frame(
            time_s=float(i),
            rpm=float(rpm),
            orders=orders,
            channels=tuple(f"ch{j}" for j in range(9)),
            amplitudes=amps,
            channel_ok=np.ones(9, bool),
        )


class SplitExcitation:
    """A derivative offering its speed-split parts (estimator.setup.PairExcitationSplitFn):
    per order h, gas ``h c_gas`` and unit-speed ``h^2 c_unit``; a pair's value (its call,
    what the numpy rows take) ``gas + omega^2 unit``."""

    def split(self, key: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
        h = np.array(key)[:, None, None]
        gas = h * np.array([[0.1, 0.2j, 0.3], [0.02j, 0.01, 0.03]])
        return gas, h**2 * np.array([[0.3j, 0.1, 0.2], [0.01, 0.05j, 0.02]])

    def __call__(self, rpm: np.ndarray, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = tuple(sorted(set(orders.tolist())))
        gas, unit = self.split(key)
        at = [key.index(h) for h in orders.tolist()]
        both = gas[at] + ((rpm * np.pi / 30) ** 2)[:, None, None] * unit[at]
        return both[:, 0], both[:, 1]
