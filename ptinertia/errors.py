"""The user-facing error classes the CLI turns into one line and exit code 2.

Each layer raises its own ``ValueError`` subclass (no layer imports another's
errors); this module only gathers them for the CLI.
"""

from __future__ import annotations


class UsageError(ValueError):
    """A command-line value that cannot work (bad option value, missing file)."""


def user_error_types() -> tuple[type[BaseException], ...]:
    """Every exception class that means "the user's input is wrong", not "we have a bug"."""
    from acquisition.stream import SourceError
    from powertrain.errors import PhysicsError
    from ptinertia.config import ConfigError

    types: list[type[BaseException]] = [UsageError, ConfigError, SourceError, PhysicsError]
    try:
        from dsp.errors import DspConfigError

        types.append(DspConfigError)
    except ImportError:  # dsp not built yet in this checkout
        pass
    try:
        from estimator.errors import EstimatorError

        types.append(EstimatorError)
    except ImportError:
        pass
    return tuple(types)
