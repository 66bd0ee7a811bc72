"""The viewer tests' shared fixture: the i3 bench's simulated model and its truth (module
scope: each module builds its own, none is mutated)."""

from __future__ import annotations

import pytest

from ptinertia.to_physics import build_simulated_model


@pytest.fixture(scope="module")
def i3_simulated(i3):
    bench = i3
    model, truth = build_simulated_model(bench)
    return bench, model, truth
