"""The gas torque from a cylinder-pressure channel, through the whole chain.

The simulated i3 burns 20 % more than its bench file's ``[gas]`` says: the gas model
then biases the roll inertia, the pressure channel does not. Also: which source
``gas_torque`` picks, its one-line errors, and a replay of such a run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.estimator_runs import cog_error_m, rel_errors, run

from acquisition.stream import ChannelSpec, SampleGroup, StreamLayout
from ptinertia.cli import main
from ptinertia.config import ConfigError, load_bench, loads_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source
from ptinertia.to_estimator import pressure_gas

I3 = EXAMPLES_DIR / "i3-bench.toml"
OFF_GAS = {"duration_s": 20.0, "heat_release_error_pct": 20.0}


def _bench(gas_torque: str, **tacho: Any):
    bench = load_bench(I3)
    est = bench.estimator.model_copy(update={"gas_torque": gas_torque})
    return bench.model_copy(
        update={"estimator": est, "tacho": bench.tacho.model_copy(update=tacho)}
    )


def _errors(gas_torque: str) -> tuple[dict[str, float], dict[str, Any]]:
    doc = run(I3, OFF_GAS, estimator={"gas_torque": gas_torque})
    return rel_errors(doc), doc


def test_a_wrong_gas_model_biases_the_roll_inertia_and_the_pressure_channel_does_not():
    modelled, _ = _errors("model")
    assert modelled["Iyy"] < -0.05  # the gas torque is the roll excitation: 20 % more gas
    measured, doc = _errors("pressure")
    assert max(abs(e) for e in measured.values()) < 0.002, measured
    assert np.all(cog_error_m(doc) < 0.0005)
    assert doc["frames"]["used"] > 450


def _layout(*channels: ChannelSpec) -> StreamLayout:
    accel = [ChannelSpec(c, "m/s^2") for c in ("A_x", "A_y", "A_z")]
    return StreamLayout((SampleGroup("accel", 5120.0, (*accel, *channels)),), ("tacho",))


def test_which_gas_torque_is_used():
    pressure = ChannelSpec("p_cyl1", "bar")
    assert pressure_gas(_bench("auto"), _layout()) is None
    assert pressure_gas(_bench("model"), _layout(pressure)) is None
    got = pressure_gas(_bench("auto"), _layout(pressure))
    assert got is not None and got.channel == "p_cyl1" and got.pa_per_unit == 1e5
    # a channel in volts is not a pressure: auto leaves it, pressure refuses it
    volts = ChannelSpec("p_cyl1", "V")
    assert pressure_gas(_bench("auto"), _layout(volts)) is None
    with pytest.raises(ConfigError, match="'p_cyl1' is in 'V'"):
        pressure_gas(_bench("pressure"), _layout(volts))
    with pytest.raises(ConfigError, match=r"no channel 'cyl3'.*A_x, A_y, A_z"):
        pressure_gas(_bench("pressure", pressure_channel="cyl3"), _layout(pressure))


def test_the_simulator_records_the_pressure_when_the_estimator_needs_it():
    names = open_source("sim", _bench("pressure"), duration_s=1.0).layout.channel_names
    assert "p_cyl1" in names
    assert "p_cyl1" not in open_source("sim", _bench("auto"), duration_s=1.0).layout.channel_names


def test_a_heat_release_error_needs_the_parametric_gas():
    head, rest = I3.read_text().split("[gas]")
    sensors = rest[rest.index("[[sensors]]") :]
    text = head + '[gas]\nmodel = "orders"\norders = []\n\n' + sensors
    bench = loads_bench(text)
    with pytest.raises(ConfigError, match=r"heat_release_error_pct: needs \[gas\] model"):
        open_source("sim", bench, heat_release_error_pct=10.0)


def test_replay_of_a_pressure_run_gives_its_result(tmp_path: Path):
    assert "[estimator]" not in I3.read_text()
    text = I3.read_text() + '\n[estimator]\ngas_torque = "pressure"\n'
    text = text.replace("[simulation]", "[simulation]\nheat_release_error_pct = 20.0", 1)
    bench_file = tmp_path / "bench.toml"
    bench_file.write_text(text)
    log, first, again = tmp_path / "run.mcap", tmp_path / "r.json", tmp_path / "r2.json"
    args = ["--rerun", "off", "--quiet", "--json"]
    assert main(["run", "--bench", str(bench_file), "--duration", "8", *args, str(first),
                 "--record", str(log)]) == 0  # fmt: skip
    assert main(["replay", str(log), *args, str(again)]) == 0
    a, b = json.loads(first.read_text()), json.loads(again.read_text())
    assert a["inertia_kgm2"] == b["inertia_kgm2"] and a["cog_m"] == b["cog_m"]
