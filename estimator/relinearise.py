"""When the streaming estimator refreshes its linearisation point, and its first frame's.

A few terms of the equations (:mod:`estimator.equations`) are linearised about
the current estimate: ``G x F_unb`` (and ``G x`` the scaled mount reactions), the
crank offset, the row weighting. Each frame's rows are built about the point of
their flush and stay in the sums all run, so the point is refreshed often while
the estimate still moves (each refresh costs a solve and a row batch).

The first frame's rows would be built about the bench file's nominal cog
(centimetres off) and no unbalance at all: then ``(G - G0) x F_unb`` stays in
the sums (0.1 % of a 5e-4 kg m unbalance with a 1 cm cog error over the 60
frames of the test harness). So that frame is solved alone first, Gauss-Newton
(:func:`settle_first_frame`).
"""

from __future__ import annotations

from typing import Protocol

from estimator.hypotheses import Accumulator
from estimator.misfit import MisfitSample
from estimator.pending_rows import FrameQueue
from estimator.result import EstimatorStats
from estimator.setup import EstimatorSetup


class Relinearised(Protocol):
    """What of the streaming estimator (:class:`estimator.streaming.InertiaEstimator`,
    which calls in here) a refresh uses."""

    queue: FrameQueue
    acc: dict[int, Accumulator]
    misfit: MisfitSample
    _hypotheses_equal: bool
    stats: EstimatorStats
    setup: EstimatorSetup

    def _flush(self) -> None: ...

    def _relinearise(self) -> None: ...


# The linearised terms (G x F_unb, row weighting) move slowly once a few frames are in:
# refresh them every few used frames rather than solving after every frame, more
# often while the estimate still moves (each refresh costs a solve and a row batch).
RELINEARISE_EVERY = 8
RELINEARISE_EVERY_LATER = 32
RELINEARISE_LATER_AFTER = 64


def relinearise_due(used: int) -> bool:
    """True after the used frames at which the linearisation point is refreshed."""
    every = RELINEARISE_EVERY if used <= RELINEARISE_LATER_AFTER else RELINEARISE_EVERY_LATER
    return used % every == 1


def next_relinearisation(used: int) -> int:
    """The first count of used frames above ``used`` at which :func:`relinearise_due`
    holds (a run's loop compares its count with it: no call per frame)."""
    due = used + 1 + (-used) % RELINEARISE_EVERY
    if due > RELINEARISE_LATER_AFTER:  # (then every RELINEARISE_EVERY_LATER frames)
        after = max(used, RELINEARISE_LATER_AFTER)
        due = after + 1 + (-after) % RELINEARISE_EVERY_LATER
    return due


# Gauss-Newton steps on the first used frame before its rows are kept: with the
# harness's 1 cm nominal cog error the inertia is 2e-9 off after two, round-off after three.
FIRST_FRAME_ITERATIONS = 3


def relinearise(est: Relinearised) -> None:
    """Add the queued frames' rows and refresh the linearisation point (after the first
    used frame, settled first when the unbalance is located: with its couple free, the
    first frame's ``G x F_unb`` error is no longer tied down by the rest)."""
    corr = est.setup.corrections
    if est.stats.used == 1 and corr.unbalance and corr.unbalance_location:
        settle_first_frame(est)
    est._flush()
    est._relinearise()


def settle_first_frame(est: Relinearised) -> None:
    """Move ``est``'s linearisation point to its first used frame's own solution.

    Its rows are built, added, solved and the point refreshed, the trial sums then
    dropped (``FIRST_FRAME_ITERATIONS`` times); :func:`relinearise` then adds them
    once, as every other frame's. Frames of an unseen motion are left to
    :mod:`estimator.partial_pairs` (they solve their own motion).
    """
    pending = list(est.queue.frames)
    if any(p.fit.null is not None for p in pending):
        return
    acc, misfit, equal = dict(est.acc), est.misfit.copy(), est._hypotheses_equal
    for _ in range(FIRST_FRAME_ITERATIONS):
        est.queue.frames = list(pending)
        est._flush()
        est._relinearise()
        est.acc, est.misfit, est._hypotheses_equal = dict(acc), misfit.copy(), equal
    est.queue.frames = pending
