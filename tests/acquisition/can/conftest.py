"""The CAN tests' shared fixtures: the i3 bench's DBC plan, its simulated stream and that
stream's clean frames (module scope: each module builds its own, none is mutated)."""

from __future__ import annotations

import pytest
from support.can_streams import DBC, sim_frames, simulated

from ptinertia.to_can import can_plan


@pytest.fixture(scope="module")
def plan(i3):
    return can_plan(i3, DBC)


@pytest.fixture(scope="module")
def reference(i3):
    return simulated(i3)


@pytest.fixture(scope="module")
def clean_frames(i3, plan):
    return sim_frames(i3, plan)[0]
