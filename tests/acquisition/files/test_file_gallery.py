"""A gallery of recordings as other tools write them, each read to the reference's estimate.

One short simulated sweep is written by ``ptinertia simulate`` (the reference MF4); the
same samples are then written by asammdf's own ``MDF`` writer and by pandas and numpy in
the layouts a DAQ or a user produces: accelerometers and rpm in one 5120 Hz group beside a
102.4 kHz tacho wave, tacho and cam edge events (a marker ``1`` at each edge, the time in
the group's master channel), channels per sensor with repeating names, units ``g``,
``mm/s^2``, ``1/min``, ``kPa``, names differing from the bench's. The bench's ``[channels]``
table maps them. Each must give the reference's estimate (the conversion ``x / 9.80665 *
9.80665`` costs at most an ulp, far below what moves an estimate).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from acquisition.stream import EdgeBlock, SampleBlock
from ptinertia.commands.simulate import simulate
from ptinertia.config import Bench, load_bench, loads_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import RunOptions, run_source
from ptinertia.sources import open_source

I3 = EXAMPLES_DIR / "i3-bench.toml"
G0 = 9.80665  # m/s^2 per g (standard gravity)
FS = 5120.0
# a short sweep with a cam: enough frames for an estimate, quick to run
SIM = {
    "duration_s": 3.0,
    "rpm_start": 2000.0,
    "rpm_end": 2600.0,
    "accel_rate_hz": FS,
    "tacho": {"phase_reference": "cam", "rpm_rate_hz": FS},
}
TACHO = '[tacho]\nphase_reference = "cam"\nrpm_rate_hz = 5120.0\n'
SENSORS = {"A": "A", "B": "B", "C": "C"}


def _bench(extra: str) -> Bench:
    """The i3 bench with a cam reference and ``extra`` (a [channels] table) appended."""
    text = I3.read_text(encoding="utf-8").replace(
        'phase_reference = "none"', 'phase_reference = "cam"'
    )
    text = text.replace("rpm_rate_hz = 100.0", "rpm_rate_hz = 5120.0")
    return loads_bench(text + "\n" + extra, "gallery bench", base_dir=EXAMPLES_DIR)


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The reference MF4, its samples (by channel), edges and estimate."""
    tmp = tmp_path_factory.mktemp("gallery")
    path = tmp / "reference.mf4"
    simulate(I3, path, **SIM)
    bench = _bench("")
    channels: dict[str, np.ndarray] = {}
    edges: dict[str, list[np.ndarray]] = {}
    with open_source(f"file:{path}", bench) as src:
        layout = src.layout
        pieces: dict[str, list[np.ndarray]] = {}
        for item in src:
            if isinstance(item, SampleBlock):
                pieces.setdefault(item.group, []).append(item.data)
            elif isinstance(item, EdgeBlock):
                edges.setdefault(item.channel, []).append(item.times_s)
    for g in layout.groups:
        data = np.concatenate(pieces[g.name], axis=1)
        for i, c in enumerate(g.channels):
            channels[c.name] = data[i]
        channels["time:" + g.name] = g.t0_s + np.arange(data.shape[1]) / g.rate_hz
    assert layout.group("accel").rate_hz == FS and layout.find_channel("rpm")[0].rate_hz == FS
    return {
        "dir": tmp,
        "channels": channels,
        "edges": {k: np.concatenate(v) for k, v in edges.items()},
        "estimate": _estimate(f"file:{path}", bench),
    }


def _estimate(spec: str, bench: Bench) -> dict:
    with open_source(spec, bench) as src:
        _, doc = run_source(bench, "", src, spec, RunOptions(quiet=True))
    assert doc is not None, spec
    return doc


def _same_estimate(doc: dict, ref: dict) -> None:
    got, want = doc["inertia_kgm2"]["value"], ref["inertia_kgm2"]["value"]
    assert set(got) == set(want)
    for term, value in want.items():
        assert got[term] == pytest.approx(value, rel=1e-9, abs=1e-12), term
    np.testing.assert_allclose(doc["cog_m"]["value"], ref["cog_m"]["value"], rtol=0, atol=1e-9)


def _accel(ref: dict) -> dict[str, np.ndarray]:
    return {f"{s}_{a}": ref["channels"][f"{s}_{a}"] for s in "ABC" for a in "xyz"}


def _daq_mdf(ref: dict) -> tuple[Path, str]:
    """A DAQ's MF4: one 5120 Hz group (accelerometers in g, speed in 1/min), a 102.4 kHz
    tacho wave, ECU events at irregular times, tacho and cam edge event groups; every name
    its own."""
    from asammdf import MDF, Signal

    ch, t = ref["channels"], ref["channels"]["time:accel"]
    mdf = MDF(version="4.10")
    sigs = [
        Signal(x / G0, t, name=f"Acc{name[0]}_{name[2].upper()}", unit="g")
        for name, x in _accel(ref).items()
    ]
    sigs.append(Signal(ch["rpm"], t, name="n_engine", unit="1/min"))
    mdf.append(sigs, acq_name="DAQ fast")
    wave_t = np.arange(0, 0.2, 1 / 102_400.0)
    wave = np.where(np.sin(2 * np.pi * 1000 * wave_t) > 0, 5.0, 0.0)
    mdf.append([Signal(wave, wave_t, name="tacho_wave", unit="V")], acq_name="tacho wave")
    # an ECU's events at irregular times, unneeded: never read, so never refused
    ecu_t = np.cumsum(np.random.default_rng(1).uniform(0.01, 0.3, 12))
    mdf.append([Signal(np.arange(12.0), ecu_t, name="gear", unit="")], acq_name="ECU events")
    for name, edges in (("TachoEdge", ref["edges"]["tacho"]), ("CamEdge", ref["edges"]["cam"])):
        mdf.append([Signal(np.ones(edges.size), edges, name=name, unit="")], acq_name=name)
    path = ref["dir"] / "daq.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    table = "[channels]\n" + "".join(f'{n} = "Acc{n[0]}_{n[2].upper()}"\n' for n in _accel(ref))
    table += 'rpm = "n_engine"\ntacho = "TachoEdge"\ncam = "CamEdge"\n'
    return path, table


def _per_sensor_mdf(ref: dict) -> tuple[Path, str]:
    """One group per sensor, each with channels X, Y, Z in mm/s^2 (names repeat: the
    bench names the group); the speed in rad/s in a group of its own; edges as
    ptinertia-independent event groups with a marker of 0.5."""
    from asammdf import MDF, Signal

    ch, t = ref["channels"], ref["channels"]["time:accel"]
    mdf = MDF(version="4.10")
    for s in "ABC":
        mdf.append(
            [Signal(ch[f"{s}_{a}"] * 1000.0, t, name=a.upper(), unit="mm/s^2") for a in "xyz"],
            acq_name=f"sensor {s}",
        )
    rad_s = ch["rpm"] * 2 * np.pi / 60
    mdf.append([Signal(rad_s, t, name="speed", unit="rad/s")], acq_name="engine")
    for name in ("tacho", "cam"):
        e = ref["edges"][name]
        mdf.append([Signal(np.full(e.size, 0.5), e, name="event", unit="")], acq_name=name)
    path = ref["dir"] / "per_sensor.mf4"
    mdf.save(path, overwrite=True)
    mdf.close()
    # groups by acquisition name, and sensor C's by its index (the third group, 2)
    group = {"A": "sensor A", "B": "sensor B", "C": "2"}
    table = "[channels]\n" + "".join(
        f'{s}_{a} = {{ name = "{a.upper()}", group = "{group[s]}" }}\n'
        for s in "ABC"
        for a in "xyz"
    )
    table += 'rpm = "speed"\n'
    table += (
        'tacho = { name = "event", group = "tacho" }\ncam = { name = "event", group = "cam" }\n'
    )
    return path, table


def _pandas_csv(ref: dict) -> tuple[Path, str]:
    """pandas: accelerometers in g with their own names, the speed in 1/min, edges as
    single-column files of any header."""
    ch = ref["channels"]
    frame = pd.DataFrame({"time_s": ch["time:accel"]})
    for name, x in _accel(ref).items():
        frame[f"acc{name} [g]"] = x / G0
    frame["n_mot [1/min]"] = ch["rpm"]
    base = ref["dir"] / "pandas.csv"
    frame.to_csv(base, index=False)
    pd.DataFrame({"Tacho times": ref["edges"]["tacho"]}).to_csv(
        ref["dir"] / "pandas.tacho.csv", index=False
    )
    pd.DataFrame({"cam pulses": ref["edges"]["cam"]}).to_csv(
        ref["dir"] / "pandas.cam.csv", index=False
    )
    table = "[channels]\n" + "".join(f'{n} = "acc{n}"\n' for n in _accel(ref))
    table += 'rpm = "n_mot"\ntacho = "Tacho times"\ncam = "cam pulses"\n'
    return base, table


def _numpy_csv(ref: dict) -> tuple[Path, str]:
    """numpy.savetxt: accelerometers in mm/s^2 with no unit in the header (the bench
    declares it), edges as event files (time and a marker column)."""
    ch = ref["channels"]
    accel = _accel(ref)
    base = ref["dir"] / "np.csv"
    cols = [ch["time:accel"], *(x * 1000.0 for x in accel.values()), ch["rpm"]]
    header = ",".join(["time_s", *accel, "rpm[rpm]"])
    np.savetxt(base, np.column_stack(cols), delimiter=",", header=header, comments="", fmt="%.17g")
    for name in ("tacho", "cam"):
        e = ref["edges"][name]
        np.savetxt(
            ref["dir"] / f"np.{name}.csv",
            np.column_stack([e, np.ones(e.size)]),
            delimiter=",",
            header=f"time_s,{name}_pulse",
            comments="",
            fmt="%.17g",
        )
    table = "[channels]\n" + "".join(f'{n} = {{ unit = "mm/s^2" }}\n' for n in accel)
    table += 'tacho = "tacho_pulse"\ncam = "cam_pulse"\n'
    return base, table


GALLERY = {
    "daq-mdf": _daq_mdf,
    "per-sensor-mdf": _per_sensor_mdf,
    "pandas-csv": _pandas_csv,
    "numpy-csv": _numpy_csv,
}


@pytest.mark.parametrize("kind", GALLERY)
def test_gallery_file_gives_the_reference_estimate(kind: str, reference: dict) -> None:
    path, table = GALLERY[kind](reference)
    bench = _bench(table)
    _same_estimate(_estimate(f"file:{path}", bench), reference["estimate"])


def test_a_unit_declared_in_the_bench_overrides_the_files(reference: dict) -> None:
    """The failure the units fix, made on purpose: the DAQ file's g declared as m/s^2 in
    [channels] is read as declared, and the estimate is far off (Ixx by 9.8x)."""
    path, _ = _daq_mdf(reference)
    declared = "[channels]\n" + "".join(
        f'{n} = {{ name = "Acc{n[0]}_{n[2].upper()}", unit = "m/s^2" }}\n'
        for n in _accel(reference)
    )
    declared += 'rpm = "n_engine"\ntacho = "TachoEdge"\ncam = "CamEdge"\n'
    doc = _estimate(f"file:{path}", _bench(declared))
    ixx = doc["inertia_kgm2"]["value"]["Ixx"]
    assert ixx / reference["estimate"]["inertia_kgm2"]["value"]["Ixx"] > 5


def test_load_bench_reads_the_channels_table(tmp_path: Path) -> None:
    text = (
        I3.read_text(encoding="utf-8")
        + '\n[channels]\nA_x = "AccA_X"\nB_y = { name = "Y", group = "sensor B", unit = "g" }\n'
    )
    path = tmp_path / "b.toml"
    path.write_text(text, encoding="utf-8")
    bench = load_bench(path)
    assert bench.channels["A_x"] == "AccA_X"
