"""Fault injection for the simulated CAN DAQ: frames dropped, duplicated, delayed, corrupted.

``ptinertia can-sim --drop/--duplicate/--reorder/--corrupt`` spoils a fraction of the
data frames (never the DAQ status frames) to exercise the receiver
(:mod:`acquisition.can.decoder`); :class:`FaultLog` says what was done, so a test can
check the decoder's loss accounting against it.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from acquisition.can.encoder import TxFrame
from acquisition.can.fields import frame_crc
from acquisition.can.frames import DLC_SIZES
from acquisition.can.plan import CanPlan
from acquisition.stream import SourceError

FAULT_KINDS = ("drop", "duplicate", "reorder", "corrupt")
CORRUPTIONS = ("length", "crc", "id", "counter")


class FaultRateError(SourceError):
    """A fault fraction outside ``[0, 1]`` (``kind`` names it), or fractions adding up past 1."""

    def __init__(self, reason: str, kind: str | None = None) -> None:
        super().__init__(f"{kind}: {reason}" if kind else reason)
        self.kind = kind
        self.reason = reason


@dataclass(frozen=True)
class FaultRates:
    """The fraction of data frames each fault spoils; together at most 1."""

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0

    def __post_init__(self) -> None:
        for name in FAULT_KINDS:
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise FaultRateError(f"expected a fraction in [0, 1], got {v:g}", name)
        total = self.drop + self.duplicate + self.reorder + self.corrupt
        if total > 1.0:
            raise FaultRateError(f"the fault fractions add up to {total:g} > 1")

    @property
    def any(self) -> bool:
        """Some fault has a non-zero fraction."""
        return any((self.drop, self.duplicate, self.reorder, self.corrupt))


@dataclass
class FaultLog:
    """What the injector did, per DBC message (``corrupted`` by kind)."""

    dropped: Counter[str] = field(default_factory=Counter)
    duplicated: Counter[str] = field(default_factory=Counter)
    reordered: Counter[str] = field(default_factory=Counter)
    corrupted: dict[str, Counter[str]] = field(default_factory=dict)
    spoiled: dict[str, set[int]] = field(default_factory=dict)  # frame numbers dropped or corrupted

    def as_dict(self) -> dict[str, Any]:
        return {
            "dropped": dict(self.dropped),
            "duplicated": dict(self.duplicated),
            "reordered": dict(self.reordered),
            "corrupted": {k: dict(v) for k, v in self.corrupted.items()},
        }


class FaultInjector:
    """Drops, duplicates, delays and corrupts data frames; status frames pass untouched.

    Each frame draws one fate: dropped, duplicated (the copy follows 0-2 frames
    later), reordered (sent 1-3 frames later) or corrupted (wrong length, a bit
    flipped under the CRC, an id the DBC does not know, or a counter moved far
    off with a valid CRC), with the given probabilities.
    """

    def __init__(self, rates: FaultRates, plan: CanPlan, seed: int = 0) -> None:
        self.rates = rates
        self.rng = np.random.default_rng(seed)
        self.log = FaultLog()
        self._known = set(plan.dbc_ids) | {m.key for m in plan.messages}
        self._delayed: list[list[Any]] = []  # [frames still to pass, TxFrame]

    def apply(self, frames: list[TxFrame]) -> list[TxFrame]:
        out: list[TxFrame] = []
        r = self.rates
        cuts = np.cumsum([r.drop, r.duplicate, r.reorder, r.corrupt])
        for f in frames:
            self._release(out)
            if f.message.kind == "status":
                out.append(f)
                continue
            u = self.rng.random()
            name = f.message.name
            if u < cuts[0]:
                self.log.dropped[name] += 1
                self.log.spoiled.setdefault(name, set()).add(f.frame_no)
            elif u < cuts[1]:
                self.log.duplicated[name] += 1
                out.append(f)
                self._delayed.append([int(self.rng.integers(0, 3)), f])
            elif u < cuts[2]:
                self.log.reordered[name] += 1
                self._delayed.append([int(self.rng.integers(1, 4)), f])
            elif u < cuts[3]:
                kind = CORRUPTIONS[int(self.rng.integers(len(CORRUPTIONS)))]
                if kind == "crc" and f.message.crc is None:
                    kind = "length"
                self.log.corrupted.setdefault(name, Counter())[kind] += 1
                self.log.spoiled.setdefault(name, set()).add(f.frame_no)
                out.append(self._corrupt(f, kind))
            else:
                out.append(f)
        return out

    def flush(self) -> list[TxFrame]:
        out = [d[1] for d in self._delayed]
        self._delayed.clear()
        return out

    def _release(self, out: list[TxFrame]) -> None:
        keep = []
        for d in self._delayed:
            if d[0] <= 0:
                out.append(d[1])
            else:
                d[0] -= 1
                keep.append(d)
        self._delayed = keep

    def _corrupt(self, f: TxFrame, kind: str) -> TxFrame:
        m = f.message
        data = bytearray(f.data)
        if kind == "length":
            # the next shorter length a CAN (FD) frame can have
            shorter = max(n for n in DLC_SIZES if n < len(data))
            return f._replace(data=bytes(data[:shorter]))
        if kind == "crc":
            assert m.crc is not None
            skip = set(range(m.crc.byte, m.crc.byte + m.crc.n_bytes))
            byte = int(self.rng.choice([i for i in range(len(data)) if i not in skip]))
            data[byte] ^= 1 << int(self.rng.integers(8))
            return f._replace(data=bytes(data))
        if kind == "id":
            unknown = next(
                i for i in range(0x7FF, 0, -1) if (i, m.is_extended_id) not in self._known
            )
            return f._replace(message=replace(m, frame_id=unknown))
        # a counter far off (a random quarter to half of its range), CRC made valid again
        c = m.counter
        assert c is not None
        raw = int(np.frombuffer(bytes(data[c.byte : c.byte + c.n_bytes]), c.dtype)[0])
        shift = int(self.rng.integers(1 << (c.bits - 2), 1 << (c.bits - 1)))
        data[c.byte : c.byte + c.n_bytes] = np.array(
            [(raw + shift) % (1 << c.bits)], c.dtype
        ).tobytes()
        if m.crc is not None:
            data[m.crc.byte : m.crc.byte + 2] = np.array(
                [frame_crc(bytes(data), m.crc)], m.crc.dtype
            ).tobytes()
        return f._replace(data=bytes(data))
