"""The example engine geometries (inline 3 and 4) shared by the powertrain tests."""

from __future__ import annotations

import numpy as np

from powertrain.engine import Engine
from powertrain.gas import ParametricGas

DEG = np.pi / 180
BORE, STROKE, ROD, ROD_A, M_ROD, M_PISTON = 0.071, 0.0841, 0.133, 0.040, 0.42, 0.31


PITCH = 0.08  # cylinder pitch a, m


GAS = ParametricGas(intake_pressure=0.45e5, heat_release=160.0)


def inline3(**kw) -> Engine:
    args = dict(
        cylinders=3, bore=BORE, stroke=STROKE, conrod_length=ROD, conrod_mass=M_ROD,
        conrod_cog_from_big_end=ROD_A, piston_mass=M_PISTON, reference_point=[0.0, 0.0, 0.0],
        cylinder_positions=[-PITCH, 0.0, PITCH], throw_angles=np.array([0, 240, 120]) * DEG,
        firing_order=(1, 2, 3), gas=None,
    )  # fmt: skip
    args.update(kw)
    return Engine(**args)


def inline4(**kw) -> Engine:
    args = dict(
        cylinders=4, throw_angles=np.array([0, 180, 180, 0]) * DEG, firing_order=(1, 3, 4, 2),
        cylinder_positions=[-1.5 * PITCH, -0.5 * PITCH, 0.5 * PITCH, 1.5 * PITCH],
    )  # fmt: skip
    args.update(kw)
    return inline3(**args)
