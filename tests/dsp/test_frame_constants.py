"""dsp.frame_constants.rotation: the wheel's sign table against dsp.cycle.offset_rotation."""

import numpy as np

from dsp import cycle
from dsp.frame_constants import rotation


def test_the_sign_table_gives_offset_rotations_numbers_for_any_parity():
    k2 = np.array([0, 1, 2, 3, 4, 7], dtype=np.int64)
    signs = cycle.offset_rotation(np.arange(2), k2, 1)
    parity = np.array([0, 1, 2, 3, -1, -2, 5], dtype=np.int64)
    got = rotation(parity, k2, 1, signs)
    want = cycle.offset_rotation(parity, k2, 1)
    assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
    assert set(np.unique(got)) == {-1.0, 1.0}  # half orders flip, whole ones do not


def test_pulses_keep_the_complex_rotation():
    k2 = np.array([1, 2, 3], dtype=np.int64)
    parity = np.array([0, 1, 2, 3, 7], dtype=np.int64)
    table = cycle.offset_rotation(np.arange(2), k2, 1)
    got = rotation(parity, k2, 4, table)
    assert got.tobytes() == cycle.offset_rotation(parity, k2, 4).tobytes()
