"""TOML tables shared by our files (bench, pendulum test, modal set-up): the table base class
(unknown keys refused, unit suffixes normalised by :mod:`acquisition.units`) and one-line
messages from pydantic errors.

In ``acquisition`` because the classical-method input files are TOML tables too, and
``ptinertia.config`` (the bench file) builds on the same base.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError, model_validator

from acquisition.units import normalise_keys


class TomlTable(BaseModel):
    """Base of every table of our TOML files: unknown keys refused, unit suffixes normalised."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _units(cls, data: Any) -> Any:
        if isinstance(data, dict):
            try:
                return normalise_keys(data, set(cls.model_fields))
            except KeyError as err:
                key, message = err.args
                raise ValueError(f"{key}: {message}") from None
        return data


def format_validation_error(err: ValidationError, where: str, hidden: Iterable[str] = ()) -> str:
    """``where: key.path[2].key: what was expected (+n more)``.

    ``hidden`` are location parts to leave out (discriminator tags of union tables).
    """
    errors = err.errors()
    # An unknown key usually explains the "missing" error beside it (a misspelling): report it first.
    first = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])
    skip = set(hidden)
    loc = ".".join(
        (f"[{p}]" if isinstance(p, int) else str(p)) for p in first["loc"] if p not in skip
    ).replace(".[", "[")
    message = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        message = "unknown key (check spelling and unit suffix)"
    elif first["type"] == "missing":
        message = "required key is missing"
    count = err.error_count()
    more = f" (+{count - 1} more)" if count > 1 else ""
    return f"{where}: {loc}: {message}{more}" if loc else f"{where}: {message}{more}"
