"""The leakage correction's coupling matrices (dsp.leakage) against their definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsp import leakage


def test_kappa_of_an_untapered_window_is_the_closed_form() -> None:
    # kappa(m) = int u e^{2 pi i m u} du / int du over [-1/2, 1/2]: (-1)^m / (2 pi i m)
    m = np.arange(1, 21, dtype=float)
    expected = (-1.0) ** m / (2j * math.pi * m)
    np.testing.assert_allclose(leakage.kappa(m, 1e-12), expected, rtol=1e-9)


@pytest.mark.parametrize(
    "k2, frames_per_rev, taper_deg",
    [([2, 3, 4], 4, 90.0), (list(range(17)), 2, 45.0), ([1, 2, 3, 4, 6, 8, 12], 8, 180.0)],
)
def test_coupling_is_kappa_of_each_pair_turned_by_the_frame_phase(
    k2: list[int], frames_per_rev: int, taper_deg: float
) -> None:
    # element by element: each (h, h') pair's own kappa, no sharing of distinct differences
    same, image = leakage.coupling(np.array(k2), frames_per_rev, taper_deg)
    period = 2 * frames_per_rev
    frac = math.radians(taper_deg) / (4.0 * math.pi)
    for j in range(period):
        for row, h in enumerate(k2):
            for col, g in enumerate(k2):
                d_same, d_image = g - h, -(g + h)
                want_same = (
                    0.0
                    if row == col
                    else np.exp(2j * np.pi * d_same * j / period)
                    * (leakage.kappa(np.array([float(d_same)]), frac)[0])
                )
                want_image = (
                    np.exp(2j * np.pi * d_image * j / period)
                    * (leakage.kappa(np.array([float(d_image)]), frac)[0])
                )
                assert abs(same[j, row, col] - want_same) <= 1e-14
                assert abs(image[j, row, col] - want_image) <= 1e-14
