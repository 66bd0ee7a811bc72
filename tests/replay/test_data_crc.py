"""The data section's CRC read in two halves on two threads (replay/integrity.py): the
combined CRC is zlib's CRC of the whole, for any split, and a damaged or cut file fails."""

from __future__ import annotations

import threading
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


@pytest.mark.parametrize("isal", [True, False], ids=["two-threads", "zlib-only"])
@pytest.mark.parametrize("size", [0, 1, 4097, (8 << 20) - 1, 8 << 20, (9 << 20) - 3])
def test_the_crc_of_any_prefix_is_zlibs(
    data: tuple[Path, bytes], size: int, isal: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    path, payload = data
    if not isal:  # a platform without isal wheels: zlib's CRC, one thread
        monkeypatch.setattr(integrity, "crc32_combine", None)
        monkeypatch.setattr(integrity, "crc32", zlib.crc32)
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


def test_a_read_error_in_either_half_is_raised_and_no_thread_is_left(
    data: tuple[Path, bytes], monkeypatch: pytest.MonkeyPatch
) -> None:
    path, payload = data
    real = integrity._crc_of
    for failing in (0, len(payload) // 2):

        def crc_of(p: Path, start: int, end: int, failing: int = failing) -> int:
            if start == failing:
                raise OSError(5, "Input/output error")
            return real(p, start, end)

        monkeypatch.setattr(integrity, "_crc_of", crc_of)
        with pytest.raises(OSError, match="Input/output"):
            integrity._data_crc(path, len(payload))
        assert not any(t.name == "ptinertia-data-crc-2" for t in threading.enumerate())
