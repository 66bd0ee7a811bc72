"""The excitation inputs' derivatives (ptinertia/to_model_inputs.py) of a batch of
(frame, order) pairs: their order index and speeds are shared by the inputs and kept
for the batches that come again, and every pair gets the bits of its own call, whatever
was asked before."""

from __future__ import annotations

import numpy as np

from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_estimator import estimator_setup


def test_each_pair_gets_its_own_derivative_whatever_came_before() -> None:
    setup = estimator_setup(load_bench(EXAMPLES_DIR / "i3-bench.toml"))
    inputs = [i for i in setup.model_inputs if i.d_excitation is not None]
    assert len(inputs) >= 2
    h = np.array([1.0, 1.5, 2.0, 1.0, 2.0, 1.5])
    rpm = np.array([1200.0, 1200.0, 1200.0, 3100.0, 3100.0, 5400.0])
    by_speed = []
    for inp in inputs:
        d = inp.d_excitation
        assert d is not None
        force, moment = d(rpm, h)
        other = d(rpm[::-1].copy() + 7.0, np.array([0.5, 1.0, 3.0, 1.0, 0.5, 2.0]))
        assert not np.array_equal(other[1], moment)
        again = d(rpm, h)
        assert np.array_equal(again[0], force) and np.array_equal(again[1], moment)
        for j in range(len(h)):
            one_f, one_m = d(rpm[j : j + 1], h[j : j + 1])
            assert np.array_equal(one_f[0], force[j]) and np.array_equal(one_m[0], moment[j])
        # the same order at two speeds (an inertia part grows with their square)
        by_speed.append(not np.array_equal(moment[0], moment[3]))
    assert any(by_speed) and not all(by_speed)  # the masses' and the gas's
    # the inputs differ from one another (each its own cached parts)
    firsts = [inp.d_excitation(rpm, h)[1] for inp in inputs]  # type: ignore[misc]
    assert not np.array_equal(firsts[0], firsts[1])


def test_the_split_parts_give_each_pair_its_derivative() -> None:
    """``split`` (what the compiled model-input rows gather: estimator/compiled_model_rows)
    against the call: ``gas + omega^2 unit`` of the pair's order is the call's value."""
    setup = estimator_setup(load_bench(EXAMPLES_DIR / "i3-bench.toml"))
    inputs = [i.d_excitation for i in setup.model_inputs if i.d_excitation is not None]
    h = np.array([2.0, 1.0, 1.5, 1.0])
    rpm = np.array([1500.0, 2250.0, 2250.0, 4100.0])
    w2 = (rpm * 2 * np.pi / 60.0) ** 2
    for d in inputs:
        key = tuple(sorted(set(h.tolist())))
        gas, unit = d.split(key)  # type: ignore[union-attr]
        assert gas.shape == unit.shape == (len(key), 2, 3)
        force, moment = d(rpm, h)
        at = [key.index(x) for x in h]
        both = gas[at] + w2[:, None, None] * unit[at]
        np.testing.assert_allclose(both[:, 0], force, rtol=1e-14, atol=0)
        np.testing.assert_allclose(both[:, 1], moment, rtol=1e-14, atol=0)
