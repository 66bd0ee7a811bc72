"""Errors of the physics layer."""


class PhysicsError(ValueError):
    """Parameters that describe no physical powertrain (non-positive-definite inertia, lambda >= 1)."""
