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

The differences, their statistics and the verdict are :mod:`ptinertia.resim_compare`.
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
from powertrain.rigidbody import TERMS, RigidBody, consistency_problems
from ptinertia import config
from ptinertia.resim_compare import LIMIT_DB, LIMIT_DEG, ResimCheck, compare
from ptinertia.to_physics import build_model


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
    return build_model(bench, props.body, extra)


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
