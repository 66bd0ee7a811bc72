"""The re-simulation check (paper section 6.3, Figs. 16/17): put the estimate back in the model.

The estimated body (mass, cog, inertia) replaces the bench file's powertrain in the
6-DOF model (:class:`powertrain.model.BenchModel`): same mounts, same engine
excitation, same nominal sensors. Its order amplitudes at every recorded
frame's rpm are compared with the measured ones, channel by channel, in dB and
degrees. Where the estimator also estimated them, the residual static unbalance
(a rotating order-1 force) and the crank-angle reference offset ``d`` (every
measured order ``h`` turned by ``exp(i h d)``, see :mod:`estimator.equations`)
are put in as well: without the unbalance the order-1 comparison would show the
unbalance, not the inertia.

Differences are ``pred / meas``: ``20 log10 |pred / meas|`` dB and ``arg(pred / meas)``
deg, so +1 dB means the model is 1 dB above the measurement.

Which differences can be judged. A channel reads ``n . a_P``; the bench file declares
how well each channel is known (1 sigma: relative gain ``g``, orientation ``alpha``
rad, position ``p`` m: ``[estimator]`` tolerances). Those errors alone move the
reading by (first order, independent errors)::

    sigma^2 = g^2 |n . a_P|^2 + alpha^2 ||n x a_P||^2 + p^2 ||n x Omega'||^2

(a small turn ``e`` changes the reading by ``e . (n x a_P)``, a small shift ``d`` by
``d . (n x Omega')``). A channel whose relative ``sigma / |n . a_P|`` exceeds the
amplitude limit (0.5 dB = 5.9 %) is *tolerance-limited*: a weak axis of a sensor that
sees a strong motion across it. It is shown but does not count in the verdict,
because no inertia estimate could make the model match it better than the sensor
is known.

The verdict uses the 95th percentile over the mass-line frames (the frames whose
order the estimator used: above the rigid-body modes, rigid) of the absolute
difference, per order and channel; the median is the systematic part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from estimator.result import tensor_from_terms
from estimator.setup import Tolerances
from powertrain.balancing import Unbalance
from powertrain.errors import PhysicsError
from powertrain.half_orders import rpm_to_omega
from powertrain.model import BenchModel
from powertrain.mounted import Mount
from powertrain.rigidbody import RigidBody, consistency_problems
from powertrain.sensors import Sensor
from ptinertia import config
from ptinertia.bench import build_engine, gas_model

TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
LIMIT_DB = 0.5
LIMIT_DEG = 5.0


@dataclass(frozen=True)
class EstimatedProperties:
    """What the re-simulation takes from a result document (SI, bench frame).

    Attributes
    ----------
    mass : kg; ``mass_source`` says whether it was estimated or taken from the bench file.
    cog : (3,) m.
    inertia : (3, 3) kg m^2 about the cog (the physically consistent tensor).
    unbalance : residual static unbalance, or None.
    crank_offset_rad : the estimated crank reference offset ``d`` (0 when not estimated).
    half_order_sign : +1, or -1 when the estimator resolved the 720 deg ambiguity the other way.
    """

    mass: float
    mass_source: str
    cog: np.ndarray
    inertia: np.ndarray
    unbalance: Unbalance | None
    crank_offset_rad: float
    half_order_sign: int

    @property
    def body(self) -> RigidBody:
        return RigidBody(self.mass, self.cog, self.inertia)


def estimated_properties(doc: dict[str, Any], bench: config.Bench) -> EstimatedProperties:
    """The estimate of a result document (``Estimate.to_json``) in physical form.

    The mass is the estimated one when the document has it, else the bench file's
    (weighed) ``[powertrain] mass_kg``. A tensor that is not physical is replaced by
    the document's principal moments and axes (the nearest physical tensor, as the
    estimator reports it).

    Raises
    ------
    PhysicsError
        When the document has no usable inertia or cog.
    """
    terms = np.array([doc["inertia_kgm2"]["value"][k] for k in TERMS], dtype=float)
    inertia = tensor_from_terms(terms)
    if consistency_problems(inertia):
        principal = doc.get("principal") or {}
        moments = np.asarray(principal.get("moments_kgm2", []), float)
        axes = np.asarray(principal.get("axes", []), float)  # rows: principal axes
        if moments.shape != (3,) or axes.shape != (3, 3):
            raise PhysicsError(
                f"the estimated inertia is not physical: {consistency_problems(inertia)[0]}"
            )
        inertia = axes.T @ np.diag(moments) @ axes
    mass_doc = doc.get("mass_kg")
    if mass_doc and mass_doc.get("value"):
        mass, source = float(mass_doc["value"]), "estimated"
    else:
        mass, source = float(bench.powertrain.mass_kg), "bench file (weighed)"
    unb = doc.get("unbalance")
    unbalance = None
    if unb and unb.get("mr_kgm") and unb["mr_kgm"].get("value"):
        ref = np.asarray(bench.engine.reference_point_m, float)
        point = np.asarray(unb.get("point_m", ref), float)
        # the estimator places the unbalance on the crank axis: keep its axial position
        axial = float((point - ref) @ np.asarray(bench.engine.crank_axis, float))
        unbalance = Unbalance(
            float(unb["mr_kgm"]["value"]), math.radians(float(unb["angle_deg"]["value"])), axial
        )
    offset = doc.get("crank_offset_deg")
    half = doc.get("half_order") or {}
    return EstimatedProperties(
        mass=mass,
        mass_source=source,
        cog=np.asarray(doc["cog_m"]["value"], float),
        inertia=inertia,
        unbalance=unbalance,
        crank_offset_rad=math.radians(float(offset["value"])) if offset else 0.0,
        half_order_sign=int(half.get("half_order_sign", 1)),
    )


def resim_model(bench: config.Bench, props: EstimatedProperties) -> BenchModel:
    """The bench's mounts, engine and nominal sensors around the estimated body."""
    extra = (props.unbalance,) if props.unbalance is not None else ()
    engine = build_engine(bench.engine, gas_model(bench.gas), extra)
    mounts = tuple(
        Mount(
            m.name,
            np.array(m.position_m),
            np.array(m.axes),
            np.array(m.stiffness_n_per_m),
            m.loss_factor,
        )
        for m in bench.mounts
    )
    sensors = tuple(
        Sensor(s.name, np.array(s.position_m), np.array(s.axes), tuple(s.channels))
        for s in bench.sensors
    )
    return BenchModel(props.body, mounts, engine, sensors)


def rigid_motion(
    model: BenchModel, rpm: npt.ArrayLike, orders: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration of the cog and angular acceleration per speed and order.

    Returns
    -------
    gamma_g : (n_rpm, n_o, 3) complex m/s^2.
    omega_dot : (n_rpm, n_o, 3) complex rad/s^2.
    """
    h = np.atleast_1d(np.asarray(orders, float))
    omega = rpm_to_omega(np.atleast_1d(np.asarray(rpm, float)))
    f1, m1 = model.engine.unit_inertia_orders(h, about=model.body.cog)
    fg, mg = model.engine.gas_excitation(h)
    load_w2, load_0 = np.hstack([f1, m1]), np.hstack([fg, mg])
    q = model.mounted.response_sweep(omega, h, load_w2, load_0)  # (n, o, 6) [u_G; theta]
    acc = -((omega[:, None] * h) ** 2)[..., None] * q
    return acc[..., :3], acc[..., 3:]


def predict(
    model: BenchModel, rpm: npt.ArrayLike, orders: npt.ArrayLike, crank_offset_rad: float = 0.0
) -> np.ndarray:
    """(n_rpm, n_o, n_ch) complex m/s^2: the channels as the tracker would measure them.

    The crank reference offset turns order ``h`` by ``exp(i h d)`` (a late reference
    makes every order lead by ``h d``).
    """
    h = np.atleast_1d(np.asarray(orders, float))
    amps = model.channel_amplitudes(rpm, h)
    return amps * np.exp(1j * h * crank_offset_rad)[None, :, None]


def tolerance_sigma(
    model: BenchModel, rpm: npt.ArrayLike, orders: npt.ArrayLike, tol: Tolerances
) -> np.ndarray:
    """(n_rpm, n_o, n_ch) relative 1-sigma reading error from the declared sensor tolerances.

    See the module docstring: ``sqrt(g^2 |a_n|^2 + alpha^2 ||n x a||^2 + p^2 ||n x Omega'||^2) / |a_n|``.
    """
    gamma_g, omega_dot = rigid_motion(model, rpm, orders)
    arm = model.channel_positions - model.body.cog  # (ch, 3)
    n = model.channel_directions
    a = gamma_g[..., None, :] + np.cross(omega_dot[..., None, :], arm)  # (r, o, ch, 3)
    a_n = np.einsum("roci,ci->roc", a, n)
    across = np.sum(np.abs(np.cross(n, a)) ** 2, axis=-1)
    shift = np.sum(np.abs(np.cross(n, omega_dot[..., None, :])) ** 2, axis=-1)
    var = (
        tol.gain_rel**2 * np.abs(a_n) ** 2
        + tol.alignment_rad**2 * across
        + tol.position_m**2 * shift
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(var) / np.abs(a_n)


def resolve_half_orders(
    amplitudes: np.ndarray, orders: npt.ArrayLike, ambiguous: np.ndarray, sign: int
) -> np.ndarray:
    """Measured amplitudes with the half orders of ambiguous frames turned the estimator's way.

    Without a 720 deg reference the tracker sees half orders through ``phi`` or
    ``phi + 360 deg`` (sign unknown); the estimator chose ``sign``.

    Parameters
    ----------
    amplitudes : (n, n_o, n_ch) complex.
    ambiguous : (n,) bool, frames flagged ``cycle_ambiguous``.
    sign : +1 or -1.
    """
    out = np.array(amplitudes, dtype=complex, copy=True)
    if sign == -1:
        h = np.asarray(orders, float)
        half = (np.rint(2 * h).astype(int) % 2) == 1
        out[np.ix_(np.asarray(ambiguous, bool), half)] *= -1
    return out


@dataclass(frozen=True)
class ResimCheck:
    """Re-simulated against measured order amplitudes.

    Attributes
    ----------
    rpm : (n,) frame speeds, rev/min.
    orders : (n_o,); channels : (n_ch,) names.
    measured, predicted : (n, n_o, n_ch) complex m/s^2 (NaN where not measured).
    diff_db, diff_deg : (n, n_o, n_ch) ``pred / meas`` in dB and degrees (wrapped to +-180).
    mass_line : (n, n_o) bool, the frames where the estimator used the order.
    sigma_rel : (n, n_o, n_ch) relative reading error from the sensor tolerances (1 sigma).
    level_db : (n_o, n_ch) mean measured level over the mass line, dB re the order's strongest channel.
    median_db, p95_db, median_deg, p95_deg : (n_o, n_ch) over the mass-line frames
        (median of the signed difference, 95th percentile of its absolute value).
    tolerance_rel : (n_o, n_ch) median of ``sigma_rel`` over the mass-line frames.
    assessable : (n_o, n_ch) bool, not tolerance-limited (and measured on the mass line).
    limit_db, limit_deg : the verdict's limits.
    """

    rpm: np.ndarray
    orders: tuple[float, ...]
    channels: tuple[str, ...]
    measured: np.ndarray
    predicted: np.ndarray
    diff_db: np.ndarray
    diff_deg: np.ndarray
    mass_line: np.ndarray
    sigma_rel: np.ndarray
    level_db: np.ndarray
    median_db: np.ndarray
    p95_db: np.ndarray
    median_deg: np.ndarray
    p95_deg: np.ndarray
    tolerance_rel: np.ndarray
    assessable: np.ndarray
    limit_db: float = LIMIT_DB
    limit_deg: float = LIMIT_DEG

    @property
    def worst_db(self) -> float:
        """Largest 95th-percentile |dB| over the assessable channels (NaN when none)."""
        return _nanmax(self.p95_db[self.assessable])

    @property
    def worst_deg(self) -> float:
        return _nanmax(self.p95_deg[self.assessable])

    def within(self, k: int, j: int) -> bool:
        """Order ``k``, channel ``j`` is within both limits (whether or not it is judged)."""
        return bool(self.p95_db[k, j] < self.limit_db and self.p95_deg[k, j] < self.limit_deg)

    @property
    def passed(self) -> bool | None:
        """Within both limits on every assessable channel; None when nothing could be judged."""
        if not np.any(self.assessable):
            return None
        return bool(self.worst_db < self.limit_db and self.worst_deg < self.limit_deg)

    def mass_line_rpm(self, k: int) -> tuple[float, float] | None:
        """Lowest and highest frame speed where order ``orders[k]`` was on the mass line."""
        m = self.mass_line[:, k]
        return (float(self.rpm[m].min()), float(self.rpm[m].max())) if np.any(m) else None

    def summary(self) -> str:
        """One sentence for the report and the terminal."""
        n_ok = int(np.sum(self.assessable))
        measured = np.isfinite(self.p95_db)
        limited = int(np.sum(measured & ~self.assessable))
        off_line = int(np.sum(~measured))
        why = f"{limited} tolerance-limited" + (
            f", {off_line} never used by the estimator" if off_line else ""
        )
        if self.passed is None:
            return f"re-simulation check: no order-channel pair could be judged ({why})"
        verdict = "within" if self.passed else "NOT within"
        return (
            f"re-simulation {verdict} {self.limit_db:g} dB and {self.limit_deg:g} deg of the measured "
            f"order amplitudes over the mass-line range: worst 95th percentile {self.worst_db:.2f} dB "
            f"and {self.worst_deg:.2f} deg on the {n_ok} judged of {self.assessable.size} "
            f"order-channel pairs ({why}; paper: 1 dB and 10 deg)"
        )


def _nanmax(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(x.max()) if x.size else float("nan")


def compare(
    rpm: npt.ArrayLike,
    orders: tuple[float, ...],
    channels: tuple[str, ...],
    measured: np.ndarray,
    predicted: np.ndarray,
    mass_line: np.ndarray,
    sigma_rel: np.ndarray,
    limit_db: float = LIMIT_DB,
    limit_deg: float = LIMIT_DEG,
) -> ResimCheck:
    """Differences and their statistics over the mass-line frames (pure; see :class:`ResimCheck`)."""
    meas = np.asarray(measured, complex)
    pred = np.asarray(predicted, complex)
    mass_line = np.asarray(mass_line, bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = pred / meas
        diff_db = 20.0 * np.log10(np.abs(ratio))
    diff_deg = np.degrees(np.angle(ratio))
    diff_deg[~np.isfinite(ratio)] = np.nan
    n_o, n_ch = meas.shape[1:]
    level = np.full((n_o, n_ch), np.nan)
    stats = {k: np.full((n_o, n_ch), np.nan) for k in ("mdb", "pdb", "mdeg", "pdeg", "sig")}
    for k in range(n_o):
        m = mass_line[:, k]
        if not np.any(m):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            mean_amp = np.sqrt(np.nanmean(np.abs(meas[m, k, :]) ** 2, axis=0))
            level[k] = 20.0 * np.log10(mean_amp / np.nanmax(mean_amp))
        for j in range(n_ch):
            d_db, d_deg = diff_db[m, k, j], diff_deg[m, k, j]
            ok = np.isfinite(d_db) & np.isfinite(d_deg)
            if not np.any(ok):
                continue
            stats["mdb"][k, j] = np.median(d_db[ok])
            stats["pdb"][k, j] = np.percentile(np.abs(d_db[ok]), 95)
            stats["mdeg"][k, j] = np.median(d_deg[ok])
            stats["pdeg"][k, j] = np.percentile(np.abs(d_deg[ok]), 95)
            stats["sig"][k, j] = np.median(sigma_rel[m, k, j][ok])
    limit_rel = 10 ** (limit_db / 20.0) - 1.0
    assessable = np.isfinite(stats["pdb"]) & (stats["sig"] < limit_rel)
    return ResimCheck(
        rpm=np.asarray(rpm, float),
        orders=tuple(float(h) for h in orders),
        channels=tuple(channels),
        measured=meas,
        predicted=pred,
        diff_db=diff_db,
        diff_deg=diff_deg,
        mass_line=mass_line,
        sigma_rel=np.asarray(sigma_rel, float),
        level_db=level,
        median_db=stats["mdb"],
        p95_db=stats["pdb"],
        median_deg=stats["mdeg"],
        p95_deg=stats["pdeg"],
        tolerance_rel=stats["sig"],
        assessable=assessable,
        limit_db=limit_db,
        limit_deg=limit_deg,
    )


def align_channels(
    amplitudes: np.ndarray, frame_channels: tuple[str, ...], channels: tuple[str, ...]
) -> np.ndarray:
    """(n, n_o, len(channels)) amplitudes in ``channels`` order; NaN for a channel not recorded."""
    out = np.full((*amplitudes.shape[:2], len(channels)), np.nan + 0j)
    index = {c: i for i, c in enumerate(frame_channels)}
    for j, c in enumerate(channels):
        if c in index:
            out[..., j] = amplitudes[..., index[c]]
    return out


def resim_check(
    bench: config.Bench,
    doc: dict[str, Any],
    rpm: npt.ArrayLike,
    orders: tuple[float, ...],
    frame_channels: tuple[str, ...],
    amplitudes: np.ndarray,
    ambiguous: np.ndarray,
    mass_line: np.ndarray,
    tol: Tolerances | None = None,
    limit_db: float = LIMIT_DB,
    limit_deg: float = LIMIT_DEG,
) -> ResimCheck:
    """The whole check for recorded frames.

    Parameters
    ----------
    bench : the bench file of the run (mounts, engine, sensors).
    doc : the result document (the estimate).
    rpm : (n,) frame speeds; orders : the tracked orders; frame_channels : the frames' channels.
    amplitudes : (n, n_o, n_frame_ch) complex measured amplitudes (NaN where not valid).
    ambiguous : (n,) bool, frames without a 720 deg reference.
    mass_line : (n, n_o) bool, the orders the estimator used in each frame.
    tol : declared sensor tolerances (default: the bench file's ``[estimator]`` ones).
    """
    props = estimated_properties(doc, bench)
    model = resim_model(bench, props)
    if tol is None:
        s = bench.estimator
        tol = Tolerances(
            s.gain_tolerance_pct / 100.0,
            math.radians(s.alignment_tolerance_deg),
            s.position_tolerance_m,
        )
    rpm = np.asarray(rpm, float)
    channels = model.channel_names
    meas = resolve_half_orders(
        align_channels(np.asarray(amplitudes, complex), frame_channels, channels),
        orders,
        ambiguous,
        props.half_order_sign,
    )
    pred = predict(model, rpm, orders, props.crank_offset_rad)
    sigma = tolerance_sigma(model, rpm, orders, tol)
    return compare(rpm, orders, channels, meas, pred, mass_line, sigma, limit_db, limit_deg)
