"""The bench engineer's commands end to end: run, record, replay, bad input."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ptinertia.cli import main
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR

I3 = EXAMPLES_DIR / "i3-bench.toml"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("run")
    log, result = out / "x.mcap", out / "r.json"
    code = main(["run", "--rerun", "off", "--quiet", "--record", str(log), "--json", str(result)])
    assert code == 0
    return log, result


def test_run_on_defaults_meets_the_noise_free_accuracy(recorded: tuple[Path, Path]) -> None:
    doc = json.loads(recorded[1].read_text())
    truth = doc["truth"]["inertia_kgm2"]["value"]
    for term, value in doc["inertia_kgm2"]["value"].items():
        assert value == pytest.approx(truth[term], rel=0.002), term
    cog = np.array(doc["cog_m"]["value"]) - np.array(doc["truth"]["cog_m"]["value"])
    assert np.all(np.abs(cog) < 0.0005)
    assert doc["frames"]["used"] > 1400  # every other revolution: 720 deg windows, not overlapping
    assert doc["rpm_range"][0] < 1600 and doc["rpm_range"][1] > 4400


def test_replay_gives_the_recorded_result_exactly(
    recorded: tuple[Path, Path], tmp_path: Path
) -> None:
    log, result = recorded
    again = tmp_path / "r2.json"
    assert main(["replay", str(log), "--quiet", "--json", str(again)]) == 0
    assert json.loads(again.read_text()) == json.loads(result.read_text())


def test_replay_with_a_correction_off_re_estimates(
    recorded: tuple[Path, Path], tmp_path: Path
) -> None:
    log, result = recorded
    plain = tmp_path / "plain.json"
    assert main(["replay", str(log), "--quiet", "--no", "suspension", "--json", str(plain)]) == 0
    a = json.loads(plain.read_text())["inertia_kgm2"]["value"]
    b = json.loads(result.read_text())["inertia_kgm2"]["value"]
    assert abs(a["Ixx"] - b["Ixx"]) / b["Ixx"] > 0.01  # the mount bias comes back


def test_replay_of_a_directory_writes_one_result_per_log(
    recorded: tuple[Path, Path], tmp_path: Path
) -> None:
    log, _ = recorded
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("a", "b"):
        (logs / f"{name}.mcap").write_bytes(log.read_bytes())
    assert main(["replay", str(logs), "--quiet"]) == 0
    assert sorted(p.name for p in logs.glob("*.result.json")) == ["a.result.json", "b.result.json"]


def _one_line_error(capsys: pytest.CaptureFixture[str], code: int) -> str:
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_non_mcap_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_text("not a recording")
    err = _one_line_error(capsys, main(["replay", str(bad), "--quiet"]))
    assert "bad.mcap" in err


def test_bench_override_missing_a_recorded_channel_is_one_line(
    recorded: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = I3.read_text().replace(
        'channels = ["A_x", "A_y", "A_z"]', 'channels = ["P_x", "P_y", "P_z"]'
    )
    other = tmp_path / "other.toml"
    other.write_text(text)
    err = _one_line_error(
        capsys, main(["replay", str(recorded[0]), "--bench", str(other), "--quiet"])
    )
    assert "P_x" in err


def test_bad_source_spec_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    err = _one_line_error(
        capsys, main(["run", "--source", "nonsense", "--rerun", "off", "--quiet"])
    )
    assert "nonsense" in err


def test_sweep_outside_the_mass_line_range_ends_without_estimate(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # 600 -> 700 rpm: H1, H1.5 and H2 all lie among the rigid-body modes (< 1.25 x 19.2 Hz)
    code = main(["run", "--sweep", "600:700", "--duration", "5", "--rerun", "off", "--quiet"])
    assert code == 1
    err = capsys.readouterr().err
    assert "no estimate" in err and "mass-line range" in err


def test_a_dead_sensor_in_a_file_leaves_two_that_still_estimate(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # Two triaxial sensors do not measure the rotation about the line through them:
    # it is fitted per frame (estimator/partial.py), and the run says so.
    csv = tmp_path / "s.csv"
    assert main(["simulate", "--duration", "6", "--out", str(csv)]) == 0
    lines = csv.read_text().splitlines()
    assert lines[0].split(",")[7:10] == ["C_x[m/s^2]", "C_y[m/s^2]", "C_z[m/s^2]"], lines[0]
    dead = [lines[0]] + [",".join(r.split(",")[:7] + ["nan"] * 3) for r in lines[1:]]
    csv.write_text("\n".join(dead) + "\n")
    capsys.readouterr()
    out = tmp_path / "r.json"
    code = main(
        ["run", "--bench", str(I3), "--source", f"file:{csv}", "--rerun", "off", "--json", str(out)]
    )
    assert code == 0  # (the printed note is checked in test_two_sensors, in a subprocess)
    doc = json.loads(out.read_text())
    assert doc["unseen_motion"]["converged"]
    # the line through sensors A and B of the example bench
    a, b = np.array([0.05, 0.30, 0.29]), np.array([0.02, -0.42, 0.25])
    line = (a - b) / np.linalg.norm(a - b)
    assert abs(np.dot(doc["unseen_motion"]["unseen_rotation_axis"], line)) > 1 - 1e-9
    truth = load_bench(I3).powertrain.inertia_kgm2.model_dump()
    for k, v in doc["inertia_kgm2"]["value"].items():
        assert abs(v - truth[k]) < 0.01 * abs(truth[k]), (k, v, truth[k])


def test_ctrl_c_finishes_the_recording(tmp_path: Path) -> None:
    log = tmp_path / "live.mcap"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ptinertia",
            "run",
            "--paced",
            "--rerun",
            "off",
            "--record",
            str(log),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    # Ctrl-C in the middle of the run, once there is an estimate to finish with: the
    # progress line that first shows one (a line every 10 s off a terminal; the paced
    # sweep lasts a minute, so the run is far from its end)
    assert proc.stderr is not None
    seen = []
    for line in iter(proc.stderr.readline, b""):
        seen.append(line)
        if line.startswith(b"t ") and b"kg m^2" in line:
            break
    assert seen and b"kg m^2" in seen[-1], b"".join(seen).decode()
    proc.send_signal(signal.SIGINT)
    _, rest = proc.communicate(timeout=60)
    err = b"".join(seen) + rest
    assert proc.returncode in (0, 130), err.decode()
    from replay.reader import open_log

    recording = open_log(log)
    assert recording.finished  # footer written: the shutdown was clean
    assert b"Traceback" not in err


def test_a_confirmed_elastic_mode_is_reported_and_logged(tmp_path: Path) -> None:
    text = I3.read_text().replace(
        "[simulation]",
        "[simulation]\nelastic_mode = { frequency_hz = 140.0, damping_ratio = 0.03, "
        "participation = 0.1 }",
    )
    bench = tmp_path / "elastic.toml"
    bench.write_text(text)
    (tmp_path / "bench.dbc").write_text((EXAMPLES_DIR / "bench.dbc").read_text())
    log, result = tmp_path / "e.mcap", tmp_path / "e.json"
    argv = ["run", "--bench", str(bench), "--duration", "20", "--rerun", "off", "--quiet"]
    assert main([*argv, "--record", str(log), "--json", str(result)]) == 0
    doc = json.loads(result.read_text())
    assert doc["elastic_mode"]["order"] == 2.0 and 40 < doc["elastic_mode"]["frequency_hz"] < 140

    from replay.reader import open_log

    kinds = [event.kind for _, event in open_log(log).events()]
    assert kinds.count("elastic_mode") == 1


def test_no_estimate_names_the_bending_orders_over_the_low_ones_among_the_modes() -> None:
    from ptinertia.no_estimate import no_estimate_reason

    frames = {"near_rigid_modes": 29, "dsp_settling": 1}
    assert "mass-line range" in no_estimate_reason(frames, {"near_rigid_modes": 58})
    fast = no_estimate_reason(frames, {"near_rigid_modes": 58, "neighbour_leakage": 17})
    assert "too fast" in fast and "17 orders" in fast


def test_replay_with_mount_scale_estimates_the_mounts(
    recorded: tuple[Path, Path], tmp_path: Path
) -> None:
    out = tmp_path / "scaled.json"
    assert main(["replay", str(recorded[0]), "--mount-scale", "--quiet", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    scales = doc["mount_stiffness_scale"]
    assert set(scales) == {"engine_rh", "gearbox_lh", "torque_rod"}
    for name, s in scales.items():
        assert s["value"] == pytest.approx(1.0, abs=0.01), name  # the simulation used the file's
    truth = doc["truth"]["inertia_kgm2"]["value"]
    for term, value in doc["inertia_kgm2"]["value"].items():
        assert value == pytest.approx(truth[term], rel=0.002), term
