"""Simulated classical tests of a known powertrain: pendulum periods and hammer FRFs.

Pendulum: a torsional pendulum (or rolling plate) swinging the body about
given axes through its cog; periods from ``T = 2 pi sqrt(I_total / C)`` with
``I_total = u^T I u`` (plus ``I_plate + M d^2`` on a plate), plumb lines
through the suspension points and the cog. Noise draws the errors a lab
makes: period and stiffness readings off by a relative error, the real axis
turned away from the stated one, plumb lines marked off their true place.
The file states the nominal values and the declared uncertainties.

FRFs: the rigid body on a soft suspension (:class:`powertrain.mounted.MountedPowertrain`
with the suspension springs as mounts, no crank spin) plus one elastic
mode, ``H = -w^2 T_ch (K - w^2 M)^-1 T_f^T + sum phi_ch phi_f (-w^2) / (m_e (w_e^2 - w^2 + 2 i zeta w w_e))``,
with noise ``H (1 + 10^(-snr/20) e)``, ``e`` circular complex normal of unit
variance per line (the relative scatter of an H1 estimate at a given coherence).
Accelerance convention ``x(t) = Re{X exp(i w t)}``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acquisition.classical.pendulum_file import (
    Configuration,
    Line,
    Meta,
    PendulumTestFile,
    Plate,
    Truth,
    TruthTerms,
    Uncertainty,
)
from powertrain.mounted import Mount, MountedPowertrain
from powertrain.rigidbody import RigidBody, inertia_terms, rotation_matrix
from powertrain.sensors import rigid_channel_matrix

DEG = math.pi / 180.0

#: X, Y, Z, the three face diagonals and one body diagonal: 7 swings, condition 3.4
DEFAULT_AXES = (
    np.array(
        [
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 1.0, 0.0],
            [1.0, 0.0, 1.0],
            [0.0, 1.0, 1.0],
            [1.0, -1.0, 1.0],
        ]
    )
    / np.linalg.norm(
        [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1], [1, -1, 1]], axis=1
    )[:, None]
)


@dataclass(frozen=True)
class PendulumNoise:
    """1-sigma errors drawn into a simulated pendulum test (0 = exact).

    ``period_pct``, ``stiffness_pct`` relative, independent per swing;
    ``stiffness_calibration_pct`` one relative error shared by all; ``axis_deg`` the real axis
    against the stated one; ``line_position_m``, ``line_angle_deg`` the marked
    plumb lines; ``plate_point_m`` the stated pivot point across the axis.
    """

    period_pct: float = 0.0
    stiffness_pct: float = 0.0
    stiffness_calibration_pct: float = 0.0
    axis_deg: float = 0.0
    line_position_m: float = 0.0
    line_angle_deg: float = 0.0
    plate_point_m: float = 0.0


def _across(u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A standard normal vector in the plane across unit ``u`` (unit variance per axis)."""
    v = rng.standard_normal(3)
    return v - (v @ u) * u


def _turned(u: np.ndarray, sigma: float, draw: np.ndarray) -> np.ndarray:
    """``u`` turned by ``sigma * draw`` (a vector across ``u``): isotropic angle error."""
    angle = sigma * float(np.linalg.norm(draw))
    return u if angle == 0 else rotation_matrix(draw, angle) @ u


def _plate_pivot(cog: np.ndarray, u: np.ndarray, offset: float) -> np.ndarray:
    """A point of the plate's pivot: ``offset`` below the cog, across the axis ``u``."""
    down = np.array([0.0, 0.0, -1.0])
    across = down - (down @ u) * u
    if np.linalg.norm(across) < 1e-6:  # vertical axis: pivot beside the cog instead
        across = np.array([1.0, 0.0, 0.0]) - u[0] * u
    return cog + offset * across / np.linalg.norm(across)


def simulate_pendulum_test(
    body: RigidBody,
    axes: npt.ArrayLike | None = None,
    stiffness: float | Sequence[float] = 40.0,
    suspension_points: npt.ArrayLike | None = None,
    method: str = "pendulum",
    plate_inertia: float = 0.8,
    plate_offset: float = 0.25,
    noise: PendulumNoise | None = None,
    declared: PendulumNoise | None = None,
    seed: int = 0,
    name: str = "simulated pendulum test",
) -> PendulumTestFile:
    """A pendulum or rolling-plate test of ``body`` with the errors of ``noise``.

    Parameters
    ----------
    body : the truth.
    axes : (n, 3) swing axes through the cog; default :data:`DEFAULT_AXES`.
    stiffness : N m/rad, the suspension's torsional stiffness (one value or one per axis).
    suspension_points : (k, 3) m, points the body is hung from for the plumb lines
        (default: none, no cog lines).
    method : "pendulum" or "rolling_plate".
    plate_inertia : kg m^2, the plate's inertia about its pivot (rolling plate).
    plate_offset : m, distance from the cog to the pivot (rolling plate).
    noise : the errors drawn; default none.
    declared : the uncertainties the file states; default the same as ``noise``.
    seed : random seed.
    """
    noise = noise or PendulumNoise()
    declared = noise if declared is None else declared
    rng = np.random.default_rng(seed)
    a = np.asarray(DEFAULT_AXES if axes is None else axes, dtype=float)
    a = a / np.linalg.norm(a, axis=1)[:, None]
    n = len(a)
    c_true = np.broadcast_to(np.asarray(stiffness, dtype=float), (n,))
    cog = body.cog
    # Draws in a fixed order, always all of them, so one noise size never reshuffles another.
    axis_draw = [_across(u, rng) for u in a]
    period_draw = rng.standard_normal(n)
    stiff_draw = rng.standard_normal(n)
    plate_draw = [_across(u, rng) for u in a]
    calibration = 1 + noise.stiffness_calibration_pct / 100 * rng.standard_normal()
    configs = []
    for i, u in enumerate(a):
        true_axis = _turned(u, noise.axis_deg * DEG, axis_draw[i])
        total = float(true_axis @ body.inertia @ true_axis)
        pivot = None
        if method == "rolling_plate":
            pivot = _plate_pivot(cog, u, plate_offset)
            r = cog - pivot
            d2 = float(r @ r - (r @ true_axis) ** 2)
            total += plate_inertia + body.mass * d2
            pivot = pivot + noise.plate_point_m * plate_draw[i]
        period = 2 * math.pi * math.sqrt(total / c_true[i])
        period *= 1 + noise.period_pct / 100 * period_draw[i]
        c_stated = c_true[i] * (1 + noise.stiffness_pct / 100 * stiff_draw[i]) * calibration
        configs.append(
            Configuration(
                name=f"swing {i + 1}",
                axis=u.tolist(),
                period_s=period,
                stiffness_nm_per_rad=float(c_stated),
                plate_axis_point_m=None if pivot is None else pivot.tolist(),
            )
        )
    lines = []
    if suspension_points is not None:
        for p in np.atleast_2d(np.asarray(suspension_points, dtype=float)):
            d = cog - p
            d = d / np.linalg.norm(d)
            # The marked line: moved across itself, and turned about the hook point.
            shift = noise.line_position_m * _across(d, rng)
            turned = _turned(d, noise.line_angle_deg * DEG, _across(d, rng))
            lines.append(Line(point_m=(p + shift).tolist(), direction=turned.tolist()))
    plate = None
    if method == "rolling_plate":
        plate = Plate(
            inertia_kgm2=plate_inertia,
            body_mass_kg=body.mass,
            cog_m=None if lines else cog.tolist(),
        )
    return PendulumTestFile(
        meta=Meta(name=name, method=method),  # type: ignore[arg-type]
        uncertainty=Uncertainty(
            period_pct=declared.period_pct,
            stiffness_pct=declared.stiffness_pct,
            stiffness_calibration_pct=declared.stiffness_calibration_pct,
            axis_std_deg=declared.axis_deg,
            line_position_std_m=declared.line_position_m,
            line_angle_std_deg=declared.line_angle_deg,
            plate_point_std_m=declared.plate_point_m,
        ),
        plate=plate,
        lines=lines,
        configurations=configs,
        truth=Truth(
            mass_kg=body.mass,
            cog_m=cog.tolist(),
            inertia_kgm2=TruthTerms(**inertia_terms(body.inertia)),
        ),
    )


# -- FRFs -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Hit:
    """One excitation: a unit force along ``direction`` (3,) at ``position`` (3,) m."""

    name: str
    position: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class ElasticModeSpec:
    """The first elastic mode of the simulated test article.

    Shape: bending along the crank axis ``s`` plus a twist about it,
    ``phi(P) = (xi^2 - 1/3) c + 0.5 xi s x (P - G) / L`` with ``xi = s . (P - G) / L``,
    ``L`` the largest axial distance of a channel or hit from the cog and ``c``
    the vertical across ``s``; modal mass ``m_e`` for that shape (default a
    quarter of the body's mass, as the first bending mode of a free beam
    normalised to 1 at its ends).
    """

    frequency_hz: float = 250.0
    damping_ratio: float = 0.02
    modal_mass_kg: float | None = None
    axis: tuple[float, float, float] = (0.0, 1.0, 0.0)


def default_hits(sensor_positions: npt.ArrayLike, offset: float = 0.03) -> tuple[Hit, ...]:
    """Two hits beside each sensor, along two different bench axes (six for three sensors).

    Sensor k is hit ``offset`` away from it along bench axis ``(k + 2) mod 3``,
    in the directions ``k mod 3`` and ``(k + 1) mod 3``, so three sensors give
    every direction twice at different points.
    """
    hits = []
    for k, p in enumerate(np.atleast_2d(np.asarray(sensor_positions, dtype=float))):
        at = p + offset * np.eye(3)[(k + 2) % 3]
        for j in (k % 3, (k + 1) % 3):
            hits.append(Hit(f"hit{k + 1}{'xyz'[j]}", at, np.eye(3)[j]))
    return tuple(hits)


def soft_suspension(
    body: RigidBody,
    half_size: tuple[float, float] = (0.3, 0.4),
    top_hz: float = 5.0,
    loss_factor: float = 0.05,
) -> tuple[Mount, ...]:
    """Four equal isotropic springs at the corners of a horizontal rectangle through the cog.

    Stiffness scaled so the highest suspension mode is at ``top_hz``; with the
    default half sizes and the example powertrains the six modes fall between
    about 2 Hz (the three translations) and ``top_hz`` (the rotations).
    """
    hx, hy = half_size
    corners = [body.cog + np.array([sx * hx, sy * hy, 0.0]) for sx in (-1, 1) for sy in (-1, 1)]

    def springs(k: float) -> tuple[Mount, ...]:
        return tuple(
            Mount(f"spring{i + 1}", c, np.eye(3), np.full(3, k), loss_factor)
            for i, c in enumerate(corners)
        )

    top = float(np.max(MountedPowertrain(body, springs(1.0)).modes().frequency_hz))
    return springs((top_hz / top) ** 2)


def elastic_shape(
    points: npt.ArrayLike, cog: npt.ArrayLike, axis: npt.ArrayLike, length: float
) -> np.ndarray:
    """(n, 3) modal displacement of the elastic mode at ``points`` (see :class:`ElasticModeSpec`)."""
    s = np.asarray(axis, dtype=float)
    s = s / np.linalg.norm(s)
    up = np.array([0.0, 0.0, 1.0])
    c = up - (up @ s) * s
    if np.linalg.norm(c) < 1e-6:
        c = np.array([1.0, 0.0, 0.0]) - s[0] * s
    c = c / np.linalg.norm(c)
    r = np.atleast_2d(np.asarray(points, dtype=float)) - np.asarray(cog, dtype=float)
    xi = (r @ s) / length
    return (xi**2 - 1.0 / 3.0)[:, None] * c + 0.5 * xi[:, None] * np.cross(s, r) / length


def simulate_frfs(
    body: RigidBody,
    channel_positions: npt.ArrayLike,
    channel_directions: npt.ArrayLike,
    hits: Sequence[Hit],
    frequency: npt.ArrayLike,
    mounts: Sequence[Mount] = (),
    elastic: ElasticModeSpec | None = None,
    snr_db: float | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Accelerance FRFs, (n_f, n_ch, n_hits) complex m/s^2/N (module docstring).

    Parameters
    ----------
    body : mass, cog, inertia.
    channel_positions, channel_directions : (n_ch, 3) m and unit axes.
    hits : the excitations.
    frequency : (n_f,) Hz, > 0.
    mounts : the suspension (empty: free-free).
    elastic : optional elastic mode.
    snr_db : relative noise level per line (None: exact).
    seed : noise seed.
    """
    f = np.asarray(frequency, dtype=float)
    w = 2 * np.pi * f
    pos = np.asarray(channel_positions, dtype=float)
    dirs = np.asarray(channel_directions, dtype=float)
    hit_pos = np.array([h.position for h in hits], dtype=float)
    hit_dir = np.array([h.direction for h in hits], dtype=float)
    hit_dir = hit_dir / np.linalg.norm(hit_dir, axis=1)[:, None]
    t_ch = rigid_channel_matrix(pos, dirs, body.cog)
    t_f = rigid_channel_matrix(hit_pos, hit_dir, body.cog)
    mounted = MountedPowertrain(body, tuple(mounts), spin_inertia=0.0)
    dyn = mounted.K[None] - (w**2)[:, None, None] * mounted.M[None]
    q = np.linalg.solve(dyn, np.broadcast_to(t_f.T.astype(complex), (len(f), 6, len(hits))))
    h = -(w**2)[:, None, None] * (t_ch @ q)
    if elastic is not None:
        every = np.vstack([pos, hit_pos])
        length = float(np.max(np.abs((every - body.cog) @ np.asarray(elastic.axis, float))))
        shape_ch = np.einsum("ci,ci->c", elastic_shape(pos, body.cog, elastic.axis, length), dirs)
        shape_f = np.einsum(
            "ei,ei->e", elastic_shape(hit_pos, body.cog, elastic.axis, length), hit_dir
        )
        m_e = body.mass / 4 if elastic.modal_mass_kg is None else elastic.modal_mass_kg
        we = 2 * np.pi * elastic.frequency_hz
        modal = -(w**2) / (m_e * (we**2 - w**2 + 2j * elastic.damping_ratio * we * w))
        h = h + modal[:, None, None] * np.outer(shape_ch, shape_f)[None]
    if snr_db is not None:
        rng = np.random.default_rng(seed)
        e = (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / math.sqrt(2)
        h = h * (1 + 10 ** (-snr_db / 20) * e)
    return h
