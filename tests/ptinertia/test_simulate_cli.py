"""`ptinertia simulate`: options reach the simulation, files are written, bad input is one line."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from acquisition.stream import EdgeBlock, SampleBlock
from ptinertia.cli import main
from ptinertia.config import load_bench
from ptinertia.paths import DEFAULT_BENCH, EXAMPLES_DIR
from ptinertia.sources import open_source

I4 = EXAMPLES_DIR / "i4-bench.toml"


def read_back(path, bench_path=DEFAULT_BENCH, **bench_updates):
    bench = load_bench(bench_path)
    if bench_updates:
        bench = bench.model_copy(update={"tacho": bench.tacho.model_copy(update=bench_updates)})
    samples: dict[str, list[np.ndarray]] = {}
    edges: dict[str, list[np.ndarray]] = {}
    with open_source(f"file:{path}", bench) as src:
        layout = src.layout
        for item in src:
            if isinstance(item, SampleBlock):
                samples.setdefault(item.group, []).append(item.data)
            elif isinstance(item, EdgeBlock):
                edges.setdefault(item.channel, []).append(item.times_s)
    return (
        layout,
        {k: np.concatenate(v, axis=1) for k, v in samples.items()},
        {k: np.concatenate(v) for k, v in edges.items()},
    )


def test_options_reach_the_simulation(tmp_path, capsys) -> None:
    out = tmp_path / "run.csv"
    rc = main(
        [
            "simulate",
            "--sweep",
            "2000:3200",
            "--duration",
            "1.5",
            "--fs",
            "3000",
            "--noise-db",
            "30",
            "--seed",
            "11",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and str(out) in printed
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "run.csv",
        "run.meta.json",
        "run.rpm.csv",
        "run.tacho.csv",
    ]
    layout, samples, edges = read_back(out)
    assert layout.group("accel").rate_hz == 3000.0
    assert samples["accel"].shape == (9, math.ceil(1.5 * 3000))
    rpm = samples["rpm"][0]
    assert rpm[0] == pytest.approx(2000.0) and rpm[-1] == pytest.approx(
        2000 + 1200 * (len(rpm) - 1) / 100 / 1.5
    )
    meta = layout.metadata
    assert meta["seed"] == 11 and meta["noise_snr_db"] == 30.0 and meta["truth"]["seed"] == 11
    assert meta["profile"] == [{"duration_s": 1.5, "rpm_from": 2000.0, "rpm_to": 3200.0}]
    # about 58 teeth per revolution over the run's revolutions
    revs = 0.5 * (2000 + 3200) / 60 * 1.5
    assert abs(edges["tacho"].size - 58 * revs) < 60
    assert (
        json.loads((tmp_path / "run.meta.json").read_text())["bench"]["meta"]["name"]
        == "i3-1.0L-transverse"
    )


def test_mf4_output_with_other_bench_and_sampled_tacho(tmp_path) -> None:
    out = tmp_path / "i4.mf4"
    assert (
        main(
            [
                "simulate",
                "--bench",
                str(I4),
                "--sweep",
                "2500",
                "--duration",
                "0.25",
                "--tacho",
                "sampled",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert [p.name for p in tmp_path.iterdir()] == ["i4.mf4"]
    layout, samples, edges = read_back(out, I4, delivery="sampled")
    assert not edges and set(samples) == {"accel", "rpm", "tacho"}
    assert np.all(samples["rpm"] == 2500.0)  # one rpm: a constant speed
    assert layout.metadata["bench"]["meta"]["name"] == "i4-1.6L-transverse"


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--out", "{tmp}/run.txt"], "output file extension '.txt'"),
        (["--out", "{tmp}/missing/run.csv"], "does not exist"),
        (["--sweep", "1500:fast", "--out", "{tmp}/r.csv"], "sweep '1500:fast'"),
        (["--duration", "-3", "--out", "{tmp}/r.csv"], "simulation.duration_s"),
        (["--fs", "300", "--out", "{tmp}/r.csv"], "aliases"),
        (["--bench", "{tmp}/none.toml", "--out", "{tmp}/r.csv"], "cannot read bench file"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv: list[str], needle: str) -> None:
    rc = main(["simulate", *(a.format(tmp=tmp_path) for a in argv)])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("ptinertia simulate: error: ") and err.count("\n") == 1
    assert needle in err and "Traceback" not in err
    assert not any(p.suffix in (".csv", ".mf4") for p in tmp_path.rglob("*"))


def test_console_script_runs(tmp_path) -> None:
    out = tmp_path / "p.csv"
    res = subprocess.run(
        [sys.executable, "-m", "ptinertia", "simulate", "--duration", "0.2", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""  # no progress bar when stderr is not a terminal
    assert out.exists()
