"""A used frame queued for its rows (:class:`PendingFrame`), and a flush's frames stacked.

:class:`estimator.pending_rows.FrameQueue` queues each used frame as a
:class:`PendingFrame`; a flush hands :class:`estimator.pending_rows.RowAssembler` its
frames as one :class:`FrameStack`: each per-pair array concatenated once for the
sensitivities, both sign hypotheses' rows and the elastic tail, where each call
concatenated its own (the same arrays, the same bits; the 60 s log's feed with an
estimate every 0.5 s, 128 flushes of about 12 frames: numpy flush 74.7 -> 72.1 us per
used frame, compiled 35.2 -> 33.5 with the compiled rows' constants kept per
linearisation, CPU best of 3, load 4-5).

Issue 24 (tenth wave): a frame's noise variances are queued as the list of floats the
queue makes (:meth:`FrameStack.cat` converts a flush's in one call, the same values as
an array per frame), the misfit sample thins a flush's frames without a callable per
frame, and the frames of a block with the same usable channels share one mask row.
Measured on the estimator stage alone (the 60 s log's blocks, an estimate every 0.5 s;
callgrind instructions of the stage, repeatable within 0.2 %): compiled 853.8M ->
839.4-841.3M, numpy 1799.1M -> 1784.5M; CPU best of 5 alternating with the base, load
6: 0.0761-0.0804 -> 0.0707-0.0793 s a minute. The same bits on both paths.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from estimator.kinematics import RigidFit


class PendingFrame(NamedTuple):
    """A used frame waiting for its rows: its fitted motion and what the rows need, per order.

    (A named tuple: one is made per used frame, in a third of a frozen dataclass's time.)"""

    gamma_o: np.ndarray  # (k, 3) complex
    omega_dot: np.ndarray  # (k, 3) complex
    origin: np.ndarray  # (3,)
    cov_unit: np.ndarray  # (6, 6)
    orders: np.ndarray  # (k,)
    rpm: float
    force: np.ndarray  # (k, 3) complex
    moment: np.ndarray  # (k, 3) complex
    var: list[float] | np.ndarray  # (k,) (the queue's: a list, see FrameStack.cat)
    fit: RigidFit  # the channel geometry of the fit
    amplitudes: np.ndarray  # (k, u) complex, the fitted readings
    half: np.ndarray  # (k,) bool: a half order of a frame with an unknown 720 deg cycle
    measured_moment: np.ndarray | None  # (k, 3) complex: the part of moment measured (gas)
    # self-calibration: the pairs' redundancy rows before whitening, (k, 2r, n_sys) and (k, 2r)
    redundancy: tuple[np.ndarray, np.ndarray] | None = None


class FrameStack:
    """The per-pair arrays of a batch of queued frames, each concatenated (or repeated per
    pair) once however many of a flush's calls use it: the rows of both sign hypotheses,
    the sensitivities, the tail's frequencies. The arrays are shared, never written."""

    def __init__(self, frames: list[PendingFrame]) -> None:
        self.frames = frames
        # each field's values, frame by frame (one transposition for every field; none
        # without frames)
        self._fields = dict(zip(PendingFrame._fields, zip(*frames, strict=True), strict=False))
        self.counts = [len(h) for h in self._fields.get("orders", ())]  # pairs per frame
        self._arrays: dict[str, np.ndarray] = {}

    def cat(self, name: str) -> np.ndarray:
        """The frames' per-order field ``name`` (k, ...) concatenated: (P, ...)."""
        out = self._arrays.get(name)
        if out is None:
            values = self._fields[name]
            if isinstance(values[0], list):
                # (the queue's noise variances, lists of floats: one conversion for the
                # flush, the values np.array(var) of each and their concatenation have)
                out = np.array(list(itertools.chain.from_iterable(values)), float)
            else:
                out = np.concatenate(values)
            self._arrays[name] = out
        return out

    def per_pair(self, name: str) -> np.ndarray:
        """The frames' per-frame field ``name`` repeated for each of their pairs: (P, ...)."""
        key = "per_pair:" + name
        out = self._arrays.get(key)
        if out is None:
            values = self._fields[name]
            first = values[0]
            if isinstance(first, np.ndarray) and all(v is first for v in values):
                # (the frames of one fit share its origin and cov_unit: one broadcast
                # copy, the same array as repeated, in a third of the time)
                out = np.empty((sum(self.counts), *first.shape), first.dtype)
                out[...] = first
            else:
                out = np.repeat(np.array(values), self.counts, axis=0)
            self._arrays[key] = out
        return out

    @property
    def bounds(self) -> np.ndarray:
        """Frame f's pairs are ``bounds[f]:bounds[f + 1]``."""
        out = self._arrays.get("bounds")
        if out is None:
            # (accumulated in Python: np.cumsum of a list goes through np.asarray's wrapper)
            out = self._arrays["bounds"] = np.array([0, *itertools.accumulate(self.counts)])
        return out

    @property
    def f_hz(self) -> np.ndarray:
        """(P,) each pair's frequency, Hz."""
        out = self._arrays.get("f_hz")
        if out is None:
            out = self._arrays["f_hz"] = self.cat("orders") * self.per_pair("rpm") / 60.0
        return out


def stacked(batch: list[PendingFrame] | FrameStack) -> FrameStack:
    """``batch`` as a :class:`FrameStack` (itself when it is one)."""
    return batch if isinstance(batch, FrameStack) else FrameStack(batch)
