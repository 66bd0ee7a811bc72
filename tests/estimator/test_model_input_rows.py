"""The analytic derivatives of estimator/model_inputs.py against a second route: a central
difference of the raw residual ``H theta - y`` that estimator/equations.py builds with the
input moved (the excitation, the spin inertia, one mount's stiffness), at the
linearisation point, with the mass known and estimated."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.estimator_harness import Body, make_setup

from estimator.equations import Linearisation, ParameterLayout, frame_rows
from estimator.model_inputs import model_input_rows
from estimator.setup import EstimatorSetup, ModelInput, MountStiffness

RNG = np.random.default_rng(11)
P = 5
ORDERS = np.array([1.0, 1.5, 2.0, 1.0, 3.0])
RPM = np.array([1800.0, 1800.0, 2500.0, 3900.0, 4200.0])
ORIGIN = np.tile([0.01, 0.02, -0.03], (P, 1))
GAMMA = RNG.normal(size=(P, 3)) + 1j * RNG.normal(size=(P, 3))
OMEGA = 5 * (RNG.normal(size=(P, 3)) + 1j * RNG.normal(size=(P, 3)))
D_FORCE = RNG.normal(size=(P, 3)) + 1j * RNG.normal(size=(P, 3))
D_MOMENT = RNG.normal(size=(P, 3)) + 1j * RNG.normal(size=(P, 3))


def _d_excitation(rpm: np.ndarray, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    assert np.array_equal(rpm, RPM) and np.array_equal(orders, ORDERS)
    return D_FORCE, D_MOMENT


INPUTS = (
    ModelInput("exc", "excitation", 0.05, d_excitation=_d_excitation),
    ModelInput("spin_inertia", "spin_inertia", 0.01),
    ModelInput("mount:m1", "mount", 0.15, mount=1),
)


def _raw_residual(
    setup: EstimatorSetup,
    layout: ParameterLayout,
    lin: Linearisation,
    theta: np.ndarray,
    d_exc: float = 0.0,
) -> np.ndarray:
    """(P, 12) ``H theta - y`` before whitening, the excitation moved by ``d_exc``."""
    force, moment = (np.zeros((P, 3), complex) for _ in range(2))
    for k in range(P):
        f, m = setup.excitation(float(RPM[k]), ORDERS[k : k + 1])
        force[k], moment[k] = f[0], m[0]
    r = frame_rows(
        setup,
        layout,
        lin,
        GAMMA,
        OMEGA,
        ORIGIN,
        np.eye(6),
        ORDERS,
        RPM,
        force + d_exc * D_FORCE,
        moment + d_exc * D_MOMENT,
        np.ones(P),
    )
    white = np.einsum("oij,j->oi", r.H, theta) - r.y
    return np.linalg.solve(r.whiten, white[..., None])[..., 0]


def _with_mount_scale(setup: EstimatorSetup, i: int, scale: float) -> EstimatorSetup:
    mounts = list(setup.mounts)
    m = mounts[i]
    mounts[i] = MountStiffness(m.name, m.position, m.stiffness * scale)
    return dataclasses.replace(setup, mounts=tuple(mounts))


@pytest.mark.parametrize("mass_known", [True, False])
def test_model_input_rows_match_a_difference_of_the_equations(mass_known: bool) -> None:
    body = Body()
    setup = dataclasses.replace(make_setup(body, mass_known=mass_known), model_inputs=INPUTS)
    layout = ParameterLayout(unbalance=True, mass=not mass_known, offset=True)
    lin = Linearisation(cog=body.cog + 0.01, inertia=body.inertia * 1.05, mass=body.mass * 0.97)
    theta = np.zeros(layout.size)
    theta[:6] = [4.5, 3.2, 4.1, 0.3, -0.4, 0.2]
    theta[6:9] = lin.cog  # the derivative is taken at the linearisation point
    theta[layout.index("unb_re")], theta[layout.index("unb_im")] = 1e-3, -2e-3
    if not mass_known:
        theta[layout.index("inv_mass")] = 1.0 / lin.mass

    analytic = model_input_rows(setup, lin, mass_known, GAMMA, OMEGA, ORIGIN, ORDERS, RPM)
    assert analytic.shape == (P, 12, 3)

    eps = 1e-4
    exc = (
        _raw_residual(setup, layout, lin, theta, eps)
        - _raw_residual(setup, layout, lin, theta, -eps)
    ) / (2 * eps)
    dj = 1e-4 * setup.spin_inertia
    spin = (
        _raw_residual(
            dataclasses.replace(setup, spin_inertia=setup.spin_inertia + dj), layout, lin, theta
        )
        - _raw_residual(
            dataclasses.replace(setup, spin_inertia=setup.spin_inertia - dj), layout, lin, theta
        )
    ) / (2 * dj)
    mount = (
        _raw_residual(_with_mount_scale(setup, 1, 1 + eps), layout, lin, theta)
        - _raw_residual(_with_mount_scale(setup, 1, 1 - eps), layout, lin, theta)
    ) / (2 * eps)
    for j, numeric in enumerate((exc, spin, mount)):
        size = np.max(np.abs(numeric))
        assert size > 0
        np.testing.assert_allclose(
            analytic[:, :, j], numeric, atol=1e-6 * size, err_msg=INPUTS[j].name
        )


def test_no_model_inputs_no_columns() -> None:
    body = Body()
    setup = make_setup(body)
    lin = Linearisation(cog=body.cog, inertia=body.inertia, mass=body.mass)
    out = model_input_rows(setup, lin, True, GAMMA, OMEGA, ORIGIN, ORDERS, RPM)
    assert out.shape == (P, 12, 0)
