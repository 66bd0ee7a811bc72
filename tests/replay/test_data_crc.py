"""The data section's CRC read in two halves on two threads (replay/integrity.py): the
combined CRC is zlib's CRC of the whole, for any split, and a damaged or cut file fails."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest

from replay import integrity


@pytest.fixture
def data(tmp_path: Path) -> tuple[Path, bytes]:
    payload = np.random.default_rng(4).integers(0, 256, 9 << 20, dtype=np.uint8).tobytes()
    path = tmp_path / "data.bin"
    path.write_bytes(payload)
    return path, payload


@pytest.mark.parametrize("size", [0, 1, 4097, (8 << 20) - 1, 8 << 20, (9 << 20) - 3])
def test_the_crc_of_any_prefix_is_zlibs(data: tuple[Path, bytes], size: int) -> None:
    path, payload = data
    # below SPLIT_ABOVE_BYTES one thread reads it; above, two halves are combined
    assert integrity._data_crc(path, size) == zlib.crc32(payload[:size])


def test_one_flipped_bit_in_either_half_changes_it(data: tuple[Path, bytes]) -> None:
    path, payload = data
    size = len(payload)
    whole = integrity._data_crc(path, size)
    for at in (10, size // 2 - 1, size // 2, size - 1):
        damaged = bytearray(payload)
        damaged[at] ^= 0x10
        path.write_bytes(damaged)
        assert integrity._data_crc(path, size) == zlib.crc32(damaged) != whole


def test_a_cut_file_gets_a_crc_no_record_holds(data: tuple[Path, bytes]) -> None:
    path, payload = data
    size = len(payload)
    path.write_bytes(payload[: size - 1000])
    assert integrity._data_crc(path, size) != zlib.crc32(payload)
