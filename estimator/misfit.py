"""Where the equations of motion misfit: which order and equation, and what input it points to.

The fit's chi-square per degree of freedom (``rss / dof`` of the whitened rows)
is about 1 when the model holds and the noise is what the rigid fits measured
(realistic i3: 1.0-1.1). The model misfits when it is far above 1
(``CHI2_LIMIT``) and the misfit is more than the dsp's deterministic floor, a
share ``SHARE_LIMIT`` of the rows' sum of squares: noise-free, with no noise
to compare with, the chi-square grows without bound (6e5 on a correct 10 s
sweep) while that share stays at 2e-9. Measured on the i3, 12 s sweeps: an
engine burning 20 % more than [gas] says, noise-free chi2 1e9 / share 5e-6,
at 40 dB chi2 3.5 (below the limit: intervals widened by the variance factor,
not flagged); 300 % more: 5e10 / 3e-4; a 1 g m unbalance 80 mm off the
reference point: 1e10 / 5e-5. Then the result is marked inconsistent and the
order and equation whose rows misfit most are named, with the bench-file
inputs that enter that equation.

The streaming state keeps only sums, so the rows of a sample of frames spread
over the sweep are kept (at most ``CAPACITY``; when full, every other one is
dropped and only every other later frame is added, as
:mod:`estimator.channel_noise` does) and their residuals are evaluated at the
final estimate. Rows are whitened through a lower-triangular factor, so row j
is equation j given the ones before it: the attribution is to that equation.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimator.channel_noise import ThinnedSample

CHI2_LIMIT = 10.0
SHARE_LIMIT = 1e-7
CAPACITY = 128
# the 12 rows of an order: [force x, y, z; moment x, y, z] (bench frame), real then imaginary
EQUATIONS = ("force x", "force y", "force z", "moment x", "moment y", "moment z")


def misfits(rss: float, dof: float, yty: float) -> bool:
    """Whether a fit's residual ``rss`` (whitened, ``dof`` degrees of freedom, ``yty``
    the rows' sum of squares) is a model misfit rather than noise or the dsp's floor."""
    return dof > 0 and rss / dof > CHI2_LIMIT and rss > SHARE_LIMIT * yty


def likely_inputs(order: float, equation: str, crank_axis: np.ndarray) -> str:
    """The bench-file inputs that enter that equation of that order most."""
    if equation.startswith("force"):
        inputs = "[powertrain] mass and cog, [mounts] stiffness, reciprocating masses"
        if order == 1.0:
            inputs += ", residual unbalance"
        return inputs
    axis = "xyz".index(equation[-1])
    if abs(float(crank_axis[axis])) > 0.9:  # the roll equation: the gas torque drives it
        inputs = "[gas] (or the pressure channel), crank spin inertia, [tacho] phase reference"
    else:  # a wrong roll moment leaks here through the fitted products of inertia
        inputs = "[mounts] stiffness, reciprocating masses, [gas], sensor positions"
    if 2 * order % 2 == 1:
        inputs += " (a half order: check the 720 deg phase reference)"
    return inputs


def _copied(orders: np.ndarray, H: np.ndarray, y: np.ndarray, at: slice) -> tuple[np.ndarray, ...]:
    """A kept frame's rows ``at``, copied (views would keep the whole flush batch alive)."""
    return np.array(orders[at], float), H[at].copy(), y[at].copy()


class MisfitSample:
    """Rows of a sample of used frames, per half-order sign hypothesis."""

    def __init__(self) -> None:
        self._rows: dict[int, ThinnedSample] = {}

    def add_frames(
        self, sign: int, orders: np.ndarray, H: np.ndarray, y: np.ndarray, bounds: np.ndarray
    ) -> None:
        """Consecutive frames' whitened rows in stream order: frame f's are
        ``H[bounds[f]:bounds[f + 1]]`` (p, 12, n), ``orders`` (p,) and ``y`` (p, 12) alike.
        The kept frames' rows are cut and copied: views would keep the whole flush batch
        alive."""
        kept = self._rows.get(sign)
        if kept is None:  # (not setdefault: that would build a sample per call)
            kept = self._rows[sign] = ThinnedSample(CAPACITY)
        edges = bounds.tolist()
        kept.add_made_many(
            len(edges) - 1, lambda f: _copied(orders, H, y, slice(edges[f], edges[f + 1]))
        )

    def copy(self) -> MisfitSample:
        """An independent copy (the samples are copied, their rows shared: never changed)."""
        out = MisfitSample()
        out._rows = {sign: rows.copy() for sign, rows in self._rows.items()}
        return out

    def copy_sign(self, src: int, dst: int) -> None:
        """Start hypothesis ``dst`` from ``src``'s sample (the hypotheses split)."""
        self._rows[dst] = self._rows[src].copy() if src in self._rows else ThinnedSample(CAPACITY)

    def worst(self, sign: int, theta: np.ndarray) -> dict[str, Any] | None:
        """The order and equation with the largest mean squared whitened residual at
        ``theta`` (n,), its share of the sample's residual, and the rows' mean square."""
        rows = self._rows[sign].items if sign in self._rows else []
        if not rows:
            return None
        n = len(theta)
        orders = np.concatenate([o for o, _, _ in rows])
        r = np.concatenate([y - H[:, :, :n] @ theta for _, H, y in rows])  # (P, 12)
        r2 = r[:, :6] ** 2 + r[:, 6:] ** 2  # (P, 6): both parts of each equation
        total = float(np.sum(r2))
        if not total > 0:
            return None
        best: tuple[float, float, int] | None = None
        for h in np.unique(orders):
            per_eq = np.sum(r2[orders == h], axis=0)
            j = int(np.argmax(per_eq))
            if best is None or per_eq[j] > best[0]:
                best = (float(per_eq[j]), float(h), j)
        assert best is not None
        ss, h, j = best
        return {
            "order": h,
            "equation": EQUATIONS[j],
            "share": ss / total,
            "chi2_per_row": float(ss / (2 * np.sum(orders == h))),
        }


# A residual unbalance off the reference point misfits every order (the inertia bends
# to absorb its order-1 moment): on the i3 (1 g m, 80 mm) the worst rows were H2's.
PINNED_UNBALANCE_HINT = (
    "; or a residual unbalance off the reference point ([estimator] unbalance_location = true)"
)


def misfit_report(
    sample: MisfitSample,
    sign: int,
    theta: np.ndarray,
    chi2_per_dof: float,
    crank_axis: np.ndarray,
    unbalance_pinned: bool = False,
) -> dict[str, Any]:
    """Where the fit misfits most at ``theta`` (the rows of ``sign``'s hypothesis in
    ``sample``), with the inputs most likely wrong (``unbalance_pinned``: the residual
    unbalance is estimated at the reference point, so its location is one of them)."""
    worst = sample.worst(sign, theta) or {}
    if worst:
        worst["likely_inputs"] = likely_inputs(worst["order"], worst["equation"], crank_axis)
        if unbalance_pinned:
            worst["likely_inputs"] += PINNED_UNBALANCE_HINT
    return {"chi2_per_dof": chi2_per_dof, "limit": CHI2_LIMIT, **worst}
