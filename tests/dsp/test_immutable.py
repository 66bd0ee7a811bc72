"""dsp.immutable.evolve against dataclasses.replace, on the tracker's own state records."""

import dataclasses

import numpy as np
import pytest

from dsp.immutable import evolve
from dsp.state import GroupState


def test_evolve_gives_what_replace_gives_and_leaves_the_record_alone():
    before = GroupState(pend=((0, np.zeros((2, 3))),), last_index=7)
    after = evolve(before, last_index=9, starved=True)
    want = dataclasses.replace(before, last_index=9, starved=True)
    assert type(after) is GroupState
    assert after.__dict__.keys() == want.__dict__.keys()  # the fields, in their order
    assert all(after.__dict__[k] is want.__dict__[k] for k in ("pend", "acc", "holes"))
    assert (after.last_index, after.starved) == (9, True)
    assert (before.last_index, before.starved) == (7, False)
    assert after.__dict__ is not before.__dict__
    with pytest.raises(dataclasses.FrozenInstanceError):
        after.last_index = 3  # type: ignore[misc]


def test_evolve_names_an_unknown_field():
    with pytest.raises(TypeError, match="GroupState has no field colour"):
        evolve(GroupState(), colour=1)
