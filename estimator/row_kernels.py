"""Compiled row assembly: the raw rows of (frame, order) pairs, one pair at a time.

:func:`pair_rows` does :func:`estimator.equations.frame_rows`' arithmetic pair by pair in
loops (mount reactions, gyroscopic term, translation and rotation rows, unbalance and
crank-offset columns, d residual / d measurement); :func:`estimator.whitened_rows.whiten_pairs`
then whitens them (the row covariance, its Cholesky factor and inverse) and forms
:class:`estimator.pending_rows.RowAssembler`'s whitened sensitivities ``dr``. Layouts
with estimated mount stiffness scales stay on the numpy path. :func:`jit` compiles this
module's kernels and those of :mod:`estimator.compiled_rows`,
:mod:`estimator.whitened_rows` (with the eight-lane helpers its ``LANE_HELPERS`` name),
:mod:`estimator.compiled_model_rows` and :mod:`estimator.compiled_sums` (``cache=True``,
``nogil=True``: they release the GIL), importing numba on the first call: the default
path (``PTINERTIA_NUMBA`` unset) never imports it. Why, what it gains and how close it
stays to the numpy reference: :mod:`estimator.compiled_rows`.

Products of a complex and a real (the mounts' stiffness and the skew matrices of the
mounts' positions, crosses with real arms) are formed part by part
(:func:`_matmul3_cr`, :func:`_cross_cr`, ...): numba makes the real a complex with a zero
imaginary part and multiplies in full, products by that zero included, which without
fast-math LLVM may not drop. The same values (the 60 s log's pairs: the same bits), about
a quarter fewer instructions (issue 24; callgrind, the 60 s log's 54 calls: 42.5 -> 37.3M
with the 3 x 3 products, 31.5M with the crosses too; CPU 3.0 -> 2.4-2.8 ms a minute,
load 2).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
import types
from collections.abc import Callable
from typing import Any

import numpy as np

AVAILABLE = importlib.util.find_spec("numba") is not None
# PTINERTIA_NUMBA=1: the row assembly uses the kernel (long runs, campaigns and studies)
USE = AVAILABLE and os.environ.get("PTINERTIA_NUMBA", "0") == "1"
_compiled: dict[Callable[..., None], Callable[..., None]] = {}


# the helpers pair_rows calls: compiled with it (a compiled function calls compiled ones)
_HELPERS = (
    "_matmul3_cr",
    "_matmul3_rc",
    "_skew",
    "_skew_entry",
    "_skew_into",
    "_cross_cr",
    "_cross_rc",
    "_dot3_rc",
    "_cross_unb",
)


def jit(fn: Callable[..., None]) -> Callable[..., None]:
    """``fn`` compiled by numba (``cache=True, nogil=True``), once per process."""
    names = globals()
    compiled = _compiled.get(fn)
    if compiled is None:
        from numba import njit  # heavy (0.3 s): only where a kernel is used

        # the module's helpers become their compiled selves (callable from Python alike),
        # which the kernels' compilation then finds as their globals
        for helper in _HELPERS:
            if not hasattr(names[helper], "py_func"):
                names[helper] = njit(cache=True, nogil=True)(names[helper])
        # a kernel's module may name helpers compiled elsewhere (eight-lane code that only
        # compiles): the kernel is compiled from a copy of the function whose globals hold
        # those, the module's own (the reference loops) stay for the interpreter
        module = sys.modules[fn.__module__]
        # (a kernel module's own helpers, named in its JIT_HELPERS, likewise)
        for helper in getattr(module, "JIT_HELPERS", ()):
            if not hasattr(getattr(module, helper), "py_func"):
                setattr(module, helper, njit(cache=True, nogil=True)(getattr(module, helper)))
        source = fn
        if getattr(module, "LANE_HELPERS", ()):
            lanes = importlib.import_module(module.LANES_MODULE)
            scope = dict(fn.__globals__)
            for helper in module.LANE_HELPERS:
                scope[helper] = getattr(lanes, helper)
            source = types.FunctionType(fn.__code__, scope, fn.__name__, fn.__defaults__)
            source.__qualname__ = fn.__qualname__
        compiled = _compiled[fn] = njit(cache=True, nogil=True)(source)
    return compiled


def _matmul3_cr(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a b``, ``a`` complex, ``b`` real (3, 3): each part's products on their own
    (a complex times a real as a complex with a zero imaginary part would add products by
    that zero: the same values, twice the multiplications)."""
    for i in range(3):
        for j in range(3):
            re = a[i, 0].real * b[0, j] + a[i, 1].real * b[1, j] + a[i, 2].real * b[2, j]
            im = a[i, 0].imag * b[0, j] + a[i, 1].imag * b[1, j] + a[i, 2].imag * b[2, j]
            out[i, j] = complex(re, im)


def _matmul3_rc(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a b``, ``a`` real, ``b`` complex (3, 3), as :func:`_matmul3_cr`."""
    for i in range(3):
        for j in range(3):
            re = a[i, 0] * b[0, j].real + a[i, 1] * b[1, j].real + a[i, 2] * b[2, j].real
            im = a[i, 0] * b[0, j].imag + a[i, 1] * b[1, j].imag + a[i, 2] * b[2, j].imag
            out[i, j] = complex(re, im)


def pair_rows(
    h: np.ndarray,
    rpm: np.ndarray,
    origin: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    force: np.ndarray,
    moment: np.ndarray,
    measured: np.ndarray,
    lin: np.ndarray,
    inertia: np.ndarray,
    mount_pos: np.ndarray,
    mount_stiff: np.ndarray,
    consts: np.ndarray,
    c_it: np.ndarray,
    cols: np.ndarray,
    H: np.ndarray,
    y: np.ndarray,
    d_meas: np.ndarray,
) -> None:
    """The raw rows of P (frame, order) pairs, written into ``H`` (P, 12, n), ``y`` (P, 12)
    and ``d_meas`` (P, 12, 12): :func:`estimator.equations.frame_rows`' before whitening
    (which :func:`estimator.whitened_rows.whiten_pairs` does).

    Per pair: order ``h``, crank speed ``rpm`` (rev/min), ``origin`` (3,) m, the motion
    ``gamma_o``, ``omega_dot``, the excitation ``force``, ``moment`` and its measured part
    ``measured`` (3,) complex (zeros when none). ``lin``: cog (3), mass,
    whether the mass is unknown (1.0) ; ``inertia`` (3, 3) the linearisation's;
    ``mount_pos`` (M, 3), ``mount_stiff`` (M, 3, 3) complex (M = 0 without the
    suspension); ``consts``: crank axis (3), spin inertia (0 without the gyroscopic
    term), reference point (3), unbalance point (3); ``c_it`` (3,) complex; ``cols``:
    the columns of 1/m, unb_re, unb_im, unb_couple_re, unb_couple_im, crank_offset, and
    whether ``measured`` is given (-1 / 0: absent).
    """
    n_p = h.shape[0]
    n = H.shape[2]
    n_mounts = mount_pos.shape[0]
    i_inv, i_a, i_b, i_qa, i_qb, i_off = cols[0], cols[1], cols[2], cols[3], cols[4], cols[5]
    has_measured = cols[6]
    mass = lin[3]
    mass_unknown = lin[4] != 0.0
    spin_j = consts[3]
    skew_s = np.zeros((3, 3))
    skew_g = np.zeros((3, 3))
    _skew(consts[0:3], skew_s)
    _skew(lin[0:3], skew_g)
    skew_p = np.zeros((3, 3))
    skew_r = np.zeros((3, 3))
    kw = np.empty((3, 3), np.complex128)
    tmp = np.empty((3, 3), np.complex128)
    df_dgo = np.empty((3, 3), np.complex128)
    df_dw = np.empty((3, 3), np.complex128)
    dmp_dgo = np.empty((3, 3), np.complex128)
    dmp_dw = np.empty((3, 3), np.complex128)
    dfi_dw = np.empty((3, 3), np.complex128)
    d_c = np.empty((6, 6), np.complex128)
    rows = np.empty((6, n), np.complex128)  # translation rows, then rotation rows
    yc = np.empty(6, np.complex128)
    f_mounts = np.empty(3, np.complex128)
    m_mounts = np.empty(3, np.complex128)
    f_i = np.empty(3, np.complex128)
    gamma_i = np.empty(3, np.complex128)
    r = np.empty(3)
    cog_o = np.empty(3)
    f_known = np.empty(3, np.complex128)
    for p in range(n_p):
        w_p = rpm[p] * 2 * np.pi / 60.0  # (numpy's operations on the rpm, in its order)
        big_w2 = (h[p] * w_p) ** 2
        o = origin[p]
        g = gamma_o[p]
        om = omega_dot[p]
        df_dgo[:, :] = 0.0
        df_dw[:, :] = 0.0
        dmp_dgo[:, :] = 0.0
        dmp_dw[:, :] = 0.0
        f_mounts[:] = 0.0
        m_mounts[:] = 0.0
        for i in range(n_mounts):
            # f_i = K_i gamma_i / W^2 and its derivatives, summed in mount order
            pos = mount_pos[i]
            for a in range(3):
                r[a] = pos[a] - o[a]
            _skew(r, skew_r)
            _skew(pos, skew_p)
            for a in range(3):
                for b in range(3):
                    kw[a, b] = mount_stiff[i, a, b] / big_w2
            for a in range(3):
                gamma_i[a] = g[a] + _cross_cr(om, r, a)
            for a in range(3):
                f_i[a] = kw[a, 0] * gamma_i[0] + kw[a, 1] * gamma_i[1] + kw[a, 2] * gamma_i[2]
            for a in range(3):
                f_mounts[a] += f_i[a]
                m_mounts[a] += _cross_rc(pos, f_i, a)
            _matmul3_cr(kw, skew_r, dfi_dw)
            for a in range(3):
                for b in range(3):
                    dfi_dw[a, b] = -dfi_dw[a, b]
                    df_dgo[a, b] += kw[a, b]
                    df_dw[a, b] += dfi_dw[a, b]
            _matmul3_rc(skew_p, kw, tmp)
            for a in range(3):
                for b in range(3):
                    dmp_dgo[a, b] += tmp[a, b]
            _matmul3_rc(skew_p, dfi_dw, tmp)
            for a in range(3):
                for b in range(3):
                    dmp_dw[a, b] += tmp[a, b]
        spin = spin_j / (1j * h[p])
        rows[:, :] = 0.0
        for a in range(3):
            f_known[a] = force[p, a] + f_mounts[a]
            cog_o[a] = lin[a] - o[a]
        scale = mass  # the rows' mass factor (1 with the mass unknown), and F_unb's
        unb_scale = 1.0
        if mass_unknown:
            scale = 1.0
            unb_scale = mass
            for a in range(3):
                rows[a, i_inv] = -f_known[a]
        for a in range(3):
            # translation: scale (gamma_O + Omega' x (G - O)) (- F / m)
            yc[a] = (
                -g[a] + _cross_cr(om, o, a)
                if mass_unknown
                else f_known[a] - mass * g[a] + mass * _cross_cr(om, o, a)
            )
            # rotation: I Omega' + G x F_known = M_R + R x F + sum p_i x f_i - gyro
            yc[3 + a] = (
                moment[p, a]
                + _cross_rc(consts[4:7], force[p], a)
                + m_mounts[a]
                - spin * _cross_cr(om, consts[0:3], a)
            )
        _skew_into(om, rows, 0, 6, scale)
        _skew_into(f_known, rows, 3, 6, -1.0)
        rows[3, 0], rows[3, 3], rows[3, 4] = om[0], -om[1], -om[2]
        rows[4, 1], rows[4, 3], rows[4, 5] = om[1], -om[0], -om[2]
        rows[5, 2], rows[5, 4], rows[5, 5] = om[2], -om[0], -om[1]
        for a in range(3):
            for b in range(3):
                eye = 1.0 if a == b else 0.0
                sk_cog_o = _skew_entry(cog_o, a, b)
                if mass_unknown:
                    d_c[a, b] = eye - df_dgo[a, b] / mass
                    d_c[a, 3 + b] = -sk_cog_o - df_dw[a, b] / mass
                else:
                    d_c[a, b] = mass * eye - df_dgo[a, b]
                    d_c[a, 3 + b] = -mass * sk_cog_o - df_dw[a, b]
                sg_go = _dot3_rc(skew_g, a, df_dgo, b)
                sg_w = _dot3_rc(skew_g, a, df_dw, b)
                d_c[3 + a, b] = sg_go - dmp_dgo[a, b]
                d_c[3 + a, 3 + b] = inertia[a, b] - spin * skew_s[a, b] + sg_w - dmp_dw[a, b]
        if i_a >= 0 and h[p] == 1.0:
            # the residual unbalance: F_unb = a col_a + b col_b, z = a + i b
            for a in range(3):
                col_a = w_p**2 * c_it[a]
                col_b = 1j * col_a
                rows[a, i_a] = -col_a
                rows[a, i_b] = -col_b
                if i_qa >= 0:
                    rows[3 + a, i_qa] = -col_b
                    rows[3 + a, i_qb] = col_a
            for a in range(3):
                arm_a = _cross_unb(consts[7:10], lin[0:3], c_it, w_p**2, a)
                rows[3 + a, i_a] = -unb_scale * arm_a
                rows[3 + a, i_b] = -unb_scale * (1j * arm_a)
        if i_off >= 0:
            # d residual / d offset = D (-i h m)
            for a in range(6):
                acc = 0j
                for b in range(3):
                    acc += d_c[a, b] * (-1j * h[p] * g[b]) + d_c[a, 3 + b] * (-1j * h[p] * om[b])
                rows[a, i_off] = acc
            if has_measured > 0:
                for a in range(3):
                    rows[3 + a, i_off] += 1j * h[p] * measured[p, a]
        # real form: Re rows, then Im rows; D acts on [Re m, Im m]
        dm = d_meas[p]
        hp = H[p]
        for a in range(6):
            y[p, a] = yc[a].real
            y[p, 6 + a] = yc[a].imag
            for j in range(n):
                hp[a, j] = rows[a, j].real
                hp[6 + a, j] = rows[a, j].imag
            for b in range(6):
                dm[a, b] = d_c[a, b].real
                dm[a, 6 + b] = -d_c[a, b].imag
                dm[6 + a, b] = d_c[a, b].imag
                dm[6 + a, 6 + b] = d_c[a, b].real


def _skew(v: np.ndarray, out: np.ndarray) -> None:
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -v[2], v[1]
    out[1, 0], out[1, 1], out[1, 2] = v[2], 0.0, -v[0]
    out[2, 0], out[2, 1], out[2, 2] = -v[1], v[0], 0.0


def _skew_entry(v: np.ndarray, a: int, b: int) -> float:
    if a == b:
        return 0.0
    if a == 0:
        return -v[2] if b == 1 else v[1]
    if a == 1:
        return v[2] if b == 0 else -v[0]
    return -v[1] if b == 0 else v[0]


def _skew_into(v: np.ndarray, rows: np.ndarray, r0: int, c0: int, scale: float) -> None:
    for a in range(3):
        for b in range(3):
            rows[r0 + a, c0 + b] = scale * _skew_entry(v, a, b)


def _cross_cr(a: np.ndarray, b: np.ndarray, i: int) -> complex:
    """Component ``i`` of ``a x b``, ``a`` complex, ``b`` real: each part's products on
    their own (as :func:`_matmul3_cr`)."""
    if i == 0:
        return complex(a[1].real * b[2] - a[2].real * b[1], a[1].imag * b[2] - a[2].imag * b[1])
    if i == 1:
        return complex(a[2].real * b[0] - a[0].real * b[2], a[2].imag * b[0] - a[0].imag * b[2])
    return complex(a[0].real * b[1] - a[1].real * b[0], a[0].imag * b[1] - a[1].imag * b[0])


def _cross_rc(a: np.ndarray, b: np.ndarray, i: int) -> complex:
    """Component ``i`` of ``a x b``, ``a`` real, ``b`` complex (as :func:`_cross_cr`)."""
    if i == 0:
        return complex(a[1] * b[2].real - a[2] * b[1].real, a[1] * b[2].imag - a[2] * b[1].imag)
    if i == 1:
        return complex(a[2] * b[0].real - a[0] * b[2].real, a[2] * b[0].imag - a[0] * b[2].imag)
    return complex(a[0] * b[1].real - a[1] * b[0].real, a[0] * b[1].imag - a[1] * b[0].imag)


def _dot3_rc(a: np.ndarray, i: int, b: np.ndarray, j: int) -> complex:
    """``(a b)[i, j]``, ``a`` real, ``b`` complex (3, 3), its products summed in order."""
    re = a[i, 0] * b[0, j].real + a[i, 1] * b[1, j].real
    im = a[i, 0] * b[0, j].imag + a[i, 1] * b[1, j].imag
    return complex(re + a[i, 2] * b[2, j].real, im + a[i, 2] * b[2, j].imag)


def _cross_unb(point: np.ndarray, cog: np.ndarray, c_it: np.ndarray, w2: float, i: int) -> Any:
    """Component ``i`` of ``(point - cog) x (w2 c_it)``."""
    j, k = (i + 1) % 3, (i + 2) % 3
    return (point[j] - cog[j]) * (w2 * c_it[k]) - (point[k] - cog[k]) * (w2 * c_it[j])
