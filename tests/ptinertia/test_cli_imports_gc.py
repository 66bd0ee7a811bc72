"""The collector paused while a command's modules load (ptinertia.cli.imports_uncollected)."""

from __future__ import annotations

import gc
import subprocess
import sys
from collections.abc import Iterator

import pytest

from ptinertia import cli


@pytest.fixture
def first_command(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """As in a fresh process: nothing frozen yet; what a test freezes is thawed after it."""
    monkeypatch.setattr(cli, "_frozen", [])
    yield
    gc.unfreeze()
    gc.enable()


def test_the_collector_is_paused_inside_and_back_after_with_the_imports_frozen(
    first_command: None,
) -> None:
    gc.unfreeze()
    made = []
    with cli.imports_uncollected():
        assert not gc.isenabled()
        made.append([object() for _ in range(1000)])
    assert gc.isenabled()
    # what was made inside is out of the collector's reach: no generation holds it
    inside = made[0]
    assert gc.get_freeze_count() > 1000 and not any(o is inside for o in gc.get_objects())
    frozen = gc.get_freeze_count()
    with cli.imports_uncollected():  # a second command in the process freezes nothing more
        made.append([object() for _ in range(1000)])
    assert gc.get_freeze_count() == frozen and gc.isenabled()


def test_a_collector_the_caller_switched_off_stays_off(first_command: None) -> None:
    gc.unfreeze()
    gc.disable()
    with cli.imports_uncollected():
        assert not gc.isenabled()
    assert not gc.isenabled() and gc.get_freeze_count() == 0


def test_a_parse_error_leaves_the_collector_on(first_command: None) -> None:
    with pytest.raises(SystemExit):
        cli.main(["run", "--no-such-option"])
    assert gc.isenabled()


def test_a_fresh_process_freezes_what_the_project_imports_made() -> None:
    """The estimator, dsp and replay with numpy and scipy: tens of thousands of objects."""
    code = (
        "import gc\nfrom ptinertia import cli\n"
        "with cli.imports_uncollected():\n    import ptinertia.runner\n"
        "print(gc.isenabled(), gc.get_freeze_count())"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    enabled, frozen = out.stdout.split()
    assert enabled == "True" and int(frozen) > 50_000
