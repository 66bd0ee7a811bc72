"""Files a bench file names (a pressure trace, a DBC): resolved beside the bench file,
carried into a recording, and read from it again on replay."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from powertrain.gas import CylinderGeometry
from ptinertia.cli import main
from ptinertia.config import GAS_FILE_KEY, bench_file_paths, load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_physics import build_model

I3 = EXAMPLES_DIR / "i3-bench.toml"
GAS_SECTION = re.compile(r"^\[gas\]\n(?:[^\[\n].*\n|\n)*", re.MULTILINE)


@pytest.fixture(scope="module")
def traced_bench(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The i3 bench with its gas model replaced by the pressure trace the model gives,
    in a file named relatively, and a crankcase pressure of 0.5 bar."""
    folder = tmp_path_factory.mktemp("traced")
    model = build_model(load_bench(I3))
    engine = model.engine
    geometry = CylinderGeometry(engine.bore, engine.stroke, engine.conrod_length)
    deg = np.arange(0.0, 720.25, 0.5)
    bar = engine.gas.pressure(geometry, np.radians(deg)) / 1e5
    (folder / "cyl1.csv").write_text(
        "crank_deg,pressure_bar\n"
        + "".join(f"{a:.3f},{p:.9f}\n" for a, p in zip(deg, bar, strict=True))
    )
    text = I3.read_text(encoding="utf-8")
    gas = '[gas]\nmodel = "trace"\nfile = "cyl1.csv"\ncrankcase_pressure_pa = 50000.0\n\n'
    bench = folder / "traced.toml"
    bench.write_text(
        GAS_SECTION.sub(gas, text, count=1).replace('dbc = "bench.dbc"', 'dbc = "../bench.dbc"')
    )
    return bench


def test_a_trace_is_found_beside_its_bench_and_keeps_its_settings(traced_bench: Path) -> None:
    bench = load_bench(traced_bench)
    assert bench_file_paths(bench)[GAS_FILE_KEY] == str(traced_bench.parent / "cyl1.csv")
    assert bench.gas.crankcase_pressure_pa == 50000.0  # was reset to 1 atm by the path fix-up


def test_a_recording_carries_the_trace_and_replays_without_the_bench(
    traced_bench: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    log, live, replayed = tmp_path / "run.mcap", tmp_path / "live.json", tmp_path / "replay.json"
    argv = ["run", "--bench", str(traced_bench), "--duration", "4", "--rerun", "off", "--quiet"]
    assert main([*argv, "--record", str(log), "--json", str(live)]) == 0
    traced_bench.parent.joinpath("cyl1.csv").rename(traced_bench.parent / "moved.csv")
    try:
        monkeypatch.chdir(tmp_path)  # nothing on disk to find the trace by
        assert main(["replay", str(log), "--quiet", "--json", str(replayed)]) == 0
    finally:
        traced_bench.parent.joinpath("moved.csv").rename(traced_bench.parent / "cyl1.csv")
    a, b = json.loads(live.read_text()), json.loads(replayed.read_text())
    assert a["inertia_kgm2"] == b["inertia_kgm2"] and a["cog_m"] == b["cog_m"]


def test_a_replay_with_another_bench_records_the_files_it_read(
    traced_bench: Path, tmp_path: Path
) -> None:
    """``replay --bench B --record`` carries B's pressure trace, not the first log's: the new
    recording replays alone to the result of the replay that wrote it."""
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    argv = ["run", "--bench", str(traced_bench), "--duration", "4", "--rerun", "off", "--quiet"]
    assert main([*argv, "--record", str(first)]) == 0
    folder = traced_bench.parent
    rows = (folder / "cyl1.csv").read_text().splitlines()
    scaled = [rows[0]] + [f"{a},{1.1 * float(p):.9f}" for a, p in (r.split(",") for r in rows[1:])]
    (tmp_path / "cyl1-hot.csv").write_text("\n".join(scaled) + "\n")
    hot = tmp_path / "hot.toml"
    hot.write_text(
        traced_bench.read_text()
        .replace('file = "cyl1.csv"', f'file = "{tmp_path / "cyl1-hot.csv"}"')
        .replace('dbc = "../bench.dbc"', f'dbc = "{EXAMPLES_DIR / "bench.dbc"}"')
    )
    with_hot, again = tmp_path / "hot.json", tmp_path / "again.json"
    replay = ["replay", str(first), "--bench", str(hot), "--quiet", "--rerun", "off"]
    assert main([*replay, "--record", str(second), "--json", str(with_hot)]) == 0
    assert main(["replay", str(second), "--quiet", "--json", str(again)]) == 0
    a, b = json.loads(with_hot.read_text()), json.loads(again.read_text())
    assert a["inertia_kgm2"] == b["inertia_kgm2"] and a["cog_m"] == b["cog_m"]
