"""Why a run produced no estimate, in the words a user can act on.

One table for every command that ends without an estimate (``run``, ``replay``, a
campaign's row, a study's failed run), so the same cause reads the same everywhere.
"""

from __future__ import annotations

# Why nothing could be estimated, for the reasons a user can act on.
_NO_ESTIMATE = {
    "sensor_geometry": "the usable accelerometer channels do not determine the rigid-body "
    "motion (fewer than two sensors left, or two left only for moments: two are used once "
    "the loss has lasted 8 frames): check the sensors flagged bad",
    "too_few_channels": "fewer than six usable accelerometer channels (see the channel flags)",
    "rpm_out_of_range": "the sweep never entered the [estimator] rpm range",
    "near_rigid_modes": "every frame was too close to the rigid-body modes: the sweep never "
    "reached the mass-line range (order frequency above min_mode_ratio x the highest mode)",
    "tacho": "no frame had a trustworthy crank angle (tacho lost or ambiguous)",
    "off_mass_line": "every frame was off the mass line (the motion bends with rpm, near a "
    "mode, faster than the dsp follows): sweep more slowly or further above the modes",
    "neighbour_leakage": "every frame carried too much leakage from orders bending near a "
    "mode (the sweep is too fast there): sweep more slowly or further above the modes",
    "no_rpm": "no rpm signal",
}


BENDING = ("off_mass_line", "neighbour_leakage")


def no_estimate_reason(
    rejected: dict[str, int], orders_rejected: dict[str, int] | None = None
) -> str:
    """One line: the main reason no frame was usable (``rejected`` per frame, and per
    frame and order)."""
    if not rejected:
        return "no frame reached the estimator"
    reason, count = max(rejected.items(), key=lambda kv: kv[1])
    bent = {k: v for k, v in (orders_rejected or {}).items() if k in BENDING}
    if reason == "near_rigid_modes" and bent:
        # a frame's reason is its orders' most common one: the low orders sit among the
        # modes, but the orders above them bent or leaked, which is what to act on
        reason, count = max(bent.items(), key=lambda kv: kv[1])
        detail = _NO_ESTIMATE[reason]
        return f"{detail}; {count} orders rejected for this, the lower ones among the modes"
    detail = _NO_ESTIMATE.get(reason, f"no usable frame ({reason})")
    return f"{detail}; {count} frames rejected for this, {sum(rejected.values())} in all"
