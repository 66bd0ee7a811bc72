"""The state each half-order sign hypothesis carries, and how the residuals decide between them.

Without a 720 deg reference the sign of every half-order amplitude is unknown:
the streaming estimator keeps one :class:`Accumulator` per sign (+1 as
measured, -1 flipped) and, once the residuals leave no doubt, drops the loser
(the wrong sign turns the roll equation of H1.5 against the inertia, and the misfit is
large); the ratio of the two residuals is reported.

With a cam or pressure reference the sign is known, unless the reference is wrong: a cam
angle 360 deg off flips every half order, and the fit then turns out a negative Iyy. The
same test checks the reference: its frames carry both hypotheses too, the reference's
sign is kept unless the residuals decide (``DECIDE_RATIO``) against it, and then the
test's sign is used and the contradiction reported
(``half_order["reference_contradicted"]``).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator.rls import RlsState, rank_decision, rls_init, rls_update

# Self-calibration rows of consecutive frames, one entry a frame in each list: H (k, 2r, n),
# y (k, 2r), dr (k, 2r, n_sys) (estimator.pending_rows.RowAssembler.redundancy)
Redundancy = tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]

# The half-order sign is decided when, after this many ambiguous frames, the wrong
# hypothesis leaves this many times the weighted residual of the right one.
DECIDE_AFTER_FRAMES = 40
DECIDE_RATIO = 100.0


@dataclass
class Accumulator:
    """Information state plus the systematic-error sensitivity ``S`` (n, n_p)."""

    state: RlsState
    sens: np.ndarray

    @classmethod
    def empty(cls, n: int, n_sys: int) -> Accumulator:
        return cls(state=rls_init(n), sens=np.zeros((n, n_sys)))

    def leading(self, n: int) -> Accumulator:
        """The state of the first ``n`` parameters alone (the others not in the model)."""
        st = self.state
        return Accumulator(RlsState(st.info[:n, :n], st.vec[:n], st.yty, st.rows), self.sens[:n])

    def marginal(self, n: int, scale: np.ndarray) -> Accumulator:
        """The state of the first ``n`` parameters with the others fitted alongside.

        The Schur complement of the joint normal equations: solving it gives
        exactly the first ``n`` entries of the joint solution, and its inverse is
        their joint covariance. ``scale`` (of all parameters) sets the rank
        decision for the others.
        """
        st = self.state
        s = scale[n:]
        tail = st.info[n:, n:] * np.outer(s, s)
        evals, evecs, keep, _, _ = rank_decision(tail, 1e-10)
        inv = ((evecs[:, keep] / evals[keep]) @ evecs[:, keep].T) * np.outer(s, s)
        cross = st.info[:n, n:]
        gain = cross @ inv
        return Accumulator(
            RlsState(
                info=st.info[:n, :n] - gain @ cross.T,
                vec=st.vec[:n] - gain @ st.vec[n:],
                yty=st.yty - float(st.vec[n:] @ inv @ st.vec[n:]),
                rows=st.rows - float(np.sum(keep)),
            ),
            self.sens[:n] - gain @ self.sens[n:],
        )


def add_frame(
    acc: Accumulator,
    H: np.ndarray,
    y: np.ndarray,
    dr: np.ndarray,
    forgetting: float = 1.0,
    redundancy: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> Accumulator:
    """One frame's rows added to a sign hypothesis's state: the pure-function twin of
    the streaming estimator's per-frame update.

    Parameters
    ----------
    acc : the state before the frame.
    H : (k, 12, n) whitened rows of the frame's k used orders.
    y : (k, 12) whitened observations.
    dr : (k, 12, n_sys) the rows' sensitivity to the systematic sensor errors.
    forgetting : the RLS forgetting factor, applied to the past once per frame.
    redundancy : the frame's self-calibration rows (H (k, 2r, n), y (k, 2r), dr
        (k, 2r, n_sys)), added after the discount.
    """
    n = H.shape[-1]
    # Lambda <- lam Lambda + H^T H ;  S <- lam S + H^T dr  (rows already whitened)
    state = rls_update(acc.state, H.reshape(-1, n), y.reshape(-1), None, forgetting)
    sens = forgetting * acc.sens + _rows_t(H, n) @ dr.reshape(-1, dr.shape[-1])
    if redundancy is not None:
        Hk, yk, drk = redundancy
        state = rls_update(state, Hk.reshape(-1, n), yk.reshape(-1))
        sens = sens + _rows_t(Hk, n) @ drk.reshape(-1, drk.shape[-1])
    return Accumulator(state, sens)


def add_frames_redundant(
    acc: Accumulator,
    H: np.ndarray,
    y: np.ndarray,
    dr: np.ndarray,
    bounds: np.ndarray,
    forgetting: float,
    redundancy: Redundancy,
) -> Accumulator:
    """:func:`add_frame` for consecutive frames with self-calibration: frame f's rows are
    ``H[bounds[f]:bounds[f + 1]]``, ``y`` and ``dr`` alike; its redundancy rows are entry f
    of each of ``redundancy``'s lists (:meth:`estimator.pending_rows.RowAssembler.
    redundancy`: their row counts differ between frames that fit different channels),
    added after the discount, one frame at a time in stream order."""
    for f, (a, b) in enumerate(itertools.pairwise(bounds.tolist())):
        own = (redundancy[0][f], redundancy[1][f], redundancy[2][f])
        acc = add_frame(acc, H[a:b], y[a:b], dr[a:b], forgetting, own)
    return acc


def _rows_t(H: np.ndarray, n: int) -> np.ndarray:
    """``H^T`` of (k, 12, n) rows as rls_update forms it (``H.T * w``, w = 1: a copy),
    so that :func:`add_frames`' stacked products are the same BLAS calls.

    ``H^T dr`` is a matrix product (BLAS), not an einsum: 40 us instead of 720 us for
    a 12-frame block (n = 15, 33 systematic errors); the sums round differently from
    the einsum's by ~1e-16 relative."""
    h2 = H.reshape(-1, n)
    return h2.T * np.ones(len(h2))


def add_frames(
    acc: Accumulator,
    H: np.ndarray,
    y: np.ndarray,
    dr: np.ndarray,
    bounds: np.ndarray,
    forgetting: float = 1.0,
) -> Accumulator:
    """:func:`add_frame` for consecutive frames (no redundancy rows): frame f's rows
    are ``H[bounds[f]:bounds[f + 1]]`` (pairs, 12, n), ``y`` and ``dr`` alike.

    Each frame's products are formed as :func:`add_frame` forms them (the same
    bits), those of all frames with as many orders in one call, and added to the
    state in stream order: the per-call overhead of numpy, not the arithmetic,
    is what a frame costs at these sizes. (With ``PTINERTIA_NUMBA=1`` the streaming
    estimator's sums are :func:`estimator.compiled_sums.tail_sums`'.)
    """
    n = H.shape[-1]
    starts = np.asarray(bounds[:-1])
    sizes = np.diff(bounds)
    n_f = len(sizes)
    info, vec = np.empty((n_f, n, n)), np.empty((n_f, n))
    yty, sens = np.empty(n_f), np.empty((n_f, n, dr.shape[-1]))
    for k in sorted(set(sizes.tolist())):  # (np.unique: a dozen calls for a few sizes)
        fs = np.flatnonzero(sizes == k)
        pick = (starts[fs][:, None] + np.arange(k)).ravel()
        Hk, yk = H[pick].reshape(len(fs), 12 * k, n), y[pick].reshape(len(fs), 12 * k)
        # rls_update's H^T W H and H^T W y, W = 1 (H^T times the weights: a copy)
        Ht = Hk.transpose(0, 2, 1) * np.ones(12 * k)
        info[fs] = np.matmul(Ht, Hk)
        vec[fs] = np.matmul(Ht, yk[:, :, None])[:, :, 0]
        yty[fs] = np.sum(yk * yk, axis=1)
        sens[fs] = np.matmul(Ht, dr[pick].reshape(len(fs), 12 * k, -1))
    state, total = acc.state, acc.sens
    lam = forgetting
    if lam == 1.0:
        # lam * x is x: the frames' sums added one after the other in stream order, as
        # numpy's reduction along the first axis adds them (np.add.accumulate: a 1-d
        # np.sum would add pairwise)
        return Accumulator(
            RlsState(
                info=np.add.reduce(np.concatenate([state.info[None], info]), axis=0),
                vec=np.add.reduce(np.concatenate([state.vec[None], vec]), axis=0),
                yty=float(np.add.accumulate(np.concatenate([[state.yty], yty]))[-1]),
                rows=rows_after(state.rows, sizes, lam),
            ),
            np.add.reduce(np.concatenate([total[None], sens]), axis=0),
        )
    info_t, vec_t, yty_t = state.info, state.vec, state.yty
    for f in range(n_f):
        # Lambda <- lam Lambda + H^T H ;  S <- lam S + H^T dr  (rows already whitened)
        info_t = lam * info_t + info[f]
        vec_t = lam * vec_t + vec[f]
        yty_t = lam * yty_t + float(yty[f])
        total = forgetting * total + sens[f]
    return Accumulator(RlsState(info_t, vec_t, yty_t, rows_after(state.rows, sizes, lam)), total)


def rows_after(rows: float, sizes: np.ndarray, lam: float) -> float:
    """The state's row count after frames of ``sizes`` pairs (12 rows each), discounted
    by ``lam`` once per frame, as :func:`add_frame` counts them one frame at a time."""
    if lam == 1.0:
        return rows + 12 * float(np.sum(sizes))
    for k in sizes.tolist():
        rows = lam * rows + 12 * k
    return rows


def better_sign(rss: dict[int, float]) -> tuple[int, float]:
    """The half-order sign hypothesis with the smaller weighted residual ``rss``, and the
    other's residual over its (infinite when the better one fits exactly)."""
    best = min(rss, key=lambda s: rss[s])
    ratio = rss[-best] / rss[best] if rss[best] > 0 else float("inf")
    return best, ratio


def half_order_report(
    decided_sign: int | None,
    best: int,
    ratio: float,
    after: int | None,
    frames: int,
    referenced: bool,
) -> dict[str, Any]:
    """How the 720 deg ambiguity was resolved (``method: residual``), or how a cam or
    pressure reference fared against the residual test (``method: reference_checked``).

    ``best`` and ``ratio``: the better sign hypothesis and its residual ratio;
    ``after``: the frames after which the test decided (None: not decided);
    ``frames``: the frames that carried both hypotheses.
    """
    if referenced:
        return {
            "method": "reference_checked",
            "half_order_sign": decided_sign or 1,
            # the test decided against the reference: its sign is used
            "reference_contradicted": decided_sign == -1,
            # undecided: the reference's sign is kept, whichever the test leans to,
            # and a lean against it leaves no estimate to stand behind (the run exits
            # with the reason: realistic i3, cam 360 deg off, 20 s: 42x, Iyy -2.7)
            "test_decided": decided_sign is not None,
            "reference_doubtful": decided_sign is None and best == -1,
            "residual_ratio": ratio if best == 1 else 1.0 / ratio,
            "decided_after_frames": after,
            "frames": frames,
        }
    return {
        "method": "residual",
        "half_order_sign": best,
        "residual_ratio": ratio,
        "decided_after_frames": after,
        "frames": frames,
    }
