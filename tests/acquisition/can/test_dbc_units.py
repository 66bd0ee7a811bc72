"""A DBC signal's unit is converted to the pipeline's, as a file channel's is."""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition.can.dbc import load_plan
from acquisition.stream import SourceError
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_acquisition import channel_needs

DBC = EXAMPLES_DIR / "bench.dbc"
A_X = '(0.01,0) [-327.67|327.67] "m/s^2"'


def _variant(tmp_path: Path, unit: str, scale: str = "0.01") -> Path:
    lines = DBC.read_text().splitlines(keepends=True)
    text = "".join(
        line.replace(A_X, f'({scale},0) [-327.67|327.67] "{unit}"')
        if " SG_ A_x_s" in line
        else line
        for line in lines
    )
    path = tmp_path / "units.dbc"
    path.write_text(text)
    return path


def test_dbc_units_become_the_pipelines(tmp_path: Path) -> None:
    needs = channel_needs(load_bench(EXAMPLES_DIR / "i3-bench.toml"))
    plan = load_plan(needs, _variant(tmp_path, "g", "0.001"))
    msg = next(m for m in plan.messages if "A_x" in m.channels)
    sc = msg.scalings[msg.channels.index("A_x")]
    # a raw count of 1 mg is 1e-3 * 9.80665 m/s^2 (standard gravity, by definition)
    assert sc.scale == pytest.approx(1e-3 * 9.80665, rel=1e-15) and sc.unit == "m/s^2"
    # the channels beside it, in m/s^2 already, keep their scaling bit for bit
    assert msg.scalings[msg.channels.index("A_y")].scale == 0.01
    assert plan.layout.find_channel("A_x")[0].channels[0].unit == "m/s^2"


def test_unknown_dbc_unit_names_message_and_channel(tmp_path: Path) -> None:
    needs = channel_needs(load_bench(EXAMPLES_DIR / "i3-bench.toml"))
    path = _variant(tmp_path, "zorks")
    with pytest.raises(SourceError) as err:
        load_plan(needs, path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    assert "message DAQ_AccA channel 'A_x' (sensor A_engine_mount)" in message
    assert "unit 'zorks' is unknown, expected an acceleration" in message
