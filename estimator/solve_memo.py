"""The sign hypotheses' states of theta and their solutions, kept for the length of one call.

While the half-order sign is undecided (no 720 deg reference, or one the residual test
has not confirmed: the realistic i3 sweeps end undecided, residual ratio 44-49 against
the 100 needed), an estimate solved each hypothesis's state to pick the sign in use,
solved the one in use again for the estimate, and both again for the half-order report:
five eigen-decompositions where two are needed; so did each relinearisation. Within one
call of :meth:`InertiaEstimator.estimate` or a relinearisation (:func:`within_one_call`)
each state and solution is made once, keyed by the object it is made from, and all are
dropped when the call returns. Accumulators and states are never changed in place (each
update makes new ones), so a kept result is that of its object; nothing outlives the
call, so nothing can go stale between calls, and every result has the bits it had
when it was made anew each time. Measured on a realistic 30 s i3 sweep (5120 Hz, seed 0,
undecided to the end) in blocks of 12 frames, an estimate every 0.5 s of stream: the
estimates' own CPU 16 -> 10 us per used frame, the updates' (relinearisations) 324 -> 317.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Concatenate, ParamSpec, Protocol, TypeVar

import numpy as np

from estimator.elastic_tail import effective_state
from estimator.hypotheses import Accumulator
from estimator.rls import RlsSolution, RlsState, rls_solve

P = ParamSpec("P")
R = TypeVar("R")


class SolveMemo:
    """States of theta and solutions of one call (none outside a call: made each time).

    Parameters
    ----------
    n : the number of parameters in theta (the accumulators carry the elastic tail too).
    scale : (n,) the parameters' scale (rank decisions).
    anchored : the columns of the self-calibrated sensor errors (held by their priors).
    """

    def __init__(self, n: int, scale: np.ndarray, anchored: list[int]) -> None:
        self.n = n
        self.scale = scale
        self.anchored = anchored
        self.kept: dict[Any, tuple[object, Any]] | None = None  # None: outside a call

    def effective(self, sign: int, acc: Accumulator, elastic: bool) -> Accumulator:
        """The state of theta of the sign hypothesis ``sign`` whose accumulator is ``acc``
        (:func:`estimator.elastic_tail.effective_state`; ``elastic``: a mode confirmed)."""
        return self._once(
            ("effective", sign, elastic),
            acc,
            lambda: effective_state(acc, self.n, self.scale, elastic),
        )

    def solve(self, state: RlsState) -> RlsSolution:
        """The solution of a state of theta (:func:`estimator.rls.rls_solve`)."""
        return self._once(
            ("solve", id(state)),  # (the state is kept with it: its id is not reused)
            state,
            lambda: rls_solve(state, scale=self.scale, anchored=self.anchored),
        )

    def _once(self, key: Any, source: object, make: Callable[[], R]) -> R:
        if self.kept is None:
            return make()
        hit = self.kept.get(key)
        if hit is not None and hit[0] is source:
            return hit[1]
        out = make()
        self.kept[key] = (source, out)
        return out


class HasMemo(Protocol):
    memo: SolveMemo


H = TypeVar("H", bound=HasMemo)


def within_one_call(method: Callable[Concatenate[H, P], R]) -> Callable[Concatenate[H, P], R]:
    """Keep the states and solutions ``method`` makes until it returns (calls inside it
    share them)."""

    @functools.wraps(method)
    def wrapper(self: H, /, *args: P.args, **kwargs: P.kwargs) -> R:
        memo = self.memo
        if memo.kept is not None:  # (inside another such call: its memo)
            return method(self, *args, **kwargs)
        memo.kept = {}
        try:
            return method(self, *args, **kwargs)
        finally:
            memo.kept = None

    return wrapper
