"""Channels a bench cannot read from a file: one line naming the file, the channel and what
was expected, exit code 2 through the CLI; and the units a file may use."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquisition.signal_units import UnitError, unit_factor
from acquisition.stream import SourceError
from ptinertia import cli
from ptinertia.config import Bench, ConfigError, loads_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source

I3 = EXAMPLES_DIR / "i3-bench.toml"
ACCEL = [f"{s}_{a}" for s in "ABC" for a in "xyz"]


@pytest.mark.parametrize(
    ("unit", "target", "factor"),
    [
        ("g", "m/s^2", 9.80665),
        ("mm/s^2", "m/s^2", 1e-3),
        ("m/s2", "m/s^2", 1.0),
        ("m/s²", "m/s^2", 1.0),
        ("1/min", "rpm", 1.0),
        ("U/min", "rpm", 1.0),
        ("Hz", "rpm", 60.0),
        ("rad/s", "rpm", 60.0 / (2 * np.pi)),
        ("deg/s", "rpm", 60.0 / 360.0),
        ("kPa", "bar", 1e-2),
        ("Pa", "bar", 1e-5),
        ("psi", "bar", 0.45359237 * 9.80665 / 0.0254**2 * 1e-5),
        ("mV", "V", 1e-3),
        ("ms", "s", 1e-3),
    ],
)
def test_units_convert_to_the_pipelines(unit: str, target: str, factor: float) -> None:
    # the factors are the definitions (g_n = 9.80665 m/s^2, 1 lbf/in^2 from the avoirdupois
    # pound and the inch), not pint's output
    assert unit_factor(unit, target) == pytest.approx(factor, rel=1e-12)


@pytest.mark.parametrize(
    ("unit", "target", "match"),
    [
        ("", "m/s^2", r"no unit given, expected an acceleration"),
        ("furlongs", "m/s^2", r"unit 'furlongs' is not an acceleration"),
        ("zorks", "bar", r"unit 'zorks' is unknown, expected a pressure"),
        ("g", "rpm", r"unit 'g' is not a rotation speed"),
        ("bar", "V", r"unit 'bar' is not a voltage"),
    ],
)
def test_units_refused_say_what_was_expected(unit: str, target: str, match: str) -> None:
    with pytest.raises(UnitError, match=match):
        unit_factor(unit, target)


def _bench(extra: str = "") -> Bench:
    return loads_bench(I3.read_text(encoding="utf-8") + "\n" + extra, "bench", EXAMPLES_DIR)


def _csv(tmp_path: Path, header_units: dict[str, str], rpm_unit: str = "rpm") -> Path:
    """A 0.1 s CSV at 1 kHz: the nine accelerometers in the given units, rpm, tacho edges."""
    t = [k / 1000.0 for k in range(100)]
    head = ["time_s", *(f"{c}[{header_units.get(c, 'm/s^2')}]" for c in ACCEL)]
    rows = [",".join([repr(x), *["0.5"] * len(ACCEL)]) for x in t]
    base = tmp_path / "r.csv"
    base.write_text(",".join(head) + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    rpm = tmp_path / "r.rpm.csv"
    rpm.write_text(f"time_s,rpm[{rpm_unit}]\n" + "\n".join(f"{x!r},2000" for x in t) + "\n")
    (tmp_path / "r.tacho.csv").write_text("tacho_edge_s\n0.01\n0.02\n0.03\n")
    return base


def _message(spec: str, bench: Bench) -> str:
    with pytest.raises(SourceError) as err:
        with open_source(spec, bench) as src:
            list(src)
    message = str(err.value)
    assert "\n" not in message
    return message


def test_a_unit_in_the_file_is_converted(tmp_path: Path) -> None:
    base = _csv(tmp_path, {"A_x": "g", "B_y": "mm/s^2"}, rpm_unit="1/min")
    with open_source(f"file:{base}", _bench()) as src:
        g, row = src.layout.find_channel("A_x")
        blocks = [b for b in src if getattr(b, "group", None) == g.name]
    data = np.concatenate([b.data for b in blocks], axis=1)
    assert np.all(data[row] == 0.5 * 9.80665)
    assert np.all(data[g.index_of("B_y")] == 0.5e-3)
    assert all(c.unit == "m/s^2" for c in g.channels)


def test_unknown_unit_names_file_channel_and_unit(tmp_path: Path) -> None:
    base = _csv(tmp_path, {"B_z": "furlong/fortnight"})
    message = _message(f"file:{base}", _bench())
    assert str(base) in message and "'B_z' (sensor B_gearbox_mount)" in message
    assert "'furlong/fortnight' is not an acceleration" in message
    assert "[channels]" in message  # where to declare it


def test_missing_unit_refused_then_declared(tmp_path: Path) -> None:
    base = _csv(tmp_path, {})
    base.write_text(base.read_text().replace("C_x[m/s^2]", "C_x", 1))
    message = _message(f"file:{base}", _bench())
    assert "'C_x'" in message and "no unit given, expected an acceleration" in message
    with open_source(f"file:{base}", _bench('[channels]\nC_x = { unit = "g" }\n')) as src:
        g, row = src.layout.find_channel("C_x")
        data = np.concatenate([b.data for b in src if getattr(b, "group", "") == g.name], axis=1)
    assert np.all(data[row] == 0.5 * 9.80665)


def test_a_mapped_channel_missing_is_named(tmp_path: Path) -> None:
    base = _csv(tmp_path, {})
    message = _message(f"file:{base}", _bench('[channels]\nA_y = "AccA_Y"\n'))
    assert str(base) in message and "channel 'AccA_Y' (sensor A_engine_mount) not found" in message


def test_a_channel_mapped_to_a_wrong_group_is_named(tmp_path: Path) -> None:
    base = _csv(tmp_path, {})
    bench = _bench('[channels]\nA_y = { group = "rpm" }\n')
    message = _message(f"file:{base}", bench)
    assert "channel 'A_y' (sensor A_engine_mount) is not in group 'rpm'" in message
    assert "it is in group 'accel'" in message


def _mdf_with_repeated_names(path: Path) -> Path:
    from asammdf import MDF, Signal

    t = np.arange(200) / 1000.0
    mdf = MDF(version="4.10")
    for s in "ABC":
        sigs = [Signal(np.full(t.size, 0.1), t, name=a, unit="g") for a in "XYZ"]
        mdf.append(sigs, acq_name=f"sensor {s}")
    mdf.append([Signal(np.full(t.size, 2000.0), t, name="rpm", unit="rpm")], acq_name="speed")
    wave = np.tile([0.0, 5.0], 100)
    mdf.append([Signal(wave, t, name="tacho", unit="V")], acq_name="tacho wave")
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def test_repeated_names_need_a_group_and_events_must_be_events(tmp_path: Path) -> None:
    path = _mdf_with_repeated_names(tmp_path / "r.mf4")
    names = "".join(f'{s}_{a.lower()} = "{a}"\n' for s in "ABC" for a in "XYZ")
    message = _message(f"file:{path}", _bench("[channels]\n" + names))
    assert str(path) in message
    assert (
        "channel 'X' (sensor A_engine_mount) is in groups 'sensor A', 'sensor B', 'sensor C'"
        in message
    )
    assert "name its group" in message
    grouped = "".join(
        f'{s}_{a.lower()} = {{ name = "{a}", group = "sensor {s}" }}\n'
        for s in "ABC"
        for a in "XYZ"
    )
    message = _message(f"file:{path}", _bench("[channels]\n" + grouped))
    # the tacho there is a sampled wave, not one record per edge
    assert "edge channel 'tacho' changes value (0 then 5 at record" in message
    assert "[tacho] delivery = 'sampled'" in message


def test_channels_table_names_only_the_benchs_channels() -> None:
    with pytest.raises(ConfigError, match=r"channels: 'A_q' is not a channel of this bench"):
        _bench('[channels]\nA_q = "x"\n')
    with pytest.raises(ConfigError, match=r"channels\.A_x.*unknown key"):
        _bench('[channels]\nA_x = { nam = "x" }\n')


def test_cli_bad_channel_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    base = _csv(tmp_path, {"A_z": "zorks"})
    bench = tmp_path / "b.toml"
    bench.write_text(I3.read_text(encoding="utf-8"))
    code = cli.main(["run", "--bench", str(bench), "--source", f"file:{base}", "--rerun", "off"])
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert str(base) in err and "'A_z'" in err and "'zorks' is unknown" in err


@pytest.mark.parametrize("source", ["file:run.csv", "can:virtual:x"])
def test_file_and_can_runs_need_a_bench(source: str, capsys) -> None:
    assert cli.main(["run", "--source", source, "--rerun", "off"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs --bench" in err
