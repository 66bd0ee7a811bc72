"""The streaming estimator relinearises when its count of used frames reaches
``next_relinearisation``: exactly the counts ``relinearise_due`` names, none skipped."""

from __future__ import annotations

import itertools

from estimator.relinearise import (
    RELINEARISE_EVERY,
    RELINEARISE_EVERY_LATER,
    RELINEARISE_LATER_AFTER,
    next_relinearisation,
    relinearise_due,
)


def test_the_next_point_is_the_first_due_count_after_each_count() -> None:
    points = [u for u in range(1, 2000) if relinearise_due(u)]
    for used in range(0, 1900):
        assert next_relinearisation(used) == next(u for u in points if u > used)
    # the schedule it follows: every few frames at first, then every batch
    early = [u for u in points if u <= RELINEARISE_LATER_AFTER]
    assert early[:2] == [1, 1 + RELINEARISE_EVERY]
    later = [u for u in points if u > RELINEARISE_LATER_AFTER]
    assert {b - a for a, b in itertools.pairwise(later)} == {RELINEARISE_EVERY_LATER}
