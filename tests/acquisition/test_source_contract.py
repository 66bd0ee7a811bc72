"""One contract, every source: the simulated bench, CSV, MF4, MCAP replay, each CAN log format
and a live (python-can virtual) bus.

Each file is written by the tool a user has for it (``ptinertia simulate`` for CSV, MF4 and
MCAP; ``ptinertia can-sim --log`` through python-can's log writers for BLF, ASC and TRC;
asammdf's own writer for an MF4 in a DAQ's layout, names and units, read through the bench's
``[channels]``) and opened through the same entry point the CLI uses (:func:`ptinertia.sources.open_source`). The
body below is the same for every source: the layout is known before the first item and holds
the channels the bench needs, the blocks are well formed and in order per group and edge
channel, the samples are the simulated bench's to the format's resolution, and closing is
safe twice and ends the stream.
"""

from __future__ import annotations

import threading
from pathlib import Path

import can
import numpy as np
import pytest

from acquisition.stream import EdgeBlock, SampleBlock, Source, SourceEvent
from ptinertia import cli
from ptinertia.config import Bench, load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source

DURATION_S = 1.0
SEED = 5
# What each format keeps of a float64 acceleration, as the largest absolute error it may add
# (m/s^2) given the channel's largest value: the simulator itself, CSV (shortest round-trip
# decimal) and MF4 (float64) keep it exactly; MCAP stores float32 (half an ulp, 2^-24 of the
# value); CAN carries the DBC's 0.01 m/s^2 step (half a step of rounding).
RESOLUTION = {
    "sim": lambda peak: 0.0,
    "csv": lambda peak: 0.0,
    "mf4": lambda peak: 0.0,
    # a DAQ's layout written by asammdf, accelerations in g: x / g0 * g0 is within 2 ulp
    "mf4-daq": lambda peak: 2.0**-51 * peak,
    "mcap": lambda peak: 2.0**-24 * peak,
    "blf": lambda peak: 0.005,
    "asc": lambda peak: 0.005,
    "trc": lambda peak: 0.005,
    "virtual": lambda peak: 0.005,
}
KINDS = tuple(RESOLUTION)


def _bench_file(tmp: Path) -> Path:
    """The i3 bench with its DBC given by absolute path (the copy lives outside examples/)."""
    text = (EXAMPLES_DIR / "i3-bench.toml").read_text()
    dbc = (EXAMPLES_DIR / "bench.dbc").resolve()
    text = text.replace('dbc = "bench.dbc"', f'dbc = "{dbc}"')
    path = tmp / "bench.toml"
    path.write_text(text)
    return path


def _run_cli(*argv: str) -> None:
    assert cli.main(list(argv)) == 0, argv


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Bench, dict[str, Path]]:
    """One simulated sweep written to every file format."""
    tmp = tmp_path_factory.mktemp("contract")
    bench_path = _bench_file(tmp)
    common = ["--bench", str(bench_path), "--duration", str(DURATION_S), "--seed", str(SEED)]
    files = {}
    for kind in ("csv", "mf4", "mcap"):
        files[kind] = tmp / f"run.{kind}"
        _run_cli("simulate", *common, "--out", str(files[kind]))
    for kind in ("blf", "asc", "trc"):
        files[kind] = tmp / f"run.{kind}"
        _run_cli("can-sim", *common, "--interface", "none", "--log", str(files[kind]))
    files["mf4-daq"] = _daq_layout(files["mf4"], tmp / "daq.mf4")
    return load_bench(bench_path), files


G0 = 9.80665  # m/s^2 per g


def _daq_layout(reference: Path, out: Path) -> Path:
    """The reference MF4 rewritten with asammdf as a DAQ would: its own names, accelerations
    in g, the speed in 1/min, the tacho as an event group (a 1 at each edge time)."""
    from asammdf import MDF, Signal

    with MDF(reference) as ref:
        accel = [ref.get(f"{s}_{a}") for s in "ABC" for a in "xyz"]
        rpm, tacho = ref.get("rpm"), ref.get("tacho")
    mdf = MDF(version="4.10")
    mdf.append(
        [Signal(x.samples / G0, x.timestamps, name="Acc" + x.name, unit="g") for x in accel],
        acq_name="DAQ",
    )
    mdf.append([Signal(rpm.samples, rpm.timestamps, name="n_mot", unit="1/min")], acq_name="ECU")
    edges = tacho.timestamps
    mdf.append([Signal(edges * 0 + 1, edges, name="TachoEdge", unit="")], acq_name="events")
    mdf.save(out, overwrite=True)
    mdf.close()
    return out


DAQ_CHANNELS = {
    **{f"{s}_{a}": f"Acc{s}_{a}" for s in "ABC" for a in "xyz"},
    "rpm": "n_mot",
    "tacho": "TachoEdge",
}


def _open(kind: str, bench: Bench, files: dict[str, Path]) -> Source:
    if kind == "sim":
        return open_source("sim", bench, duration_s=DURATION_S, seed=SEED)
    if kind == "virtual":
        channel = "ptinertia-contract"
        source = open_source(f"can:virtual:{channel}", bench, idle_timeout_s=1.0)
        frames = list(can.LogReader(str(files["blf"])))

        def send() -> None:
            with can.Bus(interface="virtual", channel=channel) as tx:
                for msg in frames:
                    tx.send(msg)

        sender = threading.Thread(target=send)
        sender.start()
        sender.join()
        return source
    if kind == "mf4-daq":
        bench = bench.model_copy(update={"channels": DAQ_CHANNELS})
    return open_source(f"file:{files[kind]}", bench)


def _collect(source: Source) -> tuple[dict, dict, list[SourceEvent]]:
    samples: dict[str, list[SampleBlock]] = {}
    edges: dict[str, list[np.ndarray]] = {}
    events: list[SourceEvent] = []
    for item in source:
        if isinstance(item, SampleBlock):
            samples.setdefault(item.group, []).append(item)
        elif isinstance(item, EdgeBlock):
            edges.setdefault(item.channel, []).append(item.times_s)
        else:
            assert isinstance(item, SourceEvent), type(item)
            events.append(item)
    return samples, edges, events


def _channel(samples: dict, layout, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Grid indices and values of one channel."""
    group, row = layout.find_channel(name)
    blocks = samples.get(group.name, [])
    idx = np.concatenate([b.first_index + np.arange(b.n_samples) for b in blocks])
    return idx, np.concatenate([b.data[row] for b in blocks])


@pytest.fixture(scope="module")
def reference(written) -> tuple:
    bench, files = written
    with _open("sim", bench, files) as src:
        return src.layout, _collect(src)


@pytest.mark.parametrize("kind", KINDS)
def test_every_source_keeps_the_contract(kind: str, written, reference) -> None:
    bench, files = written
    ref_layout, (ref_samples, ref_edges, _) = reference
    accel = [c for s in bench.sensors for c in s.channels if c]
    source = _open(kind, bench, files)
    with source:
        layout = source.layout  # known before the first item
        for name in accel:
            layout.find_channel(name)
        samples, edges, events = _collect(source)
    # blocks are well formed and, per group, contiguous and increasing on the group's grid
    for group, blocks in samples.items():
        n_ch = len(layout.group(group).channels)
        starts = [b.first_index for b in blocks]
        ends = [b.first_index + b.n_samples for b in blocks]
        assert starts[1:] == ends[:-1], f"{kind}: {group} blocks not contiguous on their grid"
        for b in blocks:
            assert b.data.dtype == np.float64 and b.data.shape[0] == n_ch
    # edges strictly increasing per channel, and the same tacho as the simulator's
    for channel, pieces in edges.items():
        times = np.concatenate(pieces)
        assert np.all(np.diff(times) > 0), f"{kind}: {channel} edges not increasing"
    assert set(edges) == set(ref_edges)
    # events are reports of one line each (a clean stream may still say how it went)
    for event in events:
        assert event.kind and "\n" not in event.message, event
    # every accelerometer sample is the simulator's, to the format's resolution
    for name in accel:
        ref_idx, ref_val = _channel(ref_samples, ref_layout, name)
        idx, val = _channel(samples, layout, name)
        common, ia, ib = np.intersect1d(ref_idx, idx, return_indices=True)
        assert common.size >= 0.95 * ref_idx.size, f"{kind}: {name} lost samples"
        err = np.max(np.abs(val[ib] - ref_val[ia]))
        allowed = RESOLUTION[kind](np.max(np.abs(ref_val))) * (1 + 1e-9)
        assert err <= allowed, f"{kind}: {name} off by {err:.3g} m/s^2 (format keeps {allowed:.3g})"
    # closing again is safe, and a closed source yields nothing more
    source.close()
    assert list(source) == []
