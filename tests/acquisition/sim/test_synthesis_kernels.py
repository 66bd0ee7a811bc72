"""The simulator's compiled carriers and Horner sum (acquisition.sim.kernels) against
closed forms and against the numpy path, over block splits."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from acquisition.sim import block_kernels, kernels
from acquisition.sim.amplitude_table import AmplitudeTable
from acquisition.sim.block_kernels import CHUNK, block_accel
from acquisition.sim.compact_design import DROP_RTOL
from acquisition.sim.sweep import RpmProfile, hold, ramp
from acquisition.sim.synthesis import half_orders, synthesize_accel
from acquisition.sim.tacho_synth import edge_times
from acquisition.stream import SampleBlock
from ptinertia.sources import open_source

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed")


def _carriers(profile: RpmProfile, rate: float, i0: int, i1: int, n_o: int) -> np.ndarray:
    """The kernel's rows for samples i0 .. i1 - 1, anchored as the simulator anchors them."""
    spacing = kernels.anchor_spacing(profile.rpm_max * 2 * np.pi / 60, rate)
    a0 = i0 - i0 % spacing
    anchor_phi = profile.phi(np.arange(a0, i1, spacing) / rate)
    rows = np.empty((2 * n_o, i1 - i0))
    phi = profile.phi(np.arange(i0, i1) / rate)
    kernels.carriers(phi, anchor_phi, i0 - a0, spacing, np.arange(n_o), rows)
    return rows


@pytest.mark.parametrize("rate", [25_600.0, 2_048.0])
def test_carriers_are_cos_and_sin_of_every_half_order(rate: float) -> None:
    """cos(h phi), sin(h phi) in closed form (angles kept below 64 rad, so that h phi itself
    rounds below 3e-14), to 1e-13; at 2048 Hz and 6000 rpm every sample is its own anchor."""
    profile = RpmProfile([ramp(900, 6000, 0.08), hold(6000, 0.03)])
    n = int(0.11 * rate)
    h = half_orders(6.0)
    phi = profile.phi(np.arange(n) / rate)
    assert phi.max() < 64
    rows = _carriers(profile, rate, 0, n, h.size)
    np.testing.assert_allclose(rows[0::2], np.cos(np.outer(h, phi)), rtol=0, atol=1e-13)
    np.testing.assert_allclose(rows[1::2], np.sin(np.outer(h, phi)), rtol=0, atol=1e-13)


def test_carriers_do_not_depend_on_the_block_split() -> None:
    """A sample's carriers come from its own index: random cuts give the same bits."""
    profile = RpmProfile([ramp(1500, 4500, 2.0)])
    rate, n = 25_600.0, 20_000
    whole = _carriers(profile, rate, 0, n, 12)
    cuts = [0, *sorted(np.random.default_rng(5).choice(n, 7, replace=False).tolist()), n]
    parts = [_carriers(profile, rate, a, b, 12) for a, b in itertools.pairwise(cuts)]
    assert np.array_equal(np.concatenate(parts, axis=1), whole)


def _stream(i3, block_s: float, monkeypatch, compiled: bool) -> dict[str, np.ndarray]:
    monkeypatch.setattr(kernels, "USE", compiled)
    tacho = {"phase_reference": "pressure"}
    src = open_source("sim", i3, duration_s=0.6, noise_snr_db=40.0, tacho=tacho, block_s=block_s)
    out: dict[str, list[np.ndarray]] = {}
    for item in src:
        if isinstance(item, SampleBlock):
            out.setdefault(item.group, []).append(item.data)
    return {g: np.concatenate(v, axis=1) for g, v in out.items()}


def test_compiled_stream_equals_the_numpy_stream_at_the_rounding_level(i3, monkeypatch) -> None:
    """Accelerations within 1e-13 of each channel's rms of the numpy path's, in 0.1 s and
    in 0.0137 s blocks; the pressure, rpm and noise (drawn by numpy either way) exact."""
    ref = _stream(i3, 0.1, monkeypatch, compiled=False)
    rms = np.sqrt(np.mean(ref["accel"] ** 2, axis=1))
    for block_s in (0.1, 0.0137):
        got = _stream(i3, block_s, monkeypatch, compiled=True)
        assert got.keys() == ref.keys()
        err = np.abs(got["accel"] - ref["accel"]).max(axis=1) / rms
        assert err.max() < 1e-13, err
        for g in ref.keys() - {"accel"}:
            assert np.array_equal(got[g], ref[g])


def test_motion_and_locate_are_the_numpy_methods_bit_for_bit(i3) -> None:
    """kernels.motion = RpmProfile.evaluate (and its rpm), kernels.locate =
    AmplitudeTable.locate, on a profile with a hold, a falling ramp and a step, times
    before, at, between and after its segments, and rpm at, beside and between the edges."""
    profile = RpmProfile(
        [ramp(1500, 4500, 0.3), hold(4500, 0.1), ramp(4500, 900, 0.2), ramp(2000, 2500, 0.1)]
    )
    edges = np.concatenate([profile.t_start, [profile.duration_s]])
    t = np.sort(
        np.concatenate(
            [np.linspace(-0.1, 0.8, 20001), edges, np.nextafter(edges, -1), np.nextafter(edges, 9)]
        )
    )
    seg, phi, omega, rpm = kernels.motion(profile, t)
    want_seg, want_phi, want_omega = profile.evaluate(t)
    assert np.array_equal(seg, want_seg) and np.array_equal(phi, want_phi)
    assert np.array_equal(omega, want_omega)
    assert np.array_equal(rpm, want_omega * (60.0 / (2.0 * np.pi)))
    table = open_source("sim", i3, profile=profile).table  # the i3's table on that profile
    rng = np.random.default_rng(2)
    for s in range(len(profile.segments)):
        e = table.edges[s]
        r = np.concatenate(
            [rng.uniform(800, 4600, 3000), e, np.nextafter(e, 0), np.nextafter(e, 1e4)]
        )
        for order in (r, np.sort(r)):
            j, u = kernels.locate(table, s, order)
            want_j, want_u = table.locate(s, order)
            assert np.array_equal(j, want_j) and np.array_equal(u, want_u)


def test_pressure_is_the_cycles_own_evaluation_bit_for_bit(i3) -> None:
    """kernels.pressure on a cycle's pieces = PressureCycle.__call__ (itself scipy's spline,
    tests/powertrain), over several cycles either side of zero, at every grid point, and
    at whole cycles (and the floats beside them) up to 1e6 rad."""
    cycle = open_source("sim", i3, tacho={"phase_reference": "pressure"}).model.pressure_cycle
    grid = cycle.pieces[0]
    rng = np.random.default_rng(3)
    near = np.concatenate([grid, np.nextafter(grid, -1), np.nextafter(grid, 99), -grid])
    # whole cycles and their neighbours up to 1e6 rad: the kernel's own exact mod
    cycles = np.arange(0.0, 80000.0, 3.0) * grid[-1]
    whole = np.concatenate([cycles, np.nextafter(cycles, 0), np.nextafter(cycles, 1e9)])
    far = rng.uniform(0.0, 1e6, 50000)
    phi = np.concatenate([rng.uniform(-40.0, 400.0, 50000), near, whole, far, [-0.0, -1e-300]])
    assert np.array_equal(kernels.pressure(cycle.pieces, phi), cycle(phi))


class _TwoOrderModel:
    """Orders 1 and 2 carry a rigid-body line, the others only a 1e-16 residue in rpm
    (what cancelling cylinders leave), every channel."""

    channel_names = ("a", "b", "c")

    def channel_amplitudes(self, rpm: np.ndarray, orders: np.ndarray) -> np.ndarray:
        w = np.asarray(rpm, dtype=float)[:, None] / 1000.0
        h = np.asarray(orders)[None, :]
        x = (1 + 0.3j) * w**2 / (1 + 0.2 * w - 0.05j * w**2) * np.exp(1j * h)
        x = np.where(np.isin(h, (1.0, 2.0)), x, 1e-16 * w**3 * np.exp(0.7j * h))
        return x[:, :, None] * np.array([1.0, -0.5j, 2.0])[None, None, :]

    def pressure(self, phi: np.ndarray) -> None:
        return None


def test_orders_without_rpm_dependence_worth_keeping_are_dropped_within_their_bound() -> None:
    """The residue orders lose their u^1.. rows, the samples move within DROP_RTOL of each
    channel's largest amplitude (against the numpy path, which keeps every term), and a
    model whose orders all carry something keeps them all (FakeModel in test_simulator)."""
    profile = RpmProfile([ramp(1000, 5000, 1.0), hold(5000, 0.2), ramp(5000, 3000, 0.3)])
    orders = half_orders(6.0)
    table = AmplitudeTable(_TwoOrderModel(), orders, profile)
    design = table.compact
    assert design.n_kept == 2 and set(design.position[[1, 3]]) == {0, 1}
    assert design.dropped_bound <= DROP_RTOL
    t = np.arange(30000) / 20000.0  # the ramps and the hold between them
    fast = synthesize_accel(table, profile, t, compiled=True)
    ref = synthesize_accel(table, profile, t, compiled=False)
    largest = np.abs(table.coeffs[0][:, 0]).max(axis=(0, 1))
    assert np.max(np.abs(fast - ref).max(axis=1) / largest) < DROP_RTOL


def block_case(n_k: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """block_accel on random operands of the i3's shapes (9 channels, 12 half orders of which
    8 keep their rpm dependence, ``n_k - 1`` powers of ``u``) over 9000 samples in interval
    runs longer and shorter than a chunk, and the reference: numpy's product chunk by chunk
    and the Horner sum highest power first. Returns (kernel's, reference)."""
    rng = np.random.default_rng(seed)
    n_ch, n_o, kept, n, first = 9, 12, 16, 9000, 37
    constant = rng.standard_normal((4, n_ch, 2 * n_o))
    varying = rng.standard_normal((4, (n_k - 1) * n_ch, kept))
    rows = rng.standard_normal((2 * n_o, first + n + 5))
    j = np.repeat(np.array([2, 0, 3, 1, 3]), [3000, 17, 1100, 2900, 1983])
    u = rng.uniform(-1, 1, n)
    got = np.full((n_ch, first + n), np.nan)
    block_accel(rows, first, j, u, constant, varying, kept, got)
    return got, reference_block(rows, first, j, u, constant, varying, kept, CHUNK)


def reference_block(rows, first, j, u, constant, varying, kept, chunk) -> np.ndarray:
    """What block_accel computes, by numpy: per interval run and ``chunk`` samples, the
    product with the carriers, then the Horner sum in ``u`` highest power first;
    (n_ch, first + j.size), NaN before ``first``."""
    n_ch = constant.shape[1]
    want = np.full((n_ch, first + j.size), np.nan)
    cuts = [0, *(np.flatnonzero(np.diff(j)) + 1).tolist(), j.size]
    for a, b in itertools.pairwise(cuts):
        d0, dk = constant[j[a]], varying[j[a]]
        for c0 in range(a, b, chunk):
            c1 = min(b, c0 + chunk)
            y = [d0 @ rows[:, first + c0 : first + c1]]
            if dk.shape[0]:
                y.append(dk @ rows[:kept, first + c0 : first + c1])
            y = np.concatenate(y).reshape(-1, n_ch, c1 - c0)
            acc = y[-1].copy()
            for k in range(y.shape[0] - 2, -1, -1):
                acc = acc * u[c0:c1] + y[k]
            want[:, first + c0 : first + c1] = acc
    return want


@pytest.mark.parametrize("n_k", [1, 3, 5])
def test_block_kernel_is_the_chunked_numpy_product_and_horner(n_k: int) -> None:
    """block_accel (every interval and chunk in one compiled call, numba's ``np.dot`` on
    scipy's BLAS) against numpy's product and Horner sum, degrees 0, 2 and 4 (the default
    one-pass branch and the general one): within rounding whatever the BLAS threads (a
    product split over threads rounds its own way), NaN-free and every sample written."""
    got, want = block_case(n_k, seed=n_k)
    assert np.isnan(got[:, :37]).all() and not np.isnan(got[:, 37:]).any()
    np.testing.assert_allclose(got[:, 37:], want[:, 37:], rtol=1e-12, atol=1e-12)


def test_block_kernel_is_numpy_bit_for_bit_with_one_blas_thread() -> None:
    """With one BLAS thread (as the CLI, the benchmarks and the Dask workers it starts run),
    block_accel gives numpy's bits exactly: checked in a process of its own, whose BLAS
    libraries read OPENBLAS_NUM_THREADS=1 when they load."""
    script = (
        "import sys; sys.path.insert(0, sys.argv[1]); import numpy as np\n"
        "from test_synthesis_kernels import block_case\n"
        "for n_k in (1, 3, 5):\n"
        "    got, want = block_case(n_k, seed=n_k)\n"
        "    assert np.array_equal(got, want, equal_nan=True), n_k\n"
        "print('same bits')\n"
    )
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", script, str(Path(__file__).parent)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0 and "same bits" in done.stdout, done.stderr[-2000:]


def test_block_kernel_on_the_i3s_design(i3) -> None:
    """block_accel on the i3's own operands over a sweep crossing table intervals: the
    compiled path's samples as synthesize_accel makes them, within rounding of the
    reference product and Horner sum."""
    profile = RpmProfile([ramp(900, 4800, 0.25), hold(4800, 0.05), ramp(4800, 1200, 0.2)])
    table = open_source("sim", i3, profile=profile).table
    design = table.compact
    rate = 25_600.0
    n = int(profile.duration_s * rate)
    rows = _carriers(profile, rate, 0, n, table.orders.size)[design_rows(design)]
    seg, _, _, rpm = kernels.motion(profile, np.arange(n) / rate)
    kept, n_ch = 2 * design.n_kept, table.coeffs[0].shape[3]
    crossed = 0
    for s in range(len(profile.segments)):
        idx = np.flatnonzero(seg == s)
        a0 = int(idx[0])
        j, u = kernels.locate(table, s, rpm[idx])
        crossed += int(np.count_nonzero(np.diff(j)))
        got = np.full((n_ch, n), np.nan)
        block_accel(rows, a0, j, u, design.constant[s], design.varying[s], kept, got)
        # (the reference's product over whole runs: a check of the chunking too)
        want = reference_block(rows, a0, j, u, design.constant[s], design.varying[s], kept, n)
        scale = np.abs(want[:, idx]).max()
        np.testing.assert_allclose(got[:, idx], want[:, idx], rtol=0, atol=1e-13 * scale)
    assert crossed >= 3  # the runs did cross intervals


def design_rows(design) -> np.ndarray:
    """Carrier rows in the compact design's order (kept orders first): row pair
    ``position[k]`` holds order ``k``'s ``cos``, ``sin``."""
    order = np.empty(2 * design.position.size, dtype=np.intp)
    order[0::2] = np.argsort(design.position) * 2
    order[1::2] = np.argsort(design.position) * 2 + 1
    return order


def test_the_fused_kernels_name_their_helpers_hash() -> None:
    """numba's cache watches a kernel's own file only: block_kernels carries the sha256 of
    the kernels it calls (acquisition/sim/kernels.py), so editing them changes it (else a
    warm cache runs the old machine code and every test here compares that)."""
    assert block_kernels.helpers_sha256() == block_kernels.HELPERS_SHA256, (
        "a helper of acquisition/sim/block_kernels.py changed: set HELPERS_SHA256 there to "
        f"{block_kernels.helpers_sha256()!r} so numba's cache is rebuilt"
    )


@pytest.mark.parametrize(
    "i0, n, spans", [(0, 5000, 1), (3, 777, 1), (12_345, 12_800, 3), (17_000, 9000, 2)]
)
def test_accel_block_is_the_compiled_path_step_by_step_bit_for_bit(
    i3, i0: int, n: int, spans: int
) -> None:
    """accel_block (motion, anchors, carriers and products in two calls) gives the bits of
    kernels.motion, the anchors' angles, and synthesize_accel on the compiled path, for
    blocks that start off the anchor grid and span up to three sweep segments."""
    profile = RpmProfile([ramp(900, 4800, 0.5), hold(4800, 0.2), ramp(4800, 1200, 0.5)])
    table = open_source("sim", i3, profile=profile).table
    rate = 25_600.0
    spacing = kernels.anchor_spacing(profile.rpm_max * 2 * np.pi / 60, rate)
    got = block_kernels.accel_block(table, profile, rate, i0, i0 + n, spacing)
    t = np.arange(i0, i0 + n) / rate
    seg, phi, omega, _ = kernels.motion(profile, t)
    a0 = i0 - i0 % spacing
    anchors = (kernels.motion(profile, np.arange(a0, i0 + n, spacing) / rate)[1], i0 - a0, spacing)
    x = synthesize_accel(table, profile, t, (seg, phi, omega), anchors, compiled=True)
    for a, b in zip(got, (t, seg, phi, omega, x), strict=True):
        assert np.array_equal(a, b)
    assert len(set(seg.tolist())) == spans  # the segments meant


def test_compiled_edge_times_are_the_numpy_ones_bit_for_bit() -> None:
    """block_kernels.edge_times = tacho_synth.edge_times (angles_between, t_of_phi) on a
    profile with a hold, a falling ramp and a step, windows across segment ends, before the
    start and after the end, for a 60-2 wheel's angles and a single cam edge."""
    profile = RpmProfile(
        [ramp(1500, 4500, 0.3), hold(4500, 0.1), ramp(4500, 900, 0.2), ramp(2000, 2500, 0.1)]
    )
    wheel = np.arange(58) * (2 * np.pi / 60) + 0.013
    edges = np.concatenate([[-0.05], np.linspace(0, 0.7, 45), profile.t_start, [0.75]])
    windows = [(a, b) for a, b in itertools.pairwise(np.sort(edges)) if b > a]
    total = 0
    for angles, period in ((wheel, 2 * np.pi), (np.array([1.1]), 4 * np.pi)):
        for t_a, t_b in windows:
            want = edge_times(profile, angles, period, t_a, t_b)
            got = block_kernels.edge_times(profile, angles, period, t_a, t_b)
            assert np.array_equal(got, want), (t_a, t_b)
            total += want.size
    assert total > 500  # the windows held edges
