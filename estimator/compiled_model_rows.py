"""The compiled model-input rows: :func:`kernel_model_input_rows`, what
:class:`estimator.pending_rows.RowAssembler` calls with ``PTINERTIA_NUMBA=1`` in place of
:func:`estimator.model_inputs.model_input_rows` (numpy, the default and the reference):
the derivatives of the raw residual with respect to the model inputs, pair by pair
(:func:`model_rows`), beside the rows of :mod:`estimator.compiled_rows` (why, and how
close the compiled rows stay: there).

The excitation inputs' derivatives are gathered in the loop from the speed-split tables
their ``d_excitation`` offers (:data:`estimator.setup.PairExcitationSplitFn`) rather than
made per pair by a call of each (four numpy operations on the pairs' arrays per input and
flush: 2.5 ms of Python a minute on the 60 s log's 54 flushes of three excitation inputs).
The same products as the numpy function (``gas + omega^2 unit`` per pair, the tables the
same numbers).
"""

from __future__ import annotations

import numpy as np

from estimator.equations import Linearisation
from estimator.row_kernels import jit
from estimator.setup import EstimatorSetup, ModelInput
from powertrain.half_orders import rpm_to_omega

# the helpers estimator.row_kernels.jit compiles with model_rows
JIT_HELPERS = ("_times",)


def model_constants(
    setup: EstimatorSetup, lin: Linearisation, mass_known: bool
) -> tuple[np.ndarray, ...]:
    """:func:`model_rows`' arguments that hold for every pair under one linearisation
    ``lin``: each model input's kind (0 excitation, 1 spin inertia, 2 mount stiffness),
    its mount's position and stiffness, the constants (kept like :func:`estimator.compiled_rows.row_constants`)."""
    inputs = setup.model_inputs
    n_m = len(inputs)
    kinds = np.zeros(n_m, np.int64)
    mount_pos = np.zeros((n_m, 3))
    mount_stiff = np.zeros((n_m, 3, 3), complex)
    for j, inp in enumerate(inputs):
        if inp.kind == "spin_inertia":
            kinds[j] = 1
        elif inp.kind != "excitation":
            kinds[j] = 2
            mount = setup.mounts[inp.mount]
            mount_pos[j], mount_stiff[j] = mount.position, mount.stiffness
    return kinds, mount_pos, mount_stiff, model_linearisation(setup, lin, mass_known)


def model_linearisation(setup: EstimatorSetup, lin: Linearisation, mass_known: bool) -> np.ndarray:
    """The last of :func:`model_constants`, the one ``lin`` moves: cog (3), reference
    point (3), crank axis (3), translation rows per newton."""
    per_force = 1.0 if mass_known else 1.0 / lin.mass
    return np.concatenate([lin.cog, setup.reference_point, setup.crank_axis, [per_force]]).astype(
        float
    )


def kernel_model_input_rows(
    setup: EstimatorSetup,
    lin: Linearisation,
    mass_known: bool,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    origin: np.ndarray,
    orders: np.ndarray,
    rpm: np.ndarray,
    compiled: bool = True,
    constants: tuple[np.ndarray, ...] | None = None,
    tables: dict[tuple[float, ...], np.ndarray] | None = None,
) -> np.ndarray:
    """:func:`estimator.model_inputs.model_input_rows` by the compiled :func:`model_rows`
    (the excitation inputs' derivatives gathered in its loop, :func:`_excitation_tables`);
    ``constants``: :func:`model_constants` (None: made here); ``tables``: the caller's
    store of the excitation tables per set of orders, for these inputs (None: made here)."""
    inputs = setup.model_inputs
    n_p, n_m = len(orders), len(inputs)
    h, rpm = np.asarray(orders, float), np.asarray(rpm, float)
    if constants is None:
        constants = model_constants(setup, lin, mass_known)
    kinds, mount_pos, mount_stiff, consts = constants
    w = rpm * 2 * np.pi / 60.0
    exc, at, w2 = _excitation_tables(inputs, h, rpm, tables)
    out = np.empty((n_p, 12, n_m))
    (jit(model_rows) if compiled else model_rows)(
        h,
        w,
        np.ascontiguousarray(origin, float),
        np.ascontiguousarray(gamma_o, complex),
        np.ascontiguousarray(omega_dot, complex),
        kinds,
        exc,
        at,
        w2,
        mount_pos,
        mount_stiff,
        consts,
        out,
    )
    return out


def _excitation_tables(
    inputs: tuple[ModelInput, ...],
    h: np.ndarray,
    rpm: np.ndarray,
    kept: dict[tuple[float, ...], np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The excitation inputs' derivatives as :func:`model_rows` gathers them: tables
    (n_model, 2, K, 6) complex (the gas and the unit-speed parts of K orders, [force,
    moment]), each pair's order ``at`` (P,) among them and its speed squared ``w2`` (P,)
    (rad/s)^2, the pair's derivative ``gas[at] + w2 unit[at]``. From the inputs' ``split``
    (:data:`estimator.setup.PairExcitationSplitFn`: no per-pair arrays made here) when
    every one offers it (the tables taken from ``kept``, or stored there); else their
    per-pair values as the gas part (K = P, unit 0)."""
    n_p, n_m = len(h), len(inputs)
    splits = [
        getattr(inp.d_excitation, "split", None) for inp in inputs if inp.kind == "excitation"
    ]
    if all(s is not None for s in splits):
        key = tuple(sorted(set(h.tolist())))
        exc = None if kept is None else kept.get(key)
        if exc is None:
            exc = np.zeros((n_m, 2, len(key), 6), complex)
            for j, inp in enumerate(inputs):
                if inp.kind == "excitation":
                    gas, unit = inp.d_excitation.split(key)  # type: ignore[union-attr]
                    exc[j, 0], exc[j, 1] = gas.reshape(len(key), 6), unit.reshape(len(key), 6)
            if kept is not None:
                kept[key] = exc
        at = np.searchsorted(np.array(key), h)
        return exc, at, rpm_to_omega(rpm) ** 2
    exc = np.zeros((n_m, 2, n_p, 6), complex)
    for j, inp in enumerate(inputs):
        if inp.kind == "excitation":
            assert inp.d_excitation is not None
            df, dm = inp.d_excitation(rpm, h)
            exc[j, 0, :, :3], exc[j, 0, :, 3:] = df, dm
    return exc, np.arange(n_p), np.zeros(n_p)


def model_rows(
    h: np.ndarray,
    w: np.ndarray,
    origin: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    kinds: np.ndarray,
    exc: np.ndarray,
    at: np.ndarray,
    w2: np.ndarray,
    mount_pos: np.ndarray,
    mount_stiff: np.ndarray,
    consts: np.ndarray,
    out: np.ndarray,
) -> None:
    """d raw residual / d model inputs of P pairs into ``out`` (P, 12, n_model): per input
    its ``kinds`` (0 excitation with d(force, moment) ``exc[j, 0, at[p]] + w2[p] exc[j,
    1, at[p]]`` (:func:`_excitation_tables`), 1 spin
    inertia, 2 the stiffness of the mount at ``mount_pos`` with ``mount_stiff``);
    ``consts``: cog (3), reference point (3), crank axis (3), translation rows per
    newton. :func:`estimator.model_inputs.model_input_rows`' formulas, pair by pair."""
    n_p = h.shape[0]
    n_m = kinds.shape[0]
    g = consts[0:3]
    per_force = consts[9]
    t = np.empty(3, np.complex128)  # translation rows
    r = np.empty(3, np.complex128)  # rotation rows
    v = np.empty(3, np.complex128)
    d = np.empty(6, np.complex128)  # an excitation input's d(force, moment)
    arm = np.empty(3)
    for p in range(n_p):
        om = omega_dot[p]
        big_w2 = (h[p] * w[p]) ** 2
        for j in range(n_m):
            if kinds[j] == 0:
                gas, unit = exc[j, 0, at[p]], exc[j, 1, at[p]]
                for a in range(6):
                    d[a] = gas[a] + _times(w2[p], unit[a])
                for a in range(3):
                    arm[a] = g[a] - consts[3 + a]
                    t[a] = _times(-per_force, d[a])
                for a in range(3):
                    b, c = (a + 1) % 3, (a + 2) % 3
                    r[a] = (_times(arm[b], d[c]) - _times(arm[c], d[b])) - d[3 + a]
            elif kinds[j] == 1:
                s = consts[6:9]
                for a in range(3):
                    b, c = (a + 1) % 3, (a + 2) % 3
                    t[a] = 0.0
                    r[a] = (_times(s[c], om[b]) - _times(s[b], om[c])) / (1j * h[p])
            else:
                pos = mount_pos[j]
                k = mount_stiff[j]
                for a in range(3):
                    b, c = (a + 1) % 3, (a + 2) % 3
                    v[a] = gamma_o[p, a] + (
                        _times(pos[c] - origin[p, c], om[b]) - _times(pos[b] - origin[p, b], om[c])
                    )
                for a in range(3):
                    f_a = (k[a, 0] * v[0] + k[a, 1] * v[1] + k[a, 2] * v[2]) / big_w2
                    t[a] = _times(-per_force, f_a)
                    r[a] = f_a  # (f, then the moment below)
                for a in range(3):
                    arm[a] = g[a] - pos[a]
                for a in range(3):
                    b, c = (a + 1) % 3, (a + 2) % 3
                    v[a] = _times(arm[b], r[c]) - _times(arm[c], r[b])
                r[:] = v
            for a in range(3):
                out[p, a, j] = t[a].real
                out[p, 3 + a, j] = r[a].real
                out[p, 6 + a, j] = t[a].imag
                out[p, 9 + a, j] = r[a].imag


def _times(x: float, z: complex) -> complex:
    """``x z``, a real times a complex, part by part: the values of numba's product of
    ``z`` and ``x`` made a complex with a zero imaginary part, without the products by that
    zero (issue 24)."""
    return complex(x * z.real, x * z.imag)
