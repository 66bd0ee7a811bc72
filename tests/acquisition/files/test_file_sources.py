"""CSV and MF4 sources: what `simulate` writes reads back the same; bad files fail clearly."""

from __future__ import annotations

import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from acquisition.files.csvfile import CsvSource
from acquisition.stream import EdgeBlock, SampleBlock, SourceError, SourceEvent
from ptinertia import cli
from ptinertia.commands.simulate import simulate
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source

I3 = EXAMPLES_DIR / "i3-bench.toml"
SIM = {"duration_s": 0.6, "accel_rate_hz": 4096.0, "noise_snr_db": 40.0, "seed": 3}


def stream(source) -> tuple[dict, dict, list]:
    """Per group (first_index, data) pieces, per edge channel the times, and the events."""
    samples: dict[str, list] = {}
    edges: dict[str, list] = {}
    events: list[SourceEvent] = []
    for item in source:
        if isinstance(item, SampleBlock):
            samples.setdefault(item.group, []).append((item.first_index, item.data))
        elif isinstance(item, EdgeBlock):
            edges.setdefault(item.channel, []).append(item.times_s)
        else:
            events.append(item)
    return samples, edges, events


def joined(pieces: list) -> tuple[np.ndarray, np.ndarray]:
    idx = np.concatenate([np.arange(i, i + d.shape[1]) for i, d in pieces])
    return idx, np.concatenate([d for _, d in pieces], axis=1)


@pytest.fixture(scope="module", params=[".csv", ".mf4"])
def written(request, tmp_path_factory, i3):
    """A run written by `simulate` (edges and pressure), and the same run from the simulator."""
    out = tmp_path_factory.mktemp("run") / f"run{request.param}"
    overrides = {**SIM, "tacho": {"phase_reference": "pressure"}}
    summary = simulate(I3, out, **overrides)
    with open_source("sim", i3, **overrides) as src:
        direct = stream(src), src.layout
    return out, summary, direct


def test_written_run_reads_back_the_same_samples_and_edges(written, i3) -> None:
    out, summary, ((samples, edges, _), layout) = written
    with open_source(f"file:{out}", i3) as src:
        got_samples, got_edges, events = stream(src)
        got_layout = src.layout
    assert events == []
    assert [(g.name, g.rate_hz, g.channels, g.t0_s) for g in got_layout.groups] == [
        (g.name, g.rate_hz, g.channels, g.t0_s) for g in layout.groups
    ]
    assert got_layout.edge_channels == layout.edge_channels
    for g in layout.groups:
        i_a, x_a = joined(samples[g.name])
        i_b, x_b = joined(got_samples[g.name])
        assert np.array_equal(i_a, i_b)
        # float64 in both formats: bit for bit
        assert np.array_equal(x_a, x_b), g.name
    for ch in layout.edge_channels:
        assert np.array_equal(np.concatenate(edges[ch]), np.concatenate(got_edges[ch]))
    # the truth and the bench travel with the data
    assert got_layout.metadata["truth"] == layout.metadata["truth"]
    assert got_layout.metadata["bench_text"] == I3.read_text(encoding="utf-8")
    # samples at t < duration
    assert summary["samples"]["accel"] == math.ceil(SIM["duration_s"] * SIM["accel_rate_hz"])


def test_sampled_tacho_round_trip(tmp_path, i3) -> None:
    tacho = {"delivery": "sampled", "sample_rate_hz": 50_000.0}
    kw = {"duration_s": 0.2, "accel_rate_hz": 2048.0, "tacho": tacho}
    bench = i3.model_copy(update={"tacho": i3.tacho.model_copy(update=tacho)})
    with open_source("sim", i3, **kw) as src:
        direct, _, _ = stream(src)
    for suffix in (".csv", ".mf4"):
        out = tmp_path / f"s{suffix}"
        simulate(I3, out, **kw)
        with open_source(f"file:{out}", bench) as src:
            got, edges, _ = stream(src)
        assert not edges
        assert np.array_equal(joined(got["tacho"])[1], joined(direct["tacho"])[1])


@pytest.mark.parametrize("kind", ["sim", "csv", "mf4"])
def test_stream_contract_for_every_source(kind: str, tmp_path, i3) -> None:
    """One body over every implementation: contiguous indices, time order, idempotent close."""
    kw = {"duration_s": 0.45, "accel_rate_hz": 2048.0, "tacho": {"phase_reference": "cam"}}
    if kind == "sim":
        src = open_source("sim", i3, block_s=0.07, **kw)
    else:
        out = tmp_path / f"c.{kind}"
        simulate(I3, out, **kw)
        bench = i3.model_copy(
            update={"tacho": i3.tacho.model_copy(update={"phase_reference": "cam"})}
        )
        src = open_source(f"file:{out}", bench, block_s=0.07)
    layout = src.layout
    next_index = {g.name: 0 for g in layout.groups}
    last_edge = {c: -np.inf for c in layout.edge_channels}
    prev_start = -np.inf
    for item in src:
        if isinstance(item, SampleBlock):
            g = layout.group(item.group)
            assert item.first_index == next_index[g.name]
            next_index[g.name] += item.n_samples
            assert item.data.shape == (len(g.channels), item.n_samples)
            start = g.t0_s + item.first_index / g.rate_hz
        elif isinstance(item, EdgeBlock):
            assert item.times_s[0] > last_edge[item.channel] and np.all(np.diff(item.times_s) > 0)
            last_edge[item.channel] = item.times_s[-1]
            start = item.times_s[0]
        else:
            continue
        assert start >= prev_start
        prev_start = start
    assert next_index["accel"] == math.ceil(0.45 * 2048)
    src.close()
    src.close()
    assert list(src) == []


def test_reader_streams_in_chunks(tmp_path, i3) -> None:
    out = tmp_path / "r.csv"
    simulate(I3, out, duration_s=1.0, accel_rate_hz=2048.0)
    with CsvSource(out) as src:
        ref, ref_e, _ = stream(src)
    with CsvSource(out, rows_per_chunk=37, block_s=0.013) as src:
        small, small_e, _ = stream(src)
    for g in ref:
        assert np.array_equal(joined(ref[g])[1], joined(small[g])[1])
    assert np.array_equal(np.concatenate(ref_e["tacho"]), np.concatenate(small_e["tacho"]))
    # a file is not read whole on opening: a bad line far down fails only when reached
    lines = out.read_text().splitlines()
    lines[1800] = lines[1800].replace(",", ",x", 1)
    out.write_text("\n".join(lines) + "\n")
    src = CsvSource(out, rows_per_chunk=100)
    with pytest.raises(SourceError, match=r"r\.csv: line 1801, column 'A_x': expected a number"):
        stream(src)
    src.close()


def write_csv(path: Path, header: str, rows: list[str]) -> Path:
    path.write_text(header + "\n" + "".join(r + "\n" for r in rows), encoding="utf-8")
    return path


def test_gap_splits_blocks_and_is_reported(tmp_path) -> None:
    rows = [f"{k / 100!r},{k}.0" for k in [*range(0, 50), *range(53, 80)]]
    src = CsvSource(write_csv(tmp_path / "g.csv", "time_s,a[V]", rows))
    samples, _, events = stream(src)
    idx, x = joined(samples["accel"])
    assert np.array_equal(idx, [*range(0, 50), *range(53, 80)])
    assert np.array_equal(x[0], idx.astype(float))
    gaps = [e for e in events if e.kind == "gap"]
    assert len(gaps) == 1 and gaps[0].count == 3 and gaps[0].time_s == pytest.approx(0.53)


def test_nan_samples_are_passed_on(tmp_path) -> None:
    rows = [f"{k / 10!r},{'nan' if k == 4 else k}" for k in range(10)]
    src = CsvSource(write_csv(tmp_path / "n.csv", "time_s,a[V]", rows))
    samples, _, events = stream(src)
    x = joined(samples["accel"])[1][0]
    assert np.isnan(x[4]) and np.isfinite(np.delete(x, 4)).all()
    assert [e.kind for e in events] == ["nan"] and "'a'" in events[0].message


def test_time_offset_and_rate_inferred(tmp_path) -> None:
    # times written with 6 decimals at 25.6 kHz, starting at 12.5 s
    rows = [f"{12.5 + k / 25600:.6f},{k}" for k in range(3000)]
    src = CsvSource(write_csv(tmp_path / "o.csv", "time_s,a[V]", rows))
    g = src.layout.group("accel")
    assert g.rate_hz == 25600.0 and g.t0_s == 12.5
    idx, _ = joined(stream(src)[0]["accel"])
    assert np.array_equal(idx, np.arange(3000))


@pytest.mark.parametrize(
    ("header", "rows", "match"),
    [
        ("", [], r"empty file, expected a header"),
        ("time_s,a[V],nan", ["0,1,2"], r"header column 3 is 'nan': expected name\[unit\]"),
        ("time_s,,b[V]", ["0,1,2"], r"header column 2 is '': expected name\[unit\]"),
        ("t,a[V]", ["0,1"], r"first column is 't': expected time_s"),
        (
            "time_s,a[V]",
            ["0,1", "0.1,2", "0.05,3"],
            r"time_s at line 4 is 0.05 s, not after the previous 0.1 s",
        ),
        ("time_s,a[V]", ["0,1", "0.1,2", "nan,3"], r"time_s at line 4 is nan"),
        ("time_s,a[V]", ["0,1", "0.1,2", "0.2,3", "0.34,4"], r"off the 10 Hz sampling grid"),
        (
            "time_s,a[V],b[V]",
            ["0,1,2", "0.1,2"],
            r"line 3: expected 3 columns as in the header, got 2",
        ),
        ("time_s,a[V],b[V]", ["0,1,2", "0.1,2,zz"], r"line 3, column 'b': expected a number"),
        ("time_s,a[V]", ["0,1"], r"need at least 2 samples"),
    ],
)
def test_bad_csv_is_one_clear_line(tmp_path, header: str, rows: list[str], match: str) -> None:
    path = write_csv(tmp_path / "bad.csv", header, rows)
    with pytest.raises(SourceError, match=match) as err:
        stream(CsvSource(path))
    message = str(err.value)
    assert "\n" not in message and str(path) in message


def test_bad_edge_file(tmp_path) -> None:
    write_csv(tmp_path / "e.csv", "time_s,a[V]", [f"{k / 10!r},1" for k in range(5)])
    write_csv(tmp_path / "e.tacho.csv", "tacho_edge_s", ["0.01", "0.02", "0.015"])
    with pytest.raises(
        SourceError, match=r"e\.tacho\.csv: tacho edge at line 4 is 0.015 s, not after"
    ):
        stream(CsvSource(tmp_path / "e.csv"))


def test_unreadable_files(tmp_path, i3) -> None:
    with pytest.raises(SourceError, match=r"nope\.csv: cannot read"):
        open_source(f"file:{tmp_path / 'nope.csv'}", i3)
    with pytest.raises(SourceError, match=r"nope\.mf4: no such MDF file"):
        open_source(f"file:{tmp_path / 'nope.mf4'}", i3)
    junk = tmp_path / "junk.mf4"
    junk.write_bytes(b"this is not an MDF file at all" * 10)
    with pytest.raises(SourceError, match=r"junk\.mf4: not a readable MDF4 file"):
        open_source(f"file:{junk}", i3)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(SourceError, match=r"bin\.csv"):
        stream(open_source(f"file:{binary}", i3))
    with pytest.raises(SourceError, match=r"extension '\.txt' not supported"):
        open_source(f"file:{tmp_path / 'x.txt'}", i3)
    with pytest.raises(SourceError):  # routed to the CAN backend, which refuses it clearly
        open_source("can:nosuchbus:0", i3)
    with pytest.raises(SourceError, match="expected 'sim', 'file:PATH'"):
        open_source("bogus", i3)


@pytest.mark.parametrize("suffix", [".csv", ".mf4"])
def test_missing_channel_names_it(tmp_path, i3, suffix: str) -> None:
    out = tmp_path / f"m{suffix}"
    simulate(I3, out, duration_s=0.2, accel_rate_hz=2048.0)
    renamed = i3.model_copy(
        update={
            "sensors": [
                i3.sensors[0].model_copy(update={"channels": ["A_x", "A_yy", "A_z"]}),
                *i3.sensors[1:],
            ]
        }
    )
    with pytest.raises(SourceError, match=r"channel 'A_yy' \(sensor A_engine_mount\) not found"):
        open_source(f"file:{out}", renamed)
    sampled = i3.model_copy(update={"tacho": i3.tacho.model_copy(update={"delivery": "sampled"})})
    with pytest.raises(SourceError, match=r"'tacho' .* not found \(it is an edge channel there"):
        open_source(f"file:{out}", sampled)


def test_cli_turns_a_missing_column_into_one_line_and_exit_2(
    tmp_path, i3, monkeypatch, capsys
) -> None:
    """The CLI path every reading command takes: open_source -> SourceError -> one line, code 2."""
    out = tmp_path / "cli.csv"
    simulate(I3, out, duration_s=0.2, accel_rate_hz=2048.0)
    text = out.read_text().replace("B_z[m/s^2]", "B_zz[m/s^2]", 1)
    out.write_text(text)
    module = types.ModuleType("_read_probe")

    def add_parser(sub, name, help_text):
        p = sub.add_parser(name, help=help_text)
        p.add_argument("file")
        return p

    def run(args):
        with open_source("file:" + args.file, load_bench(I3)) as src:
            for _ in src:
                pass
        return 0

    module.add_parser, module.run = add_parser, run
    monkeypatch.setitem(sys.modules, "_read_probe", module)
    monkeypatch.setitem(cli.COMMANDS, "readprobe", ("_read_probe", "read a file source"))
    assert cli.main(["readprobe", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "channel 'B_z' (sensor B_gearbox_mount) not found" in err
