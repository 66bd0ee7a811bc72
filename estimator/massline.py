"""Modal mass-line method: mass, cog and inertia from accelerance FRFs (paper eqs. 9-13).

Above the suspension modes and below the first elastic mode, a unit force
along ``f`` at ``A`` gives a rigid body the accelerations (eqs. 11-12)::

    gamma_G = f / m,   Omega' = I^-1 (GA x f),   gamma_B = gamma_G + Omega' x GB

so the accelerance from force ``(A, f)`` to a channel along ``d`` at ``B`` is
the constant ``d . f / m + (GB x d) . I^-1 (GA x f)`` (eq. 13): the mass line.
In the matrix form used here, ``A0 = T_ch M_G^-1 T_f^T`` with rows
``T = [d, GP x d]`` and ``M_G = blockdiag(m 1, I)``.

Real test articles hang on a soft suspension and have elastic modes, so in
the band each FRF is fitted as (power series about the band centre ``w_c``)::

    H(w) = A0 + sum_{k<0} R_k (w / w_c)^{2k} + sum_{k>0} E_k (w / w_c)^{2k}

``A0`` real (the rigid body is undamped), ``R_k``, ``E_k`` complex. The
``k = -1`` term is the suspension's residual stiffness: for a suspension
``K``, ``-w^2 T (K - w^2 M)^-1 T^T = T M^-1 T^T + T M^-1 K M^-1 T^T / w^2 + ...``;
``k = +1`` is the elastic modes' residual flexibility
(``-w^2 phi phi^T / (m_e w_e^2)`` below ``w_e``). ``k = -2`` and ``k = +2``
are added when a pooled F-test over all FRFs says the data need them (modes
close to the band). This is the mass-line analogue of the in-situ
estimator's suspension term: without it a suspension at 5 Hz biases a band
starting at 15 Hz by several per cent.

Then ``m``, ``G`` and the six inertia terms are fitted to all ``A0`` at once
(weighted Gauss-Newton, complex-step Jacobian), starting from the linear
two-step solution (rigid motion per excitation, then eq. 12 linear in
``1/m``, ``G``, ``I``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy import stats
from scipy.signal import find_peaks

from estimator.equations import inertia_columns
from powertrain.errors import PhysicsError
from powertrain.rigidbody import consistency_problems, inertia_matrix, rotation_matrix, skew
from powertrain.sensors import rigid_channel_matrix

PARAMETERS = ("mass", "Gx", "Gy", "Gz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
#: band edges: this many times the highest suspension mode, this fraction of the elastic mode
LOWER_MARGIN = 3.0
UPPER_MARGIN = 2.5
#: a band is refused when the mass-line model leaves more than this share of the FRFs unexplained
MAX_MISFIT = 0.10
#: ... or when the residual terms reach this share of the mass line within the band
MAX_RESIDUAL_SHARE = 0.5
#: ... or when the mass-line constants are further than this from one rigid body (relative rms)
MAX_RIGID_MISFIT = 0.05
#: significance of the F-test that adds the w^-4 / w^4 terms
F_TEST_ALPHA = 1e-3


class MassLineError(PhysicsError):
    """FRFs from which no mass line (or no rigid body) can be read; the message says why."""


@dataclass(frozen=True)
class FrfGeometry:
    """Where the responses and the forces are.

    Attributes
    ----------
    channel_positions : (n_ch, 3) m, bench frame.
    channel_directions : (n_ch, 3) unit measuring axes.
    force_positions : (n_e, 3) m, excitation points.
    force_directions : (n_e, 3) unit force directions.
    channel_names, excitation_names : labels.
    channel_sensor : (n_ch,) int, which sensor each channel belongs to (moves and turns together).
    """

    channel_positions: np.ndarray
    channel_directions: np.ndarray
    force_positions: np.ndarray
    force_directions: np.ndarray
    channel_names: tuple[str, ...] = ()
    excitation_names: tuple[str, ...] = ()
    channel_sensor: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    def __post_init__(self) -> None:
        for name in (
            "channel_positions",
            "channel_directions",
            "force_positions",
            "force_directions",
        ):
            a = np.asarray(getattr(self, name), dtype=float).reshape(-1, 3)
            object.__setattr__(self, name, a)
        n_ch, n_e = len(self.channel_positions), len(self.force_positions)
        if self.channel_directions.shape != (n_ch, 3) or self.force_directions.shape != (n_e, 3):
            raise MassLineError(
                f"geometry: {n_ch} channel positions vs {len(self.channel_directions)} directions, "
                f"{n_e} force positions vs {len(self.force_directions)} directions"
            )
        for name in ("channel_directions", "force_directions"):
            a = getattr(self, name)
            object.__setattr__(self, name, a / np.linalg.norm(a, axis=1)[:, None])
        if not self.channel_names:
            object.__setattr__(self, "channel_names", tuple(f"ch{i + 1}" for i in range(n_ch)))
        if not self.excitation_names:
            object.__setattr__(self, "excitation_names", tuple(f"exc{i + 1}" for i in range(n_e)))
        sensor = np.asarray(self.channel_sensor, dtype=int)
        if sensor.size == 0:
            sensor = np.arange(n_ch)
        object.__setattr__(self, "channel_sensor", sensor)


def mass_line_accelerance(
    mass: complex,
    cog: npt.ArrayLike,
    inertia: npt.ArrayLike,
    geometry: FrfGeometry,
) -> np.ndarray:
    """(n_ch, n_e) m/s^2/N, the rigid body's mass-line accelerances (eq. 13).

    Works with complex parameters (for complex-step derivatives).
    """
    g = np.asarray(cog)
    t_ch = np.hstack(
        [
            geometry.channel_directions,
            np.cross(geometry.channel_positions - g, geometry.channel_directions),
        ]
    )
    t_f = np.hstack(
        [
            geometry.force_directions,
            np.cross(geometry.force_positions - g, geometry.force_directions),
        ]
    )
    # T_ch M_G^-1 T_f^T with M_G = blockdiag(m 1, I)
    trans = t_ch[:, :3] @ t_f[:, :3].T / mass
    rot = t_ch[:, 3:] @ np.linalg.solve(np.asarray(inertia), t_f[:, 3:].T)
    return trans + rot


# -- band -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Band:
    """The mass-line band and how it was chosen.

    Attributes
    ----------
    low_hz, high_hz : the band.
    resonances_hz : peaks of the mean normalised FRF magnitude.
    chosen : "auto" or "user".
    """

    low_hz: float
    high_hz: float
    resonances_hz: tuple[float, ...]
    chosen: str


def find_resonances(frequency: np.ndarray, h: np.ndarray, prominence: float = 0.1) -> np.ndarray:
    """Hz, peaks of ``log10 mean(|H| / median|H|)`` over all FRFs (prominence in decades)."""
    mag = np.abs(h.reshape(len(frequency), -1))
    ref = np.median(mag, axis=0)
    ref = np.where(ref > 0, ref, 1.0)
    indicator = np.log10(np.maximum(np.mean(mag / ref, axis=1), 1e-300))
    peaks, _ = find_peaks(indicator, prominence=prominence)
    return np.asarray(frequency)[peaks]


def choose_band(
    frequency: np.ndarray,
    h: np.ndarray,
    lower_margin: float = LOWER_MARGIN,
    upper_margin: float = UPPER_MARGIN,
) -> Band:
    """The mass-line band: between the suspension modes and the first elastic mode.

    Resonances split the frequency axis into gaps; each gap gives the band
    ``[lower_margin f_below, f_above / upper_margin]`` (no margin at the ends
    of the data). The first gap, from below, whose band spans a factor 2 is
    the mass line (it lies above the rigid-body modes and below the first
    elastic one); failing that, the widest.

    Raises
    ------
    MassLineError
        No gap spans a factor 1.5.
    """
    f = np.asarray(frequency, dtype=float)
    res = find_resonances(f, h)
    edges = [(float(f[0]), False), *((float(r), True) for r in res), (float(f[-1]), False)]
    bands = []
    for (a, a_res), (b, b_res) in itertools.pairwise(edges):
        lo = a * lower_margin if a_res else a
        hi = b / upper_margin if b_res else b
        bands.append((lo, hi))
    good = [b for b in bands if b[1] >= 2.0 * b[0]]
    lo, hi = good[0] if good else max(bands, key=lambda b: b[1] / max(b[0], 1e-300))
    if not hi >= 1.5 * lo:
        shown = ", ".join(f"{r:.4g}" for r in res)
        raise MassLineError(
            f"no mass line found between the resonances at [{shown}] Hz (data {f[0]:.4g} to "
            f"{f[-1]:.4g} Hz): no gap spans {lower_margin:g} x the mode below to 1/{upper_margin:g} "
            "of the mode above; give the band explicitly"
        )
    return Band(float(lo), float(hi), tuple(float(r) for r in res), "auto")


# -- mass-line fit ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class MassLineFit:
    """The per-FRF mass-line fit in one band.

    Attributes
    ----------
    a0 : (n_ch, n_e) m/s^2/N, the mass-line constants.
    a0_std : (n_ch, n_e), their 1-sigma (from each FRF's scatter about the fit).
    powers : the powers ``k`` of ``(w / w_c)^2k`` fitted besides the constant.
    misfit : pooled rms of the residual over the rms of the FRFs in the band.
    residual_share : pooled ratio of the largest residual terms in the band to ``A0``.
    lines : number of frequency lines in the band.
    """

    a0: np.ndarray
    a0_std: np.ndarray
    powers: tuple[int, ...]
    misfit: float
    residual_share: float
    lines: int


def _design(w: np.ndarray, powers: tuple[int, ...]) -> np.ndarray:
    """(2n, 1 + 2 len(powers)) real design for ``[Re H; Im H]``: A0 real, the others complex."""
    n = len(w)
    wc = math.sqrt(w[0] * w[-1])
    x = np.zeros((2 * n, 1 + 2 * len(powers)))
    x[:n, 0] = 1.0
    for j, k in enumerate(powers):
        col = (w / wc) ** (2 * k)  # scaled about the band centre: columns of order 1
        x[:n, 1 + 2 * j] = col
        x[n:, 2 + 2 * j] = col
    return x


def _weighted_fit(
    x: np.ndarray, y: np.ndarray, iterations: int = 3
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-FRF fit with weights ``1 / |model|^2`` (noise proportional to the FRF level).

    Parameters
    ----------
    x : (2n, p) design.
    y : (n_frf, 2n) data ``[Re; Im]``.

    Returns
    -------
    coef (n_frf, p), cov_unit (n_frf, p, p), weighted residual sum of squares (n_frf,),
    residual (n_frf, 2n) unweighted.
    """
    n = x.shape[0] // 2
    wt = np.ones_like(y)
    for _ in range(iterations):
        normal = np.einsum("fk,ki,kj->fij", wt, x, x)
        rhs = np.einsum("fk,ki,fk->fi", wt, x, y)
        coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
        model = coef @ x.T
        mag2 = model[:, :n] ** 2 + model[:, n:] ** 2
        # An anti-resonance in the band must not take all the weight.
        floor = 1e-6 * np.mean(mag2, axis=1, keepdims=True) + 1e-300
        w_line = 1.0 / np.maximum(mag2, floor)
        wt = np.hstack([w_line, w_line])
    normal = np.einsum("fk,ki,kj->fij", wt, x, x)
    rhs = np.einsum("fk,ki,fk->fi", wt, x, y)
    coef = np.linalg.solve(normal, rhs[..., None])[..., 0]
    resid = y - coef @ x.T
    rss = np.sum(wt * resid**2, axis=1)
    return coef, np.linalg.inv(normal), rss, resid


def fit_mass_line(
    frequency: npt.ArrayLike,
    h: npt.ArrayLike,
    band: tuple[float, float],
    residual_stiffness: bool = True,
    powers: tuple[int, ...] | None = None,
) -> MassLineFit:
    """Fit every FRF in ``band`` with the mass-line model (module docstring).

    Parameters
    ----------
    frequency : (n_f,) Hz.
    h : (n_f, n_ch, n_e) complex accelerance, m/s^2/N.
    band : (low, high) Hz.
    residual_stiffness : fit the suspension terms (``k < 0``); False shows their bias.
    powers : force the powers ``k``; default ``(-1, 1)`` (``(1,)`` without residual
        stiffness), growing by ``-2`` and ``+2`` when the F-test asks for them.

    Raises
    ------
    MassLineError
        Too few lines in the band, or no mass line there (see ``MAX_MISFIT``,
        ``MAX_RESIDUAL_SHARE``).
    """
    f = np.asarray(frequency, dtype=float)
    hh = np.asarray(h, dtype=complex)
    lo, hi = float(band[0]), float(band[1])
    sel = (f >= lo) & (f <= hi) & (f > 0)
    n = int(sel.sum())
    n_ch, n_e = hh.shape[1], hh.shape[2]
    if not hi > lo or n < 12:
        raise MassLineError(
            f"band {lo:.4g} to {hi:.4g} Hz holds {n} frequency lines (data {f[0]:.4g} to "
            f"{f[-1]:.4g} Hz): need at least 12"
        )
    w = 2 * np.pi * f[sel]
    y_c = hh[sel].reshape(n, -1).T  # (n_frf, n)
    y = np.hstack([y_c.real, y_c.imag])
    if powers is None:
        chosen = [-1, 1] if residual_stiffness else [1]
        optional = [-2, 2] if residual_stiffness else [2]
        coef, cov_unit, rss, resid = _weighted_fit(_design(w, tuple(chosen)), y)
        # Greedy pooled F-test: add the higher term the data call for most, while significant.
        while optional:
            best = None
            for k in optional:
                trial = tuple(sorted([*chosen, k]))
                c2, cu2, r2, re2 = _weighted_fit(_design(w, trial), y)
                extra = c2.size - coef.size
                dof2 = y.size - c2.size
                stat = ((rss.sum() - r2.sum()) / extra) / (r2.sum() / dof2)
                p = float(stats.f.sf(stat, extra, dof2))
                if p < F_TEST_ALPHA and (best is None or p < best[0]):
                    best = (p, k, c2, cu2, r2, re2)
            if best is None:
                break
            _, k, coef, cov_unit, rss, resid = best
            chosen = sorted([*chosen, k])
            optional.remove(k)
        powers = tuple(chosen)
    else:
        if not residual_stiffness:
            powers = tuple(k for k in powers if k > 0)
        coef, cov_unit, rss, resid = _weighted_fit(_design(w, tuple(powers)), y)
    p = coef.shape[1]
    s2 = rss / max(2 * n - p, 1)
    a0 = coef[:, 0]
    a0_std = np.sqrt(s2 * cov_unit[:, 0, 0])
    misfit = float(np.sqrt(np.sum(resid**2) / max(np.sum(y**2), 1e-300)))
    others = coef[:, 1:] @ _design(w, tuple(powers))[:, 1:].T
    other_peak = np.max(others[:, :n] ** 2 + others[:, n:] ** 2, axis=1)
    share = float(np.sqrt(np.sum(other_peak) / max(np.sum(a0**2), 1e-300)))
    where = f"band {lo:.4g} to {hi:.4g} Hz"
    if misfit > MAX_MISFIT:
        raise MassLineError(
            f"{where} holds no mass line: the mass-line model leaves {100 * misfit:.0f} % of the "
            f"FRFs unexplained (limit {100 * MAX_MISFIT:.0f} %), a resonance is in the band"
        )
    if share > MAX_RESIDUAL_SHARE:
        raise MassLineError(
            f"{where} holds no mass line: the suspension and elastic terms reach "
            f"{100 * share:.0f} % of the constant part (limit {100 * MAX_RESIDUAL_SHARE:.0f} %), "
            "the band is too close to the modes"
        )
    return MassLineFit(
        a0=a0.reshape(n_ch, n_e),
        a0_std=a0_std.reshape(n_ch, n_e),
        powers=tuple(powers),
        misfit=misfit,
        residual_share=share,
        lines=n,
    )


# -- rigid body from the mass line --------------------------------------------------------------------


@dataclass(frozen=True)
class MassLineTolerances:
    """Declared 1-sigma uncertainties of the set-up, propagated into the intervals (type B).

    ``force_gain`` is one calibration shared by every hit; the others are
    independent per hit, per channel or per sensor.
    """

    force_gain_rel: float = 0.0
    hit_position_m: float = 0.0
    hit_direction_rad: float = 0.0
    sensor_gain_rel: float = 0.0
    sensor_position_m: float = 0.0
    sensor_alignment_rad: float = 0.0


@dataclass(frozen=True)
class RigidBodyFit:
    """Mass, cog and inertia from the mass-line constants.

    Attributes
    ----------
    theta : (10,) ``[m, Gx, Gy, Gz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (kg, m, kg m^2).
    cov : (10, 10) random + systematic.
    cov_random, cov_systematic : (10, 10).
    variance_factor : ``max(1, chi2 / dof)`` applied to the random part.
    chi2, dof : weighted misfit of ``A0`` against the rigid body.
    rigid_misfit : relative rms misfit of ``A0``.
    iterations : Gauss-Newton steps.
    """

    theta: np.ndarray
    cov: np.ndarray
    cov_random: np.ndarray
    cov_systematic: np.ndarray
    variance_factor: float
    chi2: float
    dof: int
    rigid_misfit: float
    iterations: int

    @property
    def mass(self) -> float:
        return float(self.theta[0])

    @property
    def cog(self) -> np.ndarray:
        return self.theta[1:4].copy()

    @property
    def terms(self) -> np.ndarray:
        return self.theta[4:].copy()

    @property
    def inertia(self) -> np.ndarray:
        return inertia_matrix(*self.theta[4:])

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def _model(theta: np.ndarray, geometry: FrfGeometry) -> np.ndarray:
    m, g, t = theta[0], theta[1:4], theta[4:]
    ixx, iyy, izz, ixy, ixz, iyz = t
    inertia = np.array([[ixx, -ixy, -ixz], [-ixy, iyy, -iyz], [-ixz, -iyz, izz]])
    return mass_line_accelerance(m, g, inertia, geometry)


def _jacobian(theta: np.ndarray, geometry: FrfGeometry) -> np.ndarray:
    """(n_ch n_e, 10) by complex step: exact to rounding, no step-size trade-off."""
    cols = []
    for k in range(len(theta)):
        step = 1e-30 * max(abs(theta[k]), 1.0)
        t = theta.astype(complex)
        t[k] += 1j * step
        cols.append(_model(t, geometry).imag.ravel() / step)
    return np.array(cols).T


def linear_start(a0: np.ndarray, geometry: FrfGeometry) -> np.ndarray:
    """The linear two-step solution, ``theta`` (10,): rigid motion per hit, then eq. 12.

    Per hit (unit force ``f`` at ``a``), with ``gamma_O``, ``Omega'`` fitted about O::

        skew(Omega') G - (1/m) f = skew(Omega') O - gamma_O       (translation)
        I Omega' - skew(f) G     = a x f                          (rotation about G)

    both linear in ``(1/m, G, I)``.
    """
    o = geometry.channel_positions.mean(axis=0)
    rigid = rigid_channel_matrix(geometry.channel_positions, geometry.channel_directions, o)
    sv = np.linalg.svd(rigid, compute_uv=False)
    if len(sv) < 6 or sv[-1] < 1e-6 * sv[0]:
        raise MassLineError(
            f"the {len(rigid)} response channels cannot determine the 6 rigid-body motions: "
            "need three non-collinear triaxial sensors (or equivalent axes)"
        )
    motion, *_ = np.linalg.lstsq(rigid, a0, rcond=None)  # (6, n_e): [gamma_O; Omega'] per hit
    rows, rhs = [], []
    for e in range(a0.shape[1]):
        gam, om = motion[:3, e], motion[3:, e]
        f, a = geometry.force_directions[e], geometry.force_positions[e]
        trans = np.zeros((3, 10))
        trans[:, 0] = -f
        trans[:, 1:4] = skew(om)
        rot = np.zeros((3, 10))
        rot[:, 1:4] = -skew(f)
        rot[:, 4:] = inertia_columns(om)
        rows += [trans, rot]
        rhs += [skew(om) @ o - gam, np.cross(a, f)]
    x = np.vstack(rows)
    y = np.concatenate(rhs)
    scale = np.maximum(np.linalg.norm(x, axis=0), 1e-300)
    sol, *_ = np.linalg.lstsq(x / scale, y, rcond=None)
    sol = sol / scale
    if not sol[0] > 0:
        raise MassLineError(
            f"the mass-line accelerances give 1/m = {sol[0]:.4g} 1/kg (not positive): check the "
            "force directions (sign of the reference direction) and the FRF units"
        )
    return np.concatenate([[1.0 / sol[0]], sol[1:]])


def _perturbations(
    geometry: FrfGeometry, tol: MassLineTolerances
) -> list[tuple[float, Callable[[float], FrfGeometry]]]:
    """(sigma, geometry as a function of the perturbation) for each uncertain input."""
    out: list[tuple[float, Callable[[float], FrfGeometry]]] = []

    def replace(**kw: np.ndarray) -> FrfGeometry:
        args = {
            "channel_positions": geometry.channel_positions,
            "channel_directions": geometry.channel_directions,
            "force_positions": geometry.force_positions,
            "force_directions": geometry.force_directions,
            "channel_names": geometry.channel_names,
            "excitation_names": geometry.excitation_names,
            "channel_sensor": geometry.channel_sensor,
        }
        args.update(kw)
        return FrfGeometry(**args)  # type: ignore[arg-type]

    n_e = len(geometry.force_positions)
    if tol.hit_position_m > 0:
        for e in range(n_e):
            for axis in range(3):

                def fp(x: float, e: int = e, axis: int = axis) -> FrfGeometry:
                    p = geometry.force_positions.copy()
                    p[e, axis] += x
                    return replace(force_positions=p)

                out.append((tol.hit_position_m, fp))
    if tol.hit_direction_rad > 0:
        for e in range(n_e):
            f = geometry.force_directions[e]
            helper = np.eye(3)[int(np.argmin(np.abs(f)))]
            perp1 = np.cross(f, helper)
            perp1 /= np.linalg.norm(perp1)
            for turn in (perp1, np.cross(f, perp1)):

                def fd(x: float, e: int = e, turn: np.ndarray = turn) -> FrfGeometry:
                    d = geometry.force_directions.copy()
                    d[e] = rotation_matrix(turn, x) @ d[e]
                    return replace(force_directions=d)

                out.append((tol.hit_direction_rad, fd))
    sensors = np.unique(geometry.channel_sensor)
    if tol.sensor_position_m > 0:
        for s in sensors:
            for axis in range(3):

                def sp(x: float, s: int = int(s), axis: int = axis) -> FrfGeometry:
                    p = geometry.channel_positions.copy()
                    p[geometry.channel_sensor == s, axis] += x
                    return replace(channel_positions=p)

                out.append((tol.sensor_position_m, sp))
    if tol.sensor_alignment_rad > 0:
        for s in sensors:
            for turn in np.eye(3):

                def sa(x: float, s: int = int(s), turn: np.ndarray = turn) -> FrfGeometry:
                    d = geometry.channel_directions.copy()
                    mask = geometry.channel_sensor == s
                    d[mask] = d[mask] @ rotation_matrix(turn, x).T
                    return replace(channel_directions=d)

                out.append((tol.sensor_alignment_rad, sa))
    return out


def rigid_body_from_mass_line(
    a0: npt.ArrayLike,
    a0_std: npt.ArrayLike,
    geometry: FrfGeometry,
    tolerances: MassLineTolerances | None = None,
    max_iterations: int = 50,
) -> RigidBodyFit:
    """Mass, cog and inertia fitted to the mass-line constants of all hits at once (eq. 13).

    Weighted Gauss-Newton on ``A0 = T_ch M_G^-1 T_f^T`` from :func:`linear_start`.
    Random covariance ``s^2 (J^T W J)^-1`` with ``s^2 = max(1, chi2 / dof)``;
    systematic covariance from ``tolerances`` through the sensitivity
    ``d theta / d p = -(J^T W J)^-1 J^T W d model / d p``.

    Three excitations at least: the rotation equations of two hits,
    ``I Omega'_k = GA_k x f_k``, hold for ``I + c n n^T`` too (``n`` normal to
    both angular accelerations), so two hits leave the tensor one term short
    (the paper's "two force directions" gives mass and cog, not all of ``I``).

    Raises
    ------
    MassLineError
        Fewer than 3 excitations, geometry that cannot determine the 10
        parameters, a non-physical result, or constants no rigid body explains
        (relative misfit above ``MAX_RIGID_MISFIT``).
    """
    a0 = np.asarray(a0, dtype=float)
    std = np.asarray(a0_std, dtype=float)
    tol = tolerances or MassLineTolerances()
    n_ch, n_e = a0.shape
    if a0.size < 10 or n_e < 3:
        raise MassLineError(
            f"{n_ch} channels x {n_e} excitations: need at least 3 excitations for mass, cog "
            "and inertia (two leave the tensor undetermined by c n n^T, n normal to both "
            "angular accelerations)"
        )
    floor = 1e-9 * float(np.max(np.abs(a0)))
    w = 1.0 / np.maximum(std, floor).ravel()
    theta = linear_start(a0, geometry)
    sv = np.linalg.svd(_jacobian(theta, geometry) * w[:, None], compute_uv=False)
    if sv[-1] < 1e-10 * sv[0]:
        raise MassLineError(
            f"the {n_e} excitations and {n_ch} channels cannot separate mass, cog and inertia "
            f"(condition {sv[0] / max(sv[-1], 1e-300):.3g}): the tensor needs hits whose angular "
            "accelerations span all three directions (hit at more points, in more directions)"
        )
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        r = (_model(theta, geometry).real.ravel() - a0.ravel()) * w
        jw = _jacobian(theta, geometry) * w[:, None]
        step, *_ = np.linalg.lstsq(jw, -r, rcond=None)
        theta = theta + step
        scale = np.abs(theta) + np.r_[1.0, 0.1, 0.1, 0.1, np.full(6, np.abs(theta[4:7]).max())]
        if np.all(np.abs(step) <= 1e-12 * scale):
            break
    jw = _jacobian(theta, geometry) * w[:, None]
    model = _model(theta, geometry).real
    r = (model.ravel() - a0.ravel()) * w
    dof = a0.size - len(theta)
    chi2 = float(r @ r)
    misfit = float(np.sqrt(np.sum((model - a0) ** 2) / max(np.sum(a0**2), 1e-300)))
    if misfit > MAX_RIGID_MISFIT:
        raise MassLineError(
            f"the mass-line constants are not those of one rigid body ({100 * misfit:.1f} % "
            f"misfit, limit {100 * MAX_RIGID_MISFIT:.0f} %): band above an elastic mode, or a "
            "point or direction of the set-up is wrong"
        )
    problems = consistency_problems(inertia_matrix(*theta[4:]))
    if not theta[0] > 0 or problems:
        raise MassLineError(
            f"the mass-line fit gives no physical body (mass {theta[0]:.4g} kg"
            + (f", {problems[0]}" if problems else "")
            + ")"
        )
    normal_inv = np.linalg.inv(jw.T @ jw)
    factor = max(1.0, chi2 / dof) if dof > 0 else 1.0
    cov_random = normal_inv * factor
    # Systematic part: each uncertain input moves the model; the fit follows by
    # d theta = -(J^T W J)^-1 J^T W d model.
    gain = normal_inv @ jw.T  # (10, n) maps weighted residual changes to theta
    sens = []
    for sigma, perturbed in _perturbations(geometry, tol):
        h = 1e-6
        dm = (_model(theta, perturbed(h)).real - _model(theta, perturbed(-h)).real) / (2 * h)
        sens.append(-gain @ (dm.ravel() * w) * sigma)
    if tol.force_gain_rel > 0:
        # Gauge reads (1 + g) F: every accelerance is low by (1 + g), mass and inertia high.
        sens.append(-gain @ (-model.ravel() * w) * tol.force_gain_rel)
    if tol.sensor_gain_rel > 0:
        for c in range(n_ch):
            dm = np.zeros_like(model)
            dm[c] = model[c]
            sens.append(-gain @ (dm.ravel() * w) * tol.sensor_gain_rel)
    s = np.array(sens).T if sens else np.zeros((len(theta), 0))
    cov_sys = s @ s.T
    return RigidBodyFit(
        theta=theta,
        cov=cov_random + cov_sys,
        cov_random=cov_random,
        cov_systematic=cov_sys,
        variance_factor=factor,
        chi2=chi2,
        dof=dof,
        rigid_misfit=misfit,
        iterations=iterations,
    )


@dataclass(frozen=True)
class MassLineResult:
    """Everything :func:`estimate_mass_line` found."""

    band: Band
    fit: MassLineFit
    body: RigidBodyFit
    residual_stiffness: bool


def estimate_mass_line(
    frequency: npt.ArrayLike,
    h: npt.ArrayLike,
    geometry: FrfGeometry,
    band: tuple[float, float] | None = None,
    residual_stiffness: bool = True,
    tolerances: MassLineTolerances | None = None,
) -> MassLineResult:
    """Band (automatic unless given), mass-line fit, rigid body: the whole method.

    Parameters
    ----------
    frequency : (n_f,) Hz.
    h : (n_f, n_ch, n_e) complex accelerance m/s^2/N; channel and excitation order as
        in ``geometry``.
    geometry : the points and directions.
    band : (low, high) Hz; None chooses it (:func:`choose_band`).
    residual_stiffness : fit the suspension's residual terms (default); False shows their bias.
    tolerances : declared set-up uncertainties for the intervals.
    """
    f = np.asarray(frequency, dtype=float)
    hh = np.asarray(h, dtype=complex)
    n_ch, n_e = len(geometry.channel_positions), len(geometry.force_positions)
    if hh.shape != (len(f), n_ch, n_e):
        raise MassLineError(
            f"FRFs must have shape (n_f, n_ch, n_e) = ({len(f)}, {n_ch}, {n_e}), got {hh.shape}"
        )
    if band is None:
        chosen = choose_band(f, hh)
    else:
        chosen = Band(float(band[0]), float(band[1]), tuple(find_resonances(f, hh)), "user")
    fit = fit_mass_line(f, hh, (chosen.low_hz, chosen.high_hz), residual_stiffness)
    where = f"band {chosen.low_hz:.4g} to {chosen.high_hz:.4g} Hz"
    try:
        body = rigid_body_from_mass_line(fit.a0, fit.a0_std, geometry, tolerances)
    except MassLineError as err:
        raise MassLineError(f"{where}: {err}") from None
    return MassLineResult(chosen, fit, body, residual_stiffness)
