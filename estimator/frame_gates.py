"""The gates of whole frames: crank speed, tacho, dsp settling, steadiness, overlap.

A block's frames are judged in one loop (:func:`frame_reasons`) with the gates' limits
at hand, their revolution numbers taken in it once (the overlap gate, the channel noise
and the curvature gate all read them; :func:`revolutions` alone); :func:`frame_gate`,
:func:`revolution` and :func:`overlaps_previous` are the same tests for one frame (a
test pins the block's loop to them). The gates of orders, which remember earlier
frames, are in :mod:`estimator.gating`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from estimator.setup import Gates

TACHO_FLAGS = frozenset({"no_tacho", "tacho_resync", "angle_ambiguous", "angle_rebased"})


class FrameLike(Protocol):
    """The fields of ``dsp.frames.OrderFrame`` the estimator reads."""

    time_s: float
    rpm: float
    orders: tuple[float, ...]
    channels: tuple[str, ...]
    amplitudes: np.ndarray
    channel_ok: np.ndarray
    rpm_change: float
    flags: frozenset[str]


def frame_gate(frame: FrameLike, gates: Gates) -> str | None:
    """Why the whole frame is unusable (rpm, tacho, dsp settling, steadiness), None if not."""
    if not math.isfinite(frame.rpm) or frame.rpm <= 0:  # (np.isfinite: a ufunc call)
        return "no_rpm"
    if not TACHO_FLAGS.isdisjoint(frame.flags):
        return "tacho"
    if "leakage_uncorrected" in frame.flags:
        return "dsp_settling"
    if frame.rpm < gates.rpm_range[0] or frame.rpm > gates.rpm_range[1]:
        return "rpm_out_of_range"
    if abs(frame.rpm_change) > gates.max_rpm_change:
        return "rpm_unsteady"
    return None


def frame_reasons(
    frames: Sequence[FrameLike], gates: Gates
) -> tuple[list[str | None], list[int | None]]:
    """Why each of a block's ``frames`` is unusable as a whole: "overlapping" for the
    frames between the 720 deg-spaced ones (odd revolution numbers) when
    ``gates.independent_frames``, else :func:`frame_gate`'s reason (None: usable); and
    each frame's :func:`revolution` (the channel noise and the curvature gate read them
    too). One loop with the gates' limits at hand (a block's frames pass these tests
    one after another)."""
    lo, hi = gates.rpm_range
    most, independent = gates.max_rpm_change, gates.independent_frames
    isfinite, tacho = math.isfinite, TACHO_FLAGS
    out: list[str | None] = []
    revs: list[int | None] = []
    append, append_rev = out.append, revs.append
    for frame in frames:
        angle = getattr(frame, "crank_angle_rad", None)
        if angle is None or not isfinite(angle):
            append_rev(None)
        else:
            append_rev(rev := round(float(angle) / _TWO_PI))
            if independent and rev % 2 == 1:
                append("overlapping")
                continue
        rpm, flags = frame.rpm, frame.flags
        if not isfinite(rpm) or rpm <= 0:
            append("no_rpm")
        elif flags and not tacho.isdisjoint(flags):  # (most frames: no flags at all)
            append("tacho")
        elif flags and "leakage_uncorrected" in flags:
            append("dsp_settling")
        elif rpm < lo or rpm > hi:
            append("rpm_out_of_range")
        elif abs(frame.rpm_change) > most:
            append("rpm_unsteady")
        else:
            append(None)
    return out, revs


def revolution(frame: FrameLike) -> int | None:
    """The frame's crank revolution number (None without a crank angle)."""
    angle = getattr(frame, "crank_angle_rad", None)
    if angle is None or not math.isfinite(angle):  # (np.isfinite: a ufunc call per frame)
        return None
    return round(float(angle) / (2 * np.pi))


def revolutions(frames: Sequence[FrameLike]) -> list[int | None]:
    """:func:`revolution` of each of ``frames``, in one loop (a block's revolutions are
    read by the overlap gate, the channel noise and the curvature gate: taken once)."""
    out: list[int | None] = []
    append, isfinite = out.append, math.isfinite
    for frame in frames:
        angle = getattr(frame, "crank_angle_rad", None)
        append(None if angle is None or not isfinite(angle) else round(float(angle) / _TWO_PI))
    return out


def overlaps_previous(frame: FrameLike) -> bool:
    """True for the frames between the 720 deg-spaced ones (odd revolution numbers)."""
    angle = getattr(frame, "crank_angle_rad", None)
    if angle is None or not math.isfinite(angle):
        return False
    return round(float(angle) / _TWO_PI) % 2 == 1


_TWO_PI = 2 * np.pi  # (revolution's divisor, the same float, not made again per frame)
