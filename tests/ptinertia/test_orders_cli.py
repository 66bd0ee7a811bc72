"""``ptinertia orders``: CSV and PNG of order amplitude and phase vs rpm, from sim and from files."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from ptinertia.cli import main
from ptinertia.config import load_bench
from ptinertia.sources import open_source

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture()
def short_bench(tmp_path: Path) -> Path:
    """The i3 bench with a 4 s, 1500 -> 1700 rpm sweep (50 rpm/s)."""
    text = (EXAMPLES / "i3-bench.toml").read_text(encoding="utf-8")
    text = text.replace("duration_s = 60.0", "duration_s = 4.0")
    text = text.replace("rpm_end = 4500.0", "rpm_end = 1700.0")
    assert "duration_s = 4.0" in text and "rpm_end = 1700.0" in text
    path = tmp_path / "bench.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return list(rows[0].keys()), rows


def _complex(row: dict[str, str], ch: str, h: float) -> complex:
    amp = float(row[f"{ch}_H{h:g}_amp_mps2"])
    return amp * complex(math.cos(math.radians(float(row[f"{ch}_H{h:g}_phase_deg"]))),
                         math.sin(math.radians(float(row[f"{ch}_H{h:g}_phase_deg"]))))  # fmt: skip


def test_sim_csv_holds_the_exact_amplitudes_and_png_is_written(short_bench, tmp_path, capsys):
    out, png = tmp_path / "orders.csv", tmp_path / "orders.png"
    code = main(
        ["orders", "sim", "--bench", str(short_bench), "--out", str(out), "--png", str(png)]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "frames" in printed and f"wrote {out}" in printed
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    cols, rows = _read(out)
    bench = load_bench(short_bench)
    channels = [c for s in bench.sensors for c in s.channels]
    assert cols[:5] == ["time_s", "rpm", "crank_angle_deg", "rpm_change", "flags"]
    assert len(cols) == 5 + len(channels) * 3 * 2 + len(channels)
    assert len(rows) > 90  # 4 s at ~27 rev/s, minus the start-up
    # against the simulator's own truth at each frame's rpm
    src = open_source("sim", bench)
    good = [r for r in rows if r["flags"] == "cycle_ambiguous"]
    rpm = np.array([float(r["rpm"]) for r in good])
    exact = src.exact_amplitudes(rpm, (1.0, 1.5, 2.0))
    for i, r in enumerate(good):
        for o, h in enumerate((1.0, 1.5, 2.0)):
            for c, ch in enumerate(channels):
                x = _complex(r, ch, h)
                floor = 1e-3 * np.abs(exact[i, :, c]).max()
                assert abs(x - exact[i, o, c]) <= 1e-3 * max(abs(exact[i, o, c]), floor)
    angles = np.array([float(r["crank_angle_deg"]) for r in rows])
    np.testing.assert_allclose(np.diff(angles), 360.0)


def test_a_recorded_file_gives_the_frames_of_the_live_stream(short_bench, tmp_path, capsys):
    rec = tmp_path / "run.csv"
    assert main(["simulate", "--bench", str(short_bench), "--out", str(rec)]) == 0
    live, replay = tmp_path / "live.csv", tmp_path / "replay.csv"
    assert main(["orders", "sim", "--bench", str(short_bench), "--out", str(live)]) == 0
    assert (
        main(
            [
                "orders",
                str(rec),
                "--bench",
                str(short_bench),
                "--orders",
                "1,1.5,2",
                "--out",
                str(replay),
            ]
        )
        == 0
    )
    capsys.readouterr()
    _, a = _read(live)
    _, b = _read(replay)
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        assert ra["crank_angle_deg"] == rb["crank_angle_deg"]
        assert abs(float(ra["rpm"]) - float(rb["rpm"])) < 1e-3
        assert abs(_complex(ra, "A_x", 1.0) - _complex(rb, "A_x", 1.0)) < 1e-5 * abs(
            _complex(ra, "A_x", 1.0)
        )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--orders", "1,x"], "--orders"),
        (["--orders", "1,1.25"], "multiples of 0.5"),
        (["--orders", "1,60"], "Nyquist"),
    ],
)
def test_bad_options_are_one_line_errors(short_bench, capsys, argv, message):
    code = main(["orders", "sim", "--bench", str(short_bench), *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and err.count("\n") == 1 and err.startswith("ptinertia orders: error:")


def test_a_missing_file_is_a_one_line_error(short_bench, tmp_path, capsys):
    code = main(["orders", str(tmp_path / "nope.csv"), "--bench", str(short_bench)])
    err = capsys.readouterr().err
    assert code == 2 and "nope.csv" in err and err.count("\n") == 1


def test_a_recording_without_its_bench_is_refused(tmp_path, capsys) -> None:
    """A recording is never tracked with the example bench by default (as ``run``)."""
    rec = tmp_path / "x.csv"
    rec.write_text("time_s,A_x\n0,0\n")
    assert main(["orders", str(rec)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs --bench" in err[0] and str(rec) in err[0]
