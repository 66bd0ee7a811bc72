"""What the streaming estimator did with one frame: the record every sink and the recorder take.

Its own module so that the recorder, the replay reader and the app's sinks depend on this
record, not on the estimator that makes it.
"""

from __future__ import annotations

from dataclasses import dataclass

from estimator.kinematics import RigidMotion


@dataclass(frozen=True)
class FrameOutcome:
    """What the estimator did with one frame."""

    time_s: float
    rpm: float
    used_orders: tuple[float, ...]
    rejected: dict[float, str]
    reason: str | None  # why the whole frame was rejected, None when used
    relative_residual: dict[float, float]
    motion: RigidMotion | None = None  # the fitted rigid motion (for viewers)
