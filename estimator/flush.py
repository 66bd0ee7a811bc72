"""A flush: the queued frames' rows assembled and added to the half-order sign hypotheses.

The streaming estimator (:class:`estimator.streaming.InertiaEstimator`, which calls in
here from its ``_flush``) queues each used frame (:class:`estimator.pending_rows.FrameQueue`)
and adds the queue's rows at a relinearisation or when an estimate is asked for. Frames
whose motion is fully measured are assembled a batch at a time
(:class:`estimator.pending_rows.RowAssembler`) and added, frame by frame in stream order,
to each sign hypothesis's sums (:func:`estimator.elastic_tail.add_with_tail`): the same
sums whatever the batch. Frames with an unseen motion go to
:class:`estimator.partial_pairs.PartialPairs`, which linearises each batch it takes.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from estimator.elastic_tail import add_with_tail
from estimator.equations import Linearisation
from estimator.frame_stack import FrameStack, PendingFrame
from estimator.hypotheses import Accumulator
from estimator.misfit import MisfitSample
from estimator.partial_pairs import PartialPairs
from estimator.pending_rows import FrameQueue, RowAssembler
from estimator.result import EstimatorStats


class Flushed(Protocol):
    """What of the streaming estimator a flush reads and updates."""

    queue: FrameQueue
    rows: RowAssembler
    partial: PartialPairs
    acc: dict[int, Accumulator]
    misfit: MisfitSample
    stats: EstimatorStats
    lin: Linearisation
    forgetting: float
    decided_sign: int | None
    _hypotheses_equal: bool
    _cal: list[int]


def flush(est: Flushed) -> None:
    """Assemble the queued frames' rows and add them, frame by frame, to both hypotheses.

    The two sign hypotheses differ only in the half orders of frames whose 720 deg
    cycle is unknown (there the motion, and every measurement-derived term, flips
    sign): only those rows are computed twice, and only until the residuals have
    decided between the hypotheses.
    """
    batch = est.queue.take()
    unseen = [p for p in batch if p.fit.null is not None]
    batch = [p for p in batch if p.fit.null is None]
    if batch:
        flush_measured(est, batch)
    if unseen:
        est.partial.take(unseen)


def flush_measured(est: Flushed, batch: list[PendingFrame]) -> None:
    """:func:`flush` for the frames whose motion is fully measured."""
    stack = FrameStack(batch)  # (the frames' arrays concatenated once for every call)
    half = stack.cat("half")
    rows = est.rows
    dm = rows.sensitivity(stack)
    # (sign None: the motions as measured; sel None: every pair)
    hyp: dict[int, tuple[np.ndarray, ...]]
    if est.decided_sign is not None:
        sign = np.where(half, -1.0, 1.0) if est.decided_sign < 0 else None
        hyp = {est.decided_sign: rows.rows(stack, sign, None, dm, est.lin)}
    elif est.stats.ambiguous_frames == 0:
        # No frame without a 720 deg reference yet: both hypotheses are the same
        # sums; keep one, and copy it when the first ambiguous frame arrives.
        hyp = {1: rows.rows(stack, None, None, dm, est.lin)}
        est._hypotheses_equal = True
    else:
        if est._hypotheses_equal:
            est.acc[-1] = Accumulator(state=est.acc[1].state, sens=est.acc[1].sens)
            est.misfit.copy_sign(1, -1)
            est._hypotheses_equal = False
        H, y, dr = rows.rows(stack, None, None, dm, est.lin)
        hyp = {1: (H, y, dr), -1: (H, y, dr)}
        if np.any(half):
            flip = np.where(half, -1.0, 1.0)
            Hf, yf, drf = H.copy(), y.copy(), dr.copy()
            Hf[half], yf[half], drf[half] = rows.rows(stack, flip, half, dm, est.lin)
            hyp[-1] = (Hf, yf, drf)
    bounds, orders = stack.bounds, stack.cat("orders")
    kin = rows.redundancy(batch) if est._cal else None
    for sign_, (Hs, ys, drs) in hyp.items():
        # one update per frame, in stream order: the same sums whatever the batch
        est.misfit.add_frames(sign_, orders, Hs, ys, bounds)
        est.acc[sign_] = add_with_tail(
            est.acc[sign_], Hs, ys, drs, bounds, est.forgetting, stack.f_hz, rows.compiled, kin
        )
