"""The compiled frame assembly (dsp.kernels: window sums, amplitudes, speed and leakage
figures, the leakage correction's coupling) against the numpy path: the same bits (the
coupling within 1e-12), and whole frames within 1e-12."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.stream import EdgeBlock, SampleBlock
from dsp import assemble, kernels
from dsp.config import OrderTrackerConfig
from dsp.driver import track_items
from dsp.frame_figures import frame_figures_numpy
from dsp.frames import OrderFrame
from dsp.leakage import coupling, real_coupling
from dsp.sum_rows import window_sums
from dsp.sum_sets import SumSet
from dsp.sums import add_sample_sets
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig
from dsp.window_amplitudes import window_amplitudes

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed")


def _rows(fpr: int) -> tuple[dict[int, np.ndarray], int]:
    """Segment rows (dsp.sums, numpy) of 4 channels with clipped samples, and n_ch."""
    rng = np.random.default_rng(7)
    n = 12_000
    phi = 50.0 + np.cumsum(rng.uniform(0.004, 0.02, n))
    omega = rng.uniform(150.0, 500.0, n)
    x = rng.standard_normal((4, n)) * 2.0
    x[:, rng.integers(0, n, 5)] = 9.0
    k2 = np.array([1, 2, 3, 4])
    sets = [SumSet({}, [x[:, :5000], x[:, 5000:]], k2, 8.5)]
    return add_sample_sets(sets, phi, omega, 1001, 25_600.0, fpr, 45.0, compiled=False)[0], 4


@pytest.mark.parametrize(
    ("k2", "n_ch", "fpr"),
    [(range(1, 9), 9, 1), (range(0, 19), 1, 1), (range(1, 4), 2, 2), ([2], 3, 4)],
)
def test_compiled_coupling_agrees_with_numpy(k2, n_ch, fpr):
    """The leakage correction's coupling (dsp.fused_ramps: one real product per frame and
    channel, columns padded to eight lanes) against numpy's complex products of
    dsp.leakage.ramp_correction: within 1e-12 of the largest correction, for eight orders
    (two columns of lanes), the spectrum's 19 (five, the last part padding), three and
    one; NaN amplitudes stay NaN, a frame with zero ramps keeps its amplitudes exactly."""
    rng = np.random.default_rng(n_ch)
    k2 = np.array(k2)
    same, image = coupling(k2, fpr, 45.0)
    f, n = 7, k2.size
    phase = rng.integers(0, 2 * fpr, f)
    b = rng.standard_normal((f, n, n_ch)) + 1j * rng.standard_normal((f, n, n_ch))
    b[2] = 0.0
    x = rng.standard_normal((f, n, n_ch)) + 1j * rng.standard_normal((f, n, n_ch))
    x[3, 0, 0] = np.nan
    corr = same[phase] @ b + image[phase] @ np.conj(b)
    want = x - corr
    flat, m8 = real_coupling(same, image)
    assert m8 % 8 == 0 and m8 >= 2 * n
    got = np.empty_like(x)
    kernels.apply_ramps(x, b, phase, flat, m8, got, np.empty(m8))
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    assert np.isnan(want).sum() == 1
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(corr).max())
    np.testing.assert_array_equal(got[2], x[2])


@pytest.mark.parametrize("fpr", [1, 2, 4])
def test_compiled_window_sums_give_the_numpy_bits(fpr, monkeypatch):
    """The window sums of consecutive frames (dsp.kernels.window_sums: the loops of
    dsp.sum_rows.add_windows, compiled and as plain Python) against dsp.sum_rows.window_sums:
    the same bits, with missing segments (a dropout), windows past the data (no samples:
    NaN mean square) and segments whose count was zeroed (a positive power over no
    samples: inf, as numpy divides)."""
    rows, n_ch = _rows(fpr)
    k2 = np.array([1, 2, 3, 4])
    ms = sorted(rows)
    a = len(ms) // 3
    gap = (ms[a], ms[a + 2 * fpr + 2])  # a dropout longer than a window
    rows = {m: r for m, r in rows.items() if not gap[0] <= m < gap[1]}
    h = (next(iter(rows.values())).size - n_ch) // 2
    for m in ms[-3 * fpr :]:
        rows[m] = rows[m].copy()
        rows[m][h - 1] = 0.0  # n2: no samples counted, s2 > 0 stays
    j0, j1 = ms[0] + fpr, ms[-1] + 2
    want = window_sums(rows, j0, j1, fpr, n_ch, k2.size)
    assert np.isnan(want[2]).any() and np.isinf(want[2]).any() and want[3].any()
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(kernels, "_jit", lambda fn: fn)
        got = kernels.window_sums(rows, j0, j1, fpr, n_ch, k2.size)
        for w, g in zip(want, got, strict=True):
            np.testing.assert_array_equal(g, w)


def test_compiled_window_amplitudes_give_the_numpy_bits(monkeypatch):
    """A group's amplitudes, mean squares and flags from the compiled window sums
    (dsp.kernels.group_amplitudes) against the numpy path's on the same tracker states,
    and the spectrum channel's amplitudes: the same bits, through clipped samples, a tacho
    dropout (unusable frames) and a lost block (holes: the numpy path's refit for both)."""
    rng = np.random.default_rng(11)
    contents = [random_content(rng) for _ in range(3)]
    bench = SyntheticBench(Ramp(3000.0, 3000.0, 3.0), contents, tdc_after_gap_deg=84.0)
    # the spectrum's too, uncorrected (the compiled ramps round their own way)
    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=84.0),
        orders=(1.0, 1.5, 2.0),
        clip_level=100.0,
        spectrum_channel="a2",
        leakage_correction=False,
    )

    def spoiled():
        for item in bench.items(3.0, block_s=0.1):
            if isinstance(item, EdgeBlock) and 1.0 < item.times_s[0] < 1.35:
                continue  # a tacho dropout
            if isinstance(item, SampleBlock) and item.first_index == 512 * 5:
                data = item.data.copy()
                data[2, 200] = 1e3  # clipped
                item = SampleBlock(item.group, item.first_index, data)
            if isinstance(item, SampleBlock) and item.first_index == 512 * 20:
                continue  # a lost block
            yield item

    calls, spectra = [], []

    def capture(st, js):
        calls.append((st, js))
        return window_amplitudes(st, js)

    def capture_spectrum(*args):
        spectra.append(args)
        return spectrum(*args)

    spectrum = assemble._spectrum
    monkeypatch.setattr(assemble, "window_amplitudes", capture)
    monkeypatch.setattr(assemble, "_spectrum", capture_spectrum)
    monkeypatch.setattr(kernels, "USE", False)
    assert [x for x in track_items(bench.layout, spoiled(), config) if isinstance(x, OrderFrame)]
    seen = set()
    for st, js in calls:
        want = window_amplitudes(st, js)
        monkeypatch.setattr(kernels, "USE", True)
        got = window_amplitudes(st, js)
        monkeypatch.setattr(kernels, "USE", False)
        for name, value in want.items():
            np.testing.assert_array_equal(got[name], value, err_msg=name)
        seen |= {f for flags in want["flags"] for f in flags}
        seen |= {"unusable"} if want["tacho_bad"].any() else set()
    assert {"clipped", "unusable", "no_tacho"} <= seen, seen
    nan_frames = 0
    for args in spectra:
        want = spectrum(*args)[1]
        monkeypatch.setattr(kernels, "USE", True)
        got = spectrum(*args)[1]
        monkeypatch.setattr(kernels, "USE", False)
        assert want.tobytes() == got.tobytes()  # NaN's bits too: NaN + 0j where unusable
        nan_frames += np.isnan(want).all(axis=(1, 2)).sum()
    assert 0 < nan_frames < sum(args[1].size for args in spectra)


def _outputs(times, omegas, x, ms, corrected, out, spectrum, signs, spectrum_signs, codes):
    """dsp.kernels.frame_outputs's results (rpm, rpm change, leak, turned orders, turned
    spectrum, angles, codes) for the figures' and the codes' arguments."""
    f, _, n_ch = x.shape
    js, parity, spacing, steps, chains, ambiguous, rpm_range, ok, correcting, variance = codes
    n_spec = min(spectrum.shape[1], spectrum_signs.shape[1])  # the spectrum's first orders
    turned, spec = np.empty((f, out.size, n_ch), complex), np.empty((f, n_spec), complex)
    rpm, rpm_change, leak = np.empty(f), np.empty(f), np.empty((f, n_ch))
    angles, code = np.empty(f), np.empty(f, np.int64)
    kernels.frame_outputs(
        times, omegas, x, np.abs(x), ms, corrected, out, signs, spectrum, spectrum_signs,
        js, parity, spacing, steps, chains, ambiguous, *rpm_range, ok, correcting, variance,
        turned, spec, rpm, rpm_change, leak, angles, code,
    )  # fmt: skip
    return rpm, rpm_change, leak, turned, spec, angles, code


def _code_args(rng, f, n_ch, steps, correcting):
    """Frames' indices, parities, chains, flags and variance factors with every flag bit set
    somewhere and left out somewhere (a NaN variance factor, an rpm on the range's edge)."""
    js = np.arange(1_000_003, 1_000_003 + f)
    parity = rng.integers(0, steps + 1, f)
    chains = rng.integers(-1, 3, f)
    ambiguous = rng.random(f) < 0.3
    ok = rng.random((f, n_ch)) < 0.8
    variance = np.ones((f, n_ch))
    variance[[4, 9], [1, 3]] = 1.7, np.nan
    spacing = 2 * np.pi / 4
    return js, parity, spacing, steps, chains, ambiguous, (600.0, 6000.0), ok, correcting, variance


@pytest.mark.parametrize("compiled", [True, False])
def test_compiled_frame_figures_give_the_numpy_bits(compiled, monkeypatch):
    """rpm, rpm change and leakage figure (dsp.frame_figures.frame_outputs through dsp.kernels,
    compiled and as plain loops) against dsp.frame_figures.frame_figures_numpy: the same
    bits, also where numpy divides by zero (a window of no duration, channels with nothing
    in the output orders), where NaN comes in (a time, amplitudes) and where the orders
    explain more than the mean square."""
    rng = np.random.default_rng(21)
    f, n_int, n_ch = 40, 8, 5
    times = np.sort(rng.uniform(0.0, 1.0, (f, 3)), axis=1)
    times[3, 2] = times[3, 0]  # no duration: rpm inf
    times[4, 0] = np.nan
    omegas = rng.uniform(100.0, 400.0, (f, 3))
    x = rng.standard_normal((f, n_int, n_ch)) + 1j * rng.standard_normal((f, n_int, n_ch))
    out = np.array([2, 3, 4])
    x[5, :, 1] = 0.0  # nothing at all: 0 / 0
    x[6, out, 2] = 0.0  # nothing in the output orders: inf
    x[7, 1, 3] = np.nan
    ms = 0.5 * np.sum(np.abs(x) ** 2, axis=1) * rng.uniform(0.9, 1.3, (f, n_ch))
    corrected = rng.random((f, n_ch)) < 0.6
    corrected[6, 2] = False  # the internal orders count: x / 0
    corrected[7, 3] = True  # only the unexplained power (NaN) counts
    want = frame_figures_numpy(times, omegas, x, ms, corrected, out)
    if not compiled:
        monkeypatch.setattr(kernels, "_jit", lambda fn: fn)
    signs, no_spectrum = np.ones((2, out.size)), np.empty((0, 0, 1), complex)
    codes = _code_args(rng, f, n_ch, 1, True)
    got = _outputs(times, omegas, x, ms, corrected, out, no_spectrum, signs, signs, codes)
    for w, g in zip(want, got[:3], strict=True):
        np.testing.assert_array_equal(g, w)
    leak = want[2]
    assert np.isinf(want[0]).any() and np.isnan(leak[5, 1]) and np.isinf(leak[6, 2])
    assert (ms < 0.5 * np.sum(np.abs(x) ** 2, axis=1)).any()


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("steps", [1, 3])
def test_compiled_frame_codes_give_the_numpy_bits(compiled, steps, monkeypatch):
    """Each frame's angle and flag bits (dsp.frame_figures.frame_outputs through dsp.kernels,
    compiled and as plain loops) against dsp.frame_figures.frame_codes_numpy: the same
    angles bit for bit, the same codes, with every flag set somewhere and left out
    somewhere (a NaN variance factor counts as lost samples, an rpm on the range's edge
    is in it), with and without the leakage correction."""
    from dsp.frame_figures import frame_codes_numpy

    rng = np.random.default_rng(5)
    f, n_ch = 60, 4
    if not compiled:
        monkeypatch.setattr(kernels, "_jit", lambda fn: fn)
    for correcting in (True, False):
        codes = _code_args(rng, f, n_ch, steps, correcting)
        js, parity, spacing, steps, chains, ambiguous, rpm_range, ok, _, variance = codes
        corrected = rng.random((f, n_ch)) < 0.7
        # window ends that give these rpm: 720 deg in 120 / rpm s
        rpm = rng.uniform(500.0, 7000.0, f)
        rpm[:2] = 600.0, 6000.0  # the range's ends
        rpm[2] = np.nan
        times = np.column_stack((np.zeros(f), np.full(f, 0.01), 120.0 / rpm))
        x = np.ones((f, 3, n_ch), complex)
        ms, out = np.ones((f, n_ch)), np.array([0, 2])
        got = _outputs(
            times, np.ones((f, 3)), x, ms, corrected, out, np.empty((0, 0, 1), complex),
            np.ones((2, 2)), np.ones((2, 0)), codes,
        )  # fmt: skip
        rpm, angles, code = got[0], got[5], got[6]
        want_angles, want_codes = frame_codes_numpy(
            js, parity, spacing, steps, chains, ambiguous, rpm, rpm_range, ok, corrected,
            correcting, variance,
        )  # fmt: skip
        np.testing.assert_array_equal(angles, want_angles)
        assert angles.tobytes() == want_angles.tobytes()
        np.testing.assert_array_equal(code, want_codes)
        for bit in (16, 8, 4, 2) + ((1,) if correcting else ()):
            assert 0 < np.count_nonzero(code & bit) < f
        assert code[2] & 2 == 0 and code[0] & 2 and code[1] & 2
        assert code[4] & 16 and code[9] & 16
        if not correcting:
            assert not (code & 1).any()


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("steps", [1, 3])
def test_compiled_turn_to_the_crank_angle_gives_the_numpy_bits(compiled, steps, monkeypatch):
    """The output orders and the spectrum turned from the wheel angle to the crank angle
    (dsp.frame_figures.frame_outputs through dsp.kernels, compiled and as plain loops)
    against numpy's products with dsp.frame_constants.rotation: the same bits with a
    wheel (signed zeros, NaN and inf included), its spectrum's mean then made real;
    copied unturned with N pulses, the mean too (the caller turns them in numpy, then
    makes the mean real: the old order, which a NaN or infinite imaginary part shows)."""
    from dsp.frame_constants import rotation

    rng = np.random.default_rng(9)
    f, n_int, n_ch, n_spec = 30, 8, 4, 7
    x = rng.standard_normal((f, n_int, n_ch)) + 1j * rng.standard_normal((f, n_int, n_ch))
    x[3, 2, 1] = complex(-0.0, 0.0)
    x[4, 3, 2] = complex(np.inf, 1.0)
    x[5, 2, 0] = complex(1.0, np.nan)
    shape = (f, n_spec + 2, 1)  # the spectrum's internal orders: more than it gives out
    spectrum = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    spectrum[6, 1, 0] = complex(0.0, -np.inf)
    spectrum[7, 0, 0] = complex(1.0, np.nan)  # a mean the turn must see whole
    k2, k = np.array([2, 3, 4]), np.arange(n_spec)
    out = np.array([1, 2, 3])  # k2's rows among the internal orders
    both = np.arange(2)
    signs = np.where((k2[None, :] * both[:, None]) % 2 == 1, -1.0, 1.0)
    spectrum_signs = np.where((k[None, :] * both[:, None]) % 2 == 1, -1.0, 1.0)
    if not compiled:
        monkeypatch.setattr(kernels, "_jit", lambda fn: fn)
    codes = _code_args(rng, f, n_ch, steps, True)
    parity = codes[1]
    times, omegas, ms = np.ones((f, 3)), np.ones((f, 3)), np.ones((f, n_ch))
    corrected = np.ones((f, n_ch), bool)
    with np.errstate(invalid="ignore"):
        got = _outputs(times, omegas, x, ms, corrected, out, spectrum, signs, spectrum_signs, codes)
        turned, spec = got[3], got[4]
        if steps == 1:
            want = x[:, out, :] * rotation(parity, k2, steps, signs)[:, :, None]
            want_spec = spectrum[:, :n_spec, 0] * rotation(parity, k, steps, spectrum_signs)
        else:
            want, want_spec = x[:, out, :], spectrum[:, :n_spec, 0].copy()
    if steps == 1:
        want_spec[:, 0] = want_spec[:, 0].real
    assert turned.tobytes() == want.tobytes()
    assert spec.tobytes() == want_spec.tobytes()
    if steps == 1:
        assert (parity % 2 == 1).any() and (turned != x[:, out, :]).any()
