"""Loss accounting of the CAN decoder: per-message frame counts and their one-line summary.

Apart from the decoder so that what was counted (placed, lost, late, malformed, ...) reads
in one place; the sources report :meth:`DecoderStats.summary` as their last event.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any


@dataclass
class StreamStats:
    """Frame counts of one DBC message (``lost`` includes ``late`` and malformed ones)."""

    frames: int = 0
    lost: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    late: int = 0
    bad_length: int = 0
    bad_crc: int = 0
    bad_counter: int = 0
    bad_payload: int = 0
    before_start: int = 0

    @property
    def malformed_any(self) -> int:
        """Frames of this message that were received but unusable (malformed or late)."""
        return self.malformed + self.late + self.duplicate

    @property
    def malformed(self) -> int:
        return self.bad_length + self.bad_crc + self.bad_counter + self.bad_payload


@dataclass
class DecoderStats:
    """Everything :class:`FrameDecoder` counted."""

    streams: dict[str, StreamStats] = field(default_factory=dict)
    unknown_ids: dict[int, int] = field(default_factory=dict)
    unknown_extended: set[int] = field(default_factory=set)  # of those, the 29-bit ids
    frames_in: int = 0
    ignored: int = 0
    bus_errors: int = 0

    def total(self, name: str) -> int:
        return sum(getattr(s, name) for s in self.streams.values())

    @property
    def malformed(self) -> int:
        return sum(s.malformed for s in self.streams.values()) + sum(self.unknown_ids.values())

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames_in": self.frames_in,
            "ignored": self.ignored,
            "unknown_ids": {f"0x{k:X}": v for k, v in self.unknown_ids.items()},
            "bus_errors": self.bus_errors,
            "streams": {
                n: {f.name: getattr(s, f.name) for f in fields(s)} for n, s in self.streams.items()
            },
        }

    def nothing_matched(self, expected: list[str], where: str) -> str | None:
        """One line when frames came but none of them is a message the plan needs, else None.

        ``expected`` describes the plan's messages (``CanPlan.describe``), ``where``
        names the input (``CAN log 'run.blf'``).
        """
        if self.frames_in == 0 or self.total("frames") or self.total("malformed_any"):
            return None
        held = sorted(self.unknown_ids.items())
        ids = ", ".join(
            f"0x{k:08X} extended ({n})" if k in self.unknown_extended else f"0x{k:X} ({n})"
            for k, n in held[:12]
        )
        more = f" and {len(held) - 12} more" if len(held) > 12 else ""
        names = "; ".join(expected)
        return (
            f"{where}: none of its {self.frames_in} frames is a DBC message the bench needs "
            f"(expected {names}); it holds ids {ids or '(none unknown)'}{more}"
            f"{f', and {self.ignored} frames of DBC messages this bench does not use' if self.ignored else ''}"
        )

    def summary(self) -> str:
        """One line for the user."""
        frames = self.total("frames")
        lost = self.total("lost")
        pct = 100.0 * lost / max(1, frames + lost)
        parts = [f"CAN: {self.frames_in} frames in, {frames} placed, {lost} lost ({pct:.3g} %)"]
        for name in ("duplicate", "out_of_order", "late"):
            if self.total(name):
                parts.append(f"{self.total(name)} {name.replace('_', ' ')}")
        bad = {k: self.total(f"bad_{k}") for k in ("length", "crc", "counter", "payload")}
        bad["unknown id"] = sum(self.unknown_ids.values())
        if any(bad.values()):
            parts.append("malformed " + ", ".join(f"{k} {v}" for k, v in bad.items() if v))
        if self.bus_errors:
            parts.append(f"{self.bus_errors} bus errors")
        return "; ".join(parts)
