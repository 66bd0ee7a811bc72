"""A fast ``dataclasses.replace`` for the tracker's frozen state records.

``replace`` checks every field and re-runs ``__init__`` with all of them, about
7 us for :class:`dsp.state.TrackerState`; the tracker replaces a field or two of
its records some 3000 times a minute of stream, a twentieth of its work. The
state records have no ``__post_init__`` and keep their fields in ``__dict__``,
so a copy of that dict with the changes applied is the same object, in a fifth
of the time. The field check compares the key views (no set is built) and the dict
is the merge ``fields | changes``, set as the new instance's ``__dict__``: 1.2 -> 0.6 us
a call (issue 24; some 3000 calls a minute of the run's log).
"""

from __future__ import annotations

from typing import Any, TypeVar

T = TypeVar("T")


def evolve(record: T, **changes: Any) -> T:
    """``record`` (a frozen dataclass instance without ``__post_init__``) with ``changes``."""
    fields = record.__dict__
    if not changes.keys() <= fields.keys():
        unknown = changes.keys() - fields.keys()
        raise TypeError(f"{type(record).__name__} has no field {', '.join(sorted(unknown))}")
    new = object.__new__(type(record))
    # the merged dict made in one step and installed as the instance's own (the frozen
    # class's __setattr__ bypassed as its __init__ does): 0.75 -> 0.60 us for the 18
    # fields of TrackerState
    object.__setattr__(new, "__dict__", fields | changes)
    return new
