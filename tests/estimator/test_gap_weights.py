"""A channel whose window lost samples weighs less in the rigid fit (its variance factor).

The order tracker fills or fits the samples a lost CAN frame took (``dsp.gap_fit``) and
says by how much each channel's variance grew (``OrderFrame.variance_factor``); the rigid
fit weighs the channel by the inverse. Checked against weighted least squares by
``numpy.linalg.lstsq``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from support.estimator_harness import Body, Frame, frames, make_setup

from estimator.channel_fits import VARIANCE_STEP, ChannelFits
from estimator.kinematics import design_matrix


def _select(fits: ChannelFits, frame: Frame) -> tuple[str | None, tuple | None]:
    """The estimator's channel choice for one frame: its fit geometry and fitted readings."""
    (used, cols, _, _, steps), *_ = fits.screen([frame])
    reason, fitter = fits.choose(used, steps)
    return reason, None if fitter is None else (fitter, frame.amplitudes[:, cols[used]])


def test_the_fit_weighs_a_channel_by_its_variance_factor():
    body = Body()
    setup = make_setup(body)
    frame = next(frames(body, np.array([3000.0])))
    rng = np.random.default_rng(2)
    amps = frame.amplitudes + 0.05 * (rng.normal(size=frame.amplitudes.shape) + 0j)
    factor = np.ones(9)
    factor[[1, 5]] = [1.3, 1.8]
    lossy = dataclasses.replace(frame, amplitudes=amps, variance_factor=factor)
    fits = ChannelFits(setup)
    reason, fitted = _select(fits, lossy)
    assert reason is None and fitted is not None
    fitter, readings = fitted
    # the weights, rounded to VARIANCE_STEP in log: close to 1 / factor
    w = fitter.sw**2 / fitter.sw[0] ** 2
    np.testing.assert_allclose(w, 1.0 / factor, rtol=VARIANCE_STEP)
    # the motion is the weighted least-squares fit with those weights
    j = design_matrix(setup.positions, setup.directions, fitter.origin)
    sw = fitter.sw[:, None]
    ref = np.linalg.lstsq(j * sw, readings.T * sw, rcond=None)[0].T  # (orders, 6)
    motion = fitter.fit(readings)
    np.testing.assert_allclose(np.hstack((motion.gamma_o, motion.omega_dot)), ref, atol=1e-10)
    # ... which differs from the equal-weight fit of the same readings
    plain, _ = _select(fits, dataclasses.replace(lossy, variance_factor=None))[1]
    assert np.abs(plain.fit(readings).omega_dot - motion.omega_dot).max() > 1e-6
    # a frame without holes gets the shared (cached) geometry
    assert _select(fits, dataclasses.replace(lossy, variance_factor=None))[1][0] is plain
