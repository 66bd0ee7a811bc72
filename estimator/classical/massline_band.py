"""The mass line and its band: where it is, and ``A0`` fitted to every FRF in it.

The first half of the modal mass-line method (:mod:`estimator.classical.massline`): the set-up
geometry, the rigid body's mass-line accelerance (eq. 13), the band between the
suspension modes and the first elastic mode, and the per-FRF fit of the constant.
It is its own module because the band and the fit work on the FRFs alone, without
the rigid-body parameters; :class:`FrfGeometry`, :func:`mass_line_accelerance` and
:class:`MassLineError` sit here too, at the bottom of the imports
(massline -> massline_rigid -> massline_band), so all three modules share them
without a cycle.

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
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy import stats
from scipy.signal import find_peaks

from powertrain.errors import PhysicsError

#: band edges: this many times the highest suspension mode, this fraction of the elastic mode
LOWER_MARGIN = 3.0
UPPER_MARGIN = 2.5
#: a band is refused when the mass-line model leaves more than this share of the FRFs unexplained
MAX_MISFIT = 0.10
#: ... or when the residual terms reach this share of the mass line within the band
MAX_RESIDUAL_SHARE = 0.5
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
