"""Fixtures of the replay tests: a short real recording and its clean replay."""

from __future__ import annotations

import pytest
from support.clean_run import CleanRun, record_clean_run


@pytest.fixture(scope="session")
def clean_run(tmp_path_factory: pytest.TempPathFactory) -> CleanRun:
    """A 4 s simulated sweep (``ptinertia run --record``) and its replay's result document."""
    return record_clean_run(tmp_path_factory.mktemp("clean-run"))
