"""The compiled row assembly's entry points: :func:`kernel_rows` (the rows, by
:func:`estimator.row_kernels.pair_rows` and :func:`estimator.whitened_rows.whiten_pairs`),
:func:`kernel_motion_sensitivity` and
:func:`estimator.compiled_model_rows.kernel_model_input_rows` (the sensitivities to the
systematic errors, by the loops here, and to the model inputs, by that module's): what
:class:`estimator.pending_rows.RowAssembler`
calls with ``PTINERTIA_NUMBA=1`` in place of the numpy functions
(:func:`estimator.equations.frame_rows`, :func:`estimator.systematic.motion_sensitivity`,
:func:`estimator.model_inputs.model_input_rows`), which stay the default and the
reference; the RLS sums beside them are :func:`estimator.compiled_sums.tail_sums`.

Why: a flush assembles a dozen frames (some 35 (frame, order) pairs) with a few hundred
numpy calls on (pairs, 3..12, 3..12) arrays, and the calls, not the arithmetic, are its
cost; the numpy code was restructured as far as it keeps its bits (the motion
sensitivity in real arithmetic, the model inputs' products together), which gained
little. Measured (issue 24; the 60 s log's frames, 1498 used, CPU best of 3,
``benchmarks/bench_pipeline.py``' estimator_alone, load average 9-10 on the 2 cores):
row assembly and RLS sums 83-93 us per used frame before, 80-82 with the numpy rows,
39-40 compiled (``pair_rows`` 4.3 us a pair: its arithmetic, the whitened sensitivities
``W D dm`` most of it); the whole estimator 163-183 -> 160-166 numpy, 117-120 compiled in
blocks, 371-406 -> 376-387 numpy, 315-328 compiled one frame at a time (there the
gates, fits and published estimates dominate). The kernels release the GIL. numba is
imported on the first call only (:func:`estimator.row_kernels.jit`), and compiling
them costs about 7 s of CPU once per install (``ptinertia run --duration 5`` with an
empty numba cache: 12.4-13.0 s against 5.3-5.7 s with the dsp's kernels alone); from a
filled cache they add 0.04 s to the start (1.20 against 1.16 s; load 4).

Since (issue 24, ninth wave): the whitening is its own kernel with eight-lane sums
(:mod:`estimator.whitened_rows`, :mod:`estimator.whiten_lanes`), complex-by-real products
part by part in :func:`estimator.row_kernels.pair_rows` and
:func:`estimator.compiled_model_rows.model_rows`, the RLS sums' row count in their kernel,
the motion sensitivity by flat indices; every one the same bits as before (the 60 s log's
calls; the compiled default and realistic runs: 0 difference). On the 60 s log's calls
(CPU best of 30-50, load 2-6, against 4adcb8f's kernels): the rows 16.6-18.5 -> 9.0-10.3
ms a minute, the motion sensitivity 1.8 -> 1.5, the model inputs' rows 0.85 -> 0.78; the
compiled estimator alone (``/tmp/prof/stage_prof.py est``, best of 7, three alternations
with 4adcb8f, load 2.7-2.9) 0.0674-0.0689 -> 0.0597-0.0601 s a minute; the compiled replay
(``/tmp/prof/replay_prof.py``, load ~3.5) processing thread 0.203-0.220 -> 0.188-0.201 s,
244-268x -> 269-287x.
Compiling on an empty numba cache (CPU, this module's kernels one by one, load 3-7): the
rows 5.2 -> 7.6 s (``pair_rows`` 3.3, ``whiten_pairs`` 4.3: LLVM inlines
:func:`estimator.whiten_lanes.rows_products` at both its call sites, ~1 s each; one call
site compiled in 3.4 s but ran 0.5 ms a minute slower), the motion sensitivity 0.6 ->
0.3 s, the RLS sums 1.0 s: 6.7 -> 8.9 s in all, once per install.

How close: the sensitivity loops take the numpy functions' products and sums in their
order (the same values, tested); the rows and the RLS sums do not (loops against BLAS,
einsum and LAPACK). On the 60 s log the accumulators agree within 9e-15 of their largest
entries, the inertia, cog and their standard deviations within 1e-13 relative, the
unbalance and crank offset of that noise-free run (zero, 1e-10) within 7e-13 of their
standard deviations. ``ptinertia run --realistic`` (kernels on against off, the dsp's
compiled in both): every estimate and interval within 1e-12 relative (the crank offset
9.7e-13 the worst), a principal axis component of 0.029 within 1.8e-12 of its value
(5e-14 of the unit vector). What rests on round-off moves more, as with the dsp's
compiled sums: the random part of the noise-free intervals (1e-8 of the total) by 4e-4,
the default run's variance factor by 1 %, its half-order residual ratio by 0.3 %, the
angle of its zero unbalance by 2e-7 (the dsp's kernels: 1.6 %, 0.4 %, 2e-7). With
self-calibration and the unbalance location (an 8 s realistic run, review of issue 24) the
solve amplifies the rounding differences of either path's kernels alike: inertia terms and
their intervals within 5e-11 relative, the unbalance point and crank offset 2e-9.
"""

from __future__ import annotations

import numpy as np

from estimator.equations import Linearisation, ParameterLayout
from estimator.row_kernels import jit, pair_rows
from estimator.setup import EstimatorSetup
from estimator.systematic import SensorBlocks
from estimator.whitened_rows import whiten_pairs


def row_constants(
    setup: EstimatorSetup, layout: ParameterLayout, lin: Linearisation, measured: bool
) -> tuple[np.ndarray, ...]:
    """:func:`pair_rows`' arguments that hold for every pair under one linearisation
    ``lin`` (``measured``: a measured gas moment): ``lin`` (cog, mass, mass unknown),
    the inertia, the mounts' positions and stiffness, the constants, ``c_it`` and the
    columns. A flush's fixed cost: :class:`estimator.pending_rows.RowAssembler` keeps
    them from one flush to the next while ``lin`` stays."""
    corr = setup.corrections
    bt = setup.frame_constants
    mounts = corr.suspension and len(setup.mounts) > 0
    names = set(layout.names)

    def col(name: str) -> int:
        return layout.index(name) if name in names else -1

    cols = np.array(
        [
            col("inv_mass"),
            col("unb_re"),
            col("unb_im"),
            col("unb_couple_re"),
            col("unb_couple_im"),
            col("crank_offset"),
            1 if measured else 0,
        ]
    )
    consts = np.concatenate(
        [
            setup.crank_axis,
            [setup.spin_inertia if corr.gyroscopic else 0.0],
            setup.reference_point,
            setup.unbalance_point,
        ]
    ).astype(float)
    return (
        *row_linearisation(layout, lin),
        bt.mount_positions if mounts else np.zeros((0, 3)),
        bt.mount_stiffness.astype(complex) if mounts else np.zeros((0, 3, 3), complex),
        consts,
        np.asarray(bt.c_it, complex),
        cols,
    )


def row_linearisation(layout: ParameterLayout, lin: Linearisation) -> tuple[np.ndarray, ...]:
    """The first two of :func:`row_constants`, the ones ``lin`` moves: ``lin`` (cog, mass,
    mass unknown) and the inertia (the rest stay from one linearisation to the next)."""
    return (
        np.array([*lin.cog, lin.mass, 1.0 if layout.mass else 0.0], float),
        np.ascontiguousarray(lin.inertia, float),
    )


def _per_pair(a: np.ndarray, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """``a`` as a contiguous (``shape``) array (broadcast only when not per pair already)."""
    if np.shape(a) != shape:
        a = np.broadcast_to(a, shape)
    return np.ascontiguousarray(a, dtype)


def kernel_rows(
    setup: EstimatorSetup,
    layout: ParameterLayout,
    lin: Linearisation,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    origin: np.ndarray,
    cov_unit: np.ndarray,
    orders: np.ndarray,
    rpm: np.ndarray,
    force: np.ndarray,
    moment_r: np.ndarray,
    noise_var: np.ndarray,
    measured_moment: np.ndarray | None,
    sens: np.ndarray,
    sign: np.ndarray,
    model: np.ndarray,
    compiled: bool = True,
    constants: tuple[np.ndarray, ...] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened rows H (P, 12, n), y (P, 12) and sensitivities ``dr`` (P, 12, n_sys) of
    :meth:`estimator.pending_rows.RowAssembler.rows` (before self-calibration) by the
    compiled :func:`pair_rows`; the arguments are :func:`estimator.equations.frame_rows`'
    (per pair), ``sens`` the pairs' d motion / d systematic parameters, ``sign`` the
    sign their motion was multiplied by, ``model`` the model inputs' raw rows,
    ``constants`` :func:`row_constants` (None: made here).
    Not for layouts with estimated mount scales. ``compiled=False``: :func:`pair_rows`
    run by the interpreter (slow: for tests without numba)."""
    assert not layout.mount_scales
    n_p = len(orders)
    if constants is None:
        constants = row_constants(setup, layout, lin, measured_moment is not None)
    lin_c, inertia, mount_pos, mount_stiff, consts, c_it, cols = constants
    H = np.empty((n_p, 12, layout.size))
    y = np.empty((n_p, 12))
    d_meas = np.empty((n_p, 12, 12))
    dr = np.empty((n_p, 12, sens.shape[2]))
    (jit(pair_rows) if compiled else pair_rows)(
        np.asarray(orders, float),
        _per_pair(rpm, (n_p,), float),
        _per_pair(origin, (n_p, 3), float),
        np.ascontiguousarray(gamma_o, complex),
        np.ascontiguousarray(omega_dot, complex),
        np.ascontiguousarray(force, complex),
        np.ascontiguousarray(moment_r, complex),
        np.zeros((n_p, 3), complex)
        if measured_moment is None
        else np.ascontiguousarray(measured_moment, complex),
        lin_c,
        inertia,
        mount_pos,
        mount_stiff,
        consts,
        c_it,
        cols,
        H,
        y,
        d_meas,
    )
    (jit(whiten_pairs) if compiled else whiten_pairs)(
        np.asarray(noise_var, float),
        _per_pair(cov_unit, (n_p, 6, 6), float),
        np.asarray(sign, float),
        np.ascontiguousarray(sens, float),
        np.ascontiguousarray(model, float),
        H,
        y,
        d_meas,
        dr,
    )
    return H, y, dr


def kernel_motion_sensitivity(
    blocks: SensorBlocks,
    amplitudes: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    compiled: bool = True,
) -> np.ndarray:
    """:func:`estimator.systematic.motion_sensitivity` by the compiled :func:`motion_sens`
    (``blocks``: the fit's :func:`estimator.systematic.sensor_blocks`)."""
    b = blocks
    u = len(b.used)
    out = np.zeros((len(gamma_o), 12, b.n_sys))
    (jit(motion_sens) if compiled else motion_sens)(
        np.ascontiguousarray(amplitudes, complex),
        np.ascontiguousarray(gamma_o, complex),
        np.ascontiguousarray(omega_dot, complex),
        b.arm,
        np.ascontiguousarray(b.directions[:u, 0]),
        np.ascontiguousarray(b.gain, float),
        b.used,
        b.bases,
        out,
    )
    return out


def motion_sens(
    amplitudes: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    arm: np.ndarray,
    directions: np.ndarray,
    gain: np.ndarray,
    used: np.ndarray,
    bases: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`estimator.systematic.motion_sensitivity` of P pairs into ``out`` (P, 12,
    n_sys), zeros on entry: ``amplitudes`` (P, u), the motion (P, 3) complex; the fit's
    channels: lever ``arm`` (u, 3) m from its origin, ``directions`` (u, 3), ``gain``
    (6, u), their columns ``used`` (u,) and their sensors' first columns ``bases`` (u,).
    The same products and the same sums in channel order as the numpy function."""
    n_p, u = amplitudes.shape
    n_sys = out.shape[2]
    flat = out.reshape(out.size)  # (flat indices: no view per row, no wrap-around checks)
    pose = np.empty(6)
    for p in range(n_p):
        go = gamma_o[p]
        om = omega_dot[p]
        for part in range(2):
            w0 = om[0].real if part == 0 else om[0].imag
            w1 = om[1].real if part == 0 else om[1].imag
            w2 = om[2].real if part == 0 else om[2].imag
            for j in range(u):
                a = amplitudes[p, j].real if part == 0 else amplitudes[p, j].imag
                n = directions[j]
                r = arm[j]
                g0 = (go[0].real if part == 0 else go[0].imag) + (w1 * r[2] - w2 * r[1])
                g1 = (go[1].real if part == 0 else go[1].imag) + (w2 * r[0] - w0 * r[2])
                g2 = (go[2].real if part == 0 else go[2].imag) + (w0 * r[1] - w1 * r[0])
                # d reading / d(alignment, position): n x gamma_P, n x Omega'
                pose[0] = n[1] * g2 - n[2] * g1
                pose[1] = n[2] * g0 - n[0] * g2
                pose[2] = n[0] * g1 - n[1] * g0
                pose[3] = n[1] * w2 - n[2] * w1
                pose[4] = n[2] * w0 - n[0] * w2
                pose[5] = n[0] * w1 - n[1] * w0
                base = bases[j]
                for i in range(6):
                    row = (p * 12 + 6 * part + i) * n_sys
                    gain_ij = gain[i, j]
                    flat[row + used[j]] = gain_ij * a
                    for c in range(6):
                        flat[row + base + c] += gain_ij * pose[c]
