"""The compiled row assembly (estimator/row_kernels.py) against the numpy reference: the
rows of estimator/equations.frame_rows and RowAssembler's whitened sensitivities, for the
parameter layouts and corrections the kernel covers, and whole runs of the estimator.

The kernel's loops sum in another order than BLAS, einsum and LAPACK: the rows agree
within rounding (1e-12 relative to each array's largest entry), the estimates within
1e-12 relative (of their standard deviation where the value is near zero) and the
standard deviations within 1e-12 relative.
The loops are checked run by the interpreter (no numba needed) and compiled.
"""

from __future__ import annotations

import dataclasses
import itertools
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from support.estimator_harness import Body, SplitExcitation, frames, make_setup

from estimator import compiled_model_rows, compiled_rows, row_kernels
from estimator.compiled_sums import kernel_tail_sums
from estimator.elastic_tail import ELASTIC_F_REF_HZ, ELASTIC_TERMS, with_tail
from estimator.equations import Linearisation, ParameterLayout, frame_rows
from estimator.hypotheses import Accumulator, add_frames
from estimator.model_inputs import model_input_rows
from estimator.rls import RlsState
from estimator.setup import Corrections, ModelInput
from estimator.streaming import InertiaEstimator
from estimator.systematic import motion_sensitivity, reading_sensitivity, sensor_blocks

NUMBA = pytest.mark.skipif(not row_kernels.AVAILABLE, reason="numba not installed")
RNG = np.random.default_rng(5)
P = 7
ORDERS = np.array([1.0, 1.5, 2.0, 1.0, 3.0, 0.5, 1.0])
RPM = np.array([1800.0, 1800.0, 2500.0, 3900.0, 4200.0, 1200.0, 5000.0])


def _complex(*shape: int) -> np.ndarray:
    return RNG.normal(size=shape) + 1j * RNG.normal(size=shape)


# (name, corrections, layout, mass known, measured moment)
CASES = [
    ("default", Corrections(), ParameterLayout(unbalance=True, mass=False, offset=True), True),
    (
        "mass unknown, couple, no offset",
        Corrections(crank_offset=False, unbalance_location=True),
        ParameterLayout(unbalance=True, mass=True, offset=False, couple=True),
        False,
    ),
    (
        "no suspension, no gyroscopic term, measured gas moment",
        Corrections(suspension=False, gyroscopic=False),
        ParameterLayout(unbalance=False, mass=False, offset=True),
        True,
    ),
]


def _inputs(case: tuple) -> Any:
    _, corrections, layout, mass_known = case
    setup = make_setup(Body(), mass_known=mass_known, corrections=corrections)
    lin = Linearisation(
        cog=setup.cog_nominal + 0.003, inertia=setup.inertia_nominal, mass=setup.mass_nominal
    )
    a = RNG.normal(size=(P, 6, 6))
    cov_unit = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(6)
    args = {
        "gamma_o": _complex(P, 3),
        "omega_dot": 5 * _complex(P, 3),
        "origin": RNG.normal(scale=0.02, size=(P, 3)),
        "cov_unit": cov_unit,
        "orders": ORDERS,
        "rpm": RPM,
        "force": 300 * _complex(P, 3),
        "moment_r": 100 * _complex(P, 3),
        "noise_var": 10 ** RNG.uniform(-6, -3, P),
    }
    measured = 50 * _complex(P, 3) if "measured" in case[0] else None
    sens = RNG.normal(size=(P, 12, 20))
    sens[:, :, -2:] = 0.0  # the model inputs' columns
    sign = RNG.choice([-1.0, 1.0], P)
    model = RNG.normal(size=(P, 12, 2))
    return setup, layout, lin, args, measured, sens, sign, model


def _reference(setup, layout, lin, args, measured, sens, sign, model):
    r = frame_rows(setup, layout, lin, **args, measured_moment=measured)
    dr = r.whiten @ r.d_meas @ (sign[:, None, None] * sens)
    dr[:, :, -2:] += r.whiten @ model
    return r.H, r.y, dr


def _close(got: tuple, want: tuple) -> None:
    for g, w in zip(got, want, strict=True):
        assert g.shape == w.shape
        assert np.max(np.abs(g - w)) <= 1e-12 * np.max(np.abs(w))


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_kernel_loops_give_the_numpy_rows(case) -> None:
    setup, layout, lin, args, measured, sens, sign, model = _inputs(case)
    got = compiled_rows.kernel_rows(
        setup, layout, lin, **args, measured_moment=measured, sens=sens, sign=sign, model=model,
        compiled=False,
    )  # fmt: skip
    _close(got, _reference(setup, layout, lin, args, measured, sens, sign, model))


@NUMBA
@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_compiled_kernel_gives_the_numpy_rows(case) -> None:
    setup, layout, lin, args, measured, sens, sign, model = _inputs(case)
    got = compiled_rows.kernel_rows(
        setup, layout, lin, **args, measured_moment=measured, sens=sens, sign=sign, model=model
    )
    _close(got, _reference(setup, layout, lin, args, measured, sens, sign, model))
    # a pair's rows do not depend on the pairs assembled with it
    one = compiled_rows.kernel_rows(
        setup,
        layout,
        lin,
        **{k: v[2:3] for k, v in args.items()},
        measured_moment=None if measured is None else measured[2:3],
        sens=sens[2:3],
        sign=sign[2:3],
        model=model[2:3],
    )
    for a, b in zip(one, got, strict=True):
        assert np.array_equal(a[0], b[2])


def _sensor_setups(count: int):
    """Random channel layouts: sensors with one to three channels, used in any order."""
    rng = np.random.default_rng(8)
    for _ in range(count):
        n_sens = int(rng.integers(2, 6))
        of_channel = np.repeat(np.arange(n_sens), rng.integers(1, 4, n_sens))
        n_ch = len(of_channel)
        setup = SimpleNamespace(
            channels=[f"c{i}" for i in range(n_ch)],
            n_sensors=n_sens,
            model_inputs=[None] * int(rng.integers(0, 4)),
            sensor_of_channel=of_channel,
            positions=rng.normal(size=(n_ch, 3)),
            directions=rng.normal(size=(n_ch, 3)),
        )
        used = rng.permutation(n_ch)[: int(rng.integers(min(3, n_ch), n_ch + 1))]
        fit = SimpleNamespace(
            channels=used, origin=rng.normal(size=3), gain=rng.normal(size=(6, len(used)))
        )
        n_p = int(rng.integers(1, 30))
        motion = [rng.normal(size=(n_p, k)) + 1j * rng.normal(size=(n_p, k)) for k in (3, 3)]
        amplitudes = rng.normal(size=(n_p, len(used))) + 1j * rng.normal(size=(n_p, len(used)))
        yield setup, fit, amplitudes, *motion


def test_motion_sensitivity_is_the_gain_times_the_reading_sensitivity() -> None:
    """A second route: the fit is linear (motion = gain @ readings), so d motion / dp is
    the dense product of the gain with d readings / dp, real and imaginary rows."""
    for setup, fit, amplitudes, gamma_o, omega_dot in _sensor_setups(40):
        got = motion_sensitivity(setup, fit, amplitudes, gamma_o, omega_dot)
        dense = fit.gain @ reading_sensitivity(setup, fit, amplitudes, gamma_o, omega_dot)
        want = np.concatenate([dense.real, dense.imag], axis=1)
        assert np.max(np.abs(got - want)) <= 1e-13 * np.max(np.abs(want))


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
def test_motion_sensitivity_kernel_gives_the_numpy_values(compiled: bool) -> None:
    """The same products and sums in channel order: the same values."""
    for setup, fit, amplitudes, gamma_o, omega_dot in _sensor_setups(40):
        want = motion_sensitivity(setup, fit, amplitudes, gamma_o, omega_dot)
        blocks = sensor_blocks(setup, fit)
        got = compiled_rows.kernel_motion_sensitivity(
            blocks, amplitudes, gamma_o, omega_dot, compiled=compiled
        )
        assert np.array_equal(got, want)


def _d_excitation(rpm: np.ndarray, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w2 = (rpm * np.pi / 30) ** 2
    return (orders * w2)[:, None] * [0.1, 0.2j, 0.3], (orders * w2)[:, None] * [0.02j, 0.01, 0.03]


def _model_inputs(split: bool) -> tuple[ModelInput, ...]:
    # (split: every excitation input offers its parts, gathered in the kernel's loop)
    d = SplitExcitation() if split else _d_excitation
    return (
        ModelInput("exc", "excitation", 0.05, d_excitation=d),
        ModelInput("spin_inertia", "spin_inertia", 0.01),
        ModelInput("mount:m1", "mount", 0.15, mount=1),
        ModelInput("exc2", "excitation", 0.05, d_excitation=d),
        ModelInput("mount:m0", "mount", 0.15, mount=0),
    )


MODEL_INPUTS = _model_inputs(False)


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
@pytest.mark.parametrize("mass_known", [True, False])
@pytest.mark.parametrize("split", [False, True])
def test_model_input_kernel_gives_the_numpy_rows(
    compiled: bool, mass_known: bool, split: bool
) -> None:
    body = Body()
    inputs = _model_inputs(split)
    setup = dataclasses.replace(make_setup(body, mass_known=mass_known), model_inputs=inputs)
    lin = Linearisation(cog=body.cog + 0.01, inertia=body.inertia, mass=body.mass * 0.97)
    motion = 0.1 * _complex(P, 3), _complex(P, 3)
    origin = RNG.normal(scale=0.02, size=(P, 3))
    args = (setup, lin, mass_known, *motion, origin, ORDERS, RPM)
    got = compiled_model_rows.kernel_model_input_rows(*args, compiled=compiled)
    _close((got,), (model_input_rows(*args),))


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
@pytest.mark.parametrize("forgetting", [1.0, 0.98])
def test_compiled_sums_give_the_numpy_state(compiled: bool, forgetting: float) -> None:
    # the tail's columns scaled from theta's (compiled_sums) against the sums of the
    # widened rows (with_tail, add_frames); a pair at 0 Hz (phi 0) and one at 350 Hz;
    # in blocks of frames and frame by frame
    rng = np.random.default_rng(4)
    sizes = [3, 1, 2, 3, 3, 2]
    bounds = np.cumsum([0, *sizes])
    n_p, n, n_sys = int(bounds[-1]), 12, 30
    m = n + ELASTIC_TERMS
    H, y = rng.normal(size=(n_p, 12, n)), rng.normal(size=(n_p, 12))
    dr = rng.normal(size=(n_p, 12, n_sys))
    f_hz = rng.uniform(10.0, 250.0, n_p)
    f_hz[[2, 7]] = 0.0, 350.0
    start = Accumulator(
        RlsState(np.eye(m), rng.normal(size=m), 3.0, 10.0), rng.normal(size=(m, n_sys))
    )
    want = add_frames(start, with_tail(H, f_hz), y, dr, bounds, forgetting)
    phi = (f_hz / ELASTIC_F_REF_HZ) ** 2

    def sums(acc: Accumulator, a: int, b: int) -> Accumulator:
        return kernel_tail_sums(
            acc, H[a:b], y[a:b], dr[a:b], bounds[(bounds >= a) & (bounds <= b)] - a,
            forgetting, phi[a:b], ELASTIC_TERMS, compiled,
        )  # fmt: skip

    got = sums(start, 0, n_p)
    _close(
        (got.state.info, got.state.vec, np.array(got.state.yty), got.sens),
        (want.state.info, want.state.vec, np.array(want.state.yty), want.sens),
    )
    assert got.state.rows == want.state.rows
    assert np.array_equal(got.state.info, got.state.info.T)
    # frame by frame: the same bits
    acc = start
    for a, b in itertools.pairwise(bounds):
        acc = sums(acc, a, b)
    assert np.array_equal(acc.state.info, got.state.info)
    assert np.array_equal(acc.sens, got.sens)
    assert acc.state.yty == got.state.yty


def _run(compiled: bool, single: bool) -> InertiaEstimator:
    body = Body(unbalance=4e-4 * np.exp(-1j * 0.7))
    corrections = Corrections(crank_offset=True)
    setup = make_setup(body, corrections=corrections)
    est = InertiaEstimator(dataclasses.replace(setup, model_inputs=MODEL_INPUTS))
    est.rows.compiled = compiled
    rng = np.random.default_rng(2)
    data = [
        dataclasses.replace(f, amplitudes=f.amplitudes * (1 + 0.01 * rng.normal(size=(3, 9))))
        for f in frames(body, np.linspace(1200.0, 5200.0, 120))
    ]
    if single:
        for f in data:
            est.update(f)
    else:
        for at in range(0, len(data), 25):
            est.update_many(data[at : at + 25])
    return est


@NUMBA
def test_compiled_rows_give_the_numpy_estimate() -> None:
    ref = _run(compiled=False, single=False).estimate()
    blocks = _run(compiled=True, single=False)
    got = blocks.estimate()
    sd, sd_ref = np.sqrt(np.diag(got.cov)), np.sqrt(np.diag(ref.cov))
    # (relative to the value, or to the interval for a value near zero)
    assert np.all(np.abs(got.theta - ref.theta) <= 1e-12 * np.maximum(np.abs(ref.theta), sd_ref))
    assert np.all(np.abs(sd - sd_ref) <= 1e-12 * sd_ref)
    # compiled, one frame at a time and in blocks give the same bits
    single = _run(compiled=True, single=True)
    assert np.array_equal(single.estimate().theta, got.theta)
    for s in blocks.acc:
        assert np.array_equal(blocks.acc[s].state.info, single.acc[s].state.info)
        assert np.array_equal(blocks.acc[s].sens, single.acc[s].sens)


def test_the_default_path_never_imports_numba() -> None:
    import os
    import subprocess
    import sys

    code = (
        "import sys; from support.estimator_harness import Body, frames, make_setup; "
        "from estimator.streaming import InertiaEstimator; b = Body(); "
        "e = InertiaEstimator(make_setup(b)); "
        "[e.update(f) for f in frames(b, [1500.0 + 40 * i for i in range(60)])]; "
        "assert e.estimate().frames_used > 0; print('numba' in sys.modules)"
    )
    env = {k: v for k, v in os.environ.items() if k != "PTINERTIA_NUMBA"}
    tests = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env["PYTHONPATH"] = os.pathsep.join([tests, env.get("PYTHONPATH", "")])
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert done.stdout.strip() == "False"
