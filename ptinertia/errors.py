"""The user-facing error classes the CLI turns into one line and exit code 2.

Each layer raises its own ``ValueError`` subclass (no layer imports another's
errors); this module only gathers them for the CLI.
"""

from __future__ import annotations


class UsageError(ValueError):
    """A command-line value that cannot work (bad option value, missing file)."""


def user_error_types() -> tuple[type[BaseException], ...]:
    """Every exception class that means "the user's input is wrong", not "we have a bug"."""
    # Imported here, not at the top: cli.py imports this module before it knows the command,
    # and loading the layers (numpy, scipy, pydantic) would make every ``--help`` pay for them.
    from acquisition.stream import SourceError
    from dsp.errors import DspConfigError
    from powertrain.errors import PhysicsError
    from ptinertia.config import ConfigError

    return (UsageError, ConfigError, SourceError, PhysicsError, DspConfigError)
