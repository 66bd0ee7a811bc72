"""The bar of long work that is not a run (``report``, ``can-sim --log``): terminals only."""

from __future__ import annotations

import io

from ptinertia.progress import work_bar


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_sees_stream_seconds_and_a_log_sees_nothing() -> None:
    term, log = _Terminal(), io.StringIO()
    for stream in (term, log):
        bar = work_bar(10.0, "can-sim", stream=stream)
        if not bar.disable:  # a disabled bar has no clock at all
            bar.start_t -= 5.0  # past the 1 s delay: the bar shows
        bar.update(3.0)
        bar.refresh()
        bar.close()
    assert "3.0/10.0 s" in term.getvalue() and "can-sim" in term.getvalue()
    assert log.getvalue() == ""


def test_a_stage_bar_names_the_stage() -> None:
    term = _Terminal()
    bar = work_bar(8, "report", unit="step", stream=term)
    bar.start_t -= 5.0
    bar.set_postfix_str("orders", refresh=False)
    bar.update(1)
    bar.refresh()
    bar.close()
    assert "1/8, orders" in term.getvalue()


def test_short_work_prints_nothing() -> None:
    term = _Terminal()
    bar = work_bar(8, "report", unit="step", stream=term)
    bar.update(8)
    bar.close()
    assert "report" not in term.getvalue()
