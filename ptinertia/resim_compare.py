"""Re-simulated against measured order amplitudes: differences, statistics, verdict.

Differences are ``pred / meas``: ``20 log10 |pred / meas|`` dB and ``arg(pred / meas)``
deg, so +1 dB means the model is 1 dB above the measurement (:mod:`ptinertia.resim`
builds both sides).

The verdict uses the 95th percentile over the mass-line frames (the frames whose
order the estimator used: above the rigid-body modes, rigid) of the absolute
difference, per order and channel; the median is the systematic part. A channel
whose declared sensor tolerances alone exceed the amplitude limit is shown but not
judged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

LIMIT_DB = 0.5
LIMIT_DEG = 5.0


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
