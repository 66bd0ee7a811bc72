"""What frame assembly (:func:`dsp.assemble._finish`) derives from the plan alone, made once.

Per batch of frames the assembly needs the output orders as Python floats and the
factors that take amplitudes from the wheel angle to the crank angle
(:func:`dsp.cycle.offset_rotation`). With a wheel (one step per revolution) those are
the exact signs ``(-1) ** (k2 s)``, which depend on the parity ``s`` modulo 2 alone: two
rows, ``s = 0`` and ``s = 1``, made once per plan and indexed per frame, are the same
numbers as the four array operations per batch (and per spectrum) they replace
(issue 24). N pulses per revolution keep the complex exponential of each batch.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from dsp import cycle
from dsp.config import Plan


class FrameConstants(NamedTuple):
    """A plan's constants for frame assembly (arrays never modified)."""

    orders: tuple[float, ...]  # the output orders as Python floats
    k2: np.ndarray  # (n_orders,) twice the output orders (config.k2)
    spectrum_k: np.ndarray  # (spectrum_size,) the spectrum's orders times two: 0, 1, ..
    signs: np.ndarray  # (2, n_orders) offset_rotation of parity 0 and 1 with a wheel
    spectrum_signs: np.ndarray  # (2, spectrum_size) the same for the spectrum's orders
    half: np.ndarray  # rows of the half orders among the output orders (dsp.rejoin)


_MADE: dict[int, tuple[Plan, FrameConstants]] = {}


def frame_constants(plan: Plan) -> FrameConstants:
    """:class:`FrameConstants` of ``plan``, made on its first batch and kept."""
    hit = _MADE.get(id(plan))
    if hit is not None and hit[0] is plan:
        return hit[1]
    cfg = plan.config
    k2 = cfg.k2
    k = np.arange(cfg.spectrum_size)
    both = np.arange(2)
    const = FrameConstants(
        tuple(float(h) for h in cfg.orders), k2, k,
        cycle.offset_rotation(both, k2, 1), cycle.offset_rotation(both, k, 1),
        np.flatnonzero(k2 % 2 == 1),
    )  # fmt: skip
    if len(_MADE) > 16:
        _MADE.clear()  # plans come and go in studies: keep a few
    _MADE[id(plan)] = (plan, const)
    return const


def rotation(parity: np.ndarray, k2: np.ndarray, steps: int, signs: np.ndarray) -> np.ndarray:
    """:func:`dsp.cycle.offset_rotation` of parities ``parity`` (f,) for orders ``k2 / 2``:
    with a wheel (``steps == 1``) the rows of ``signs`` (:class:`FrameConstants`) for
    ``parity mod 2``, the same numbers."""
    if steps == 1:
        return signs[parity % 2]
    return cycle.offset_rotation(parity, k2, steps)
