"""Fuzzing the user's inputs: bench TOML values, CSV content, DBC, ASC/TRC lines, CLI options.

The property, for every input: the command exits 0, or it exits 1 or 2 with its reason on
one line. Never a traceback (an exception escaping ``main`` fails the test with it), never
a hang (the inputs are tiny: a hang shows as the suite's timeout).

In the suite each test tries a few examples (a few seconds in all, hypothesis' database
keeps the failures it found). The long profile, by hand::

    PTI_FUZZ=long .venv/bin/python -m pytest -q tests/ptinertia/test_fuzz_inputs.py

runs 300 examples per test (``PTI_FUZZ_EXAMPLES=N`` for another number): the bench, CSV and
CLI tests take a few minutes each on two shared cores, the DBC and CAN-log tests (a decoded
run per example) longer; 20 minutes covered the first four tests with no failure.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from ptinertia.cli import main
from ptinertia.paths import EXAMPLES_DIR

LONG = os.environ.get("PTI_FUZZ") == "long"
FUZZ = settings(
    max_examples=int(os.environ.get("PTI_FUZZ_EXAMPLES", 300)) if LONG else 6,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    derandomize=not LONG,  # the suite is reproducible; the long profile explores
)
BENCH = (EXAMPLES_DIR / "i3-bench.toml").read_text(encoding="utf-8")
DBC = (EXAMPLES_DIR / "bench.dbc").read_text(encoding="utf-8")


def check(argv: list[str], capsys: pytest.CaptureFixture[str]) -> int:
    """Run ``argv``; assert the property; return the exit code."""
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = main(argv)
        except SystemExit as stop:  # argparse's own errors
            code = int(stop.code or 0)
    # numpy's warnings on NaN samples would be printed to the user as noise
    noisy = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not noisy, noisy
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    assert code in (0, 1, 2), (code, err)
    if code:
        reasons = [ln for ln in err.splitlines() if ": error: " in ln or "no estimate" in ln]
        assert len(reasons) == 1, err
    return code


# -- values as TOML text ------------------------------------------------------------------------


def toml_float(x: float) -> str:
    if x != x:
        return "nan"
    if x in (float("inf"), float("-inf")):
        return "inf" if x > 0 else "-inf"
    return repr(x)


SCALARS = st.one_of(
    st.floats().map(toml_float),
    st.integers(-(2**70), 2**70).map(str),
    st.booleans().map(lambda b: "true" if b else "false"),
    st.sampled_from(['""', '"x"', "1e308", "-1e308", "5e-324", "0", "-0.0", "[]"]),
)
VALUES = st.one_of(
    SCALARS, st.lists(SCALARS, min_size=0, max_size=4).map(lambda v: f"[{', '.join(v)}]")
)
# every "key = value" line of the example bench with a number or a vector as value
NUMERIC_LINES = [
    i for i, line in enumerate(BENCH.splitlines()) if re.match(r"^\w+ = [-\[0-9]", line)
]


def bench_with(tmp_path: Path, line_no: int, value: str) -> Path:
    lines = BENCH.splitlines()
    key = lines[line_no].split(" = ", 1)[0]
    lines[line_no] = f"{key} = {value}"
    text = "\n".join(lines).replace('dbc = "bench.dbc"', f'dbc = "{EXAMPLES_DIR / "bench.dbc"}"')
    path = tmp_path / "bench.toml"
    path.write_text(text, encoding="utf-8")
    return path


@FUZZ
@given(line_no=st.sampled_from(NUMERIC_LINES), value=VALUES)
@example(
    line_no=next(i for i in NUMERIC_LINES if "axes" in BENCH.splitlines()[i]),
    value="[[inf, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
)
@example(
    line_no=next(i for i in NUMERIC_LINES if "accel_rate_hz" in BENCH.splitlines()[i]), value="1e9"
)
@example(line_no=next(i for i in NUMERIC_LINES if "seed" in BENCH.splitlines()[i]), value="-1")
@example(line_no=next(i for i in NUMERIC_LINES if "mass_kg" in BENCH.splitlines()[i]), value="true")
def test_bench_values(
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    line_no: int,
    value: str,
) -> None:
    bench = bench_with(tmp_path_factory.mktemp("bench"), line_no, value)
    check(["modes", "--bench", str(bench)], capsys)
    check(["excitation", "--bench", str(bench), "--rpm", "3000"], capsys)


def test_bench_byte_order_mark_and_encoding(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bench = bench_with(
        tmp_path, NUMERIC_LINES[0], BENCH.splitlines()[NUMERIC_LINES[0]].split(" = ")[1]
    )
    bench.write_bytes(b"\xef\xbb\xbf" + bench.read_bytes())
    assert check(["modes", "--bench", str(bench)], capsys) == 0
    bench.write_bytes(bench.read_bytes().replace(b"i3", b"i\xff3", 1))
    assert check(["modes", "--bench", str(bench)], capsys) == 2


# -- recordings: CSV, DBC, ASC/TRC --------------------------------------------------------------


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("rec")
    out = {"csv": d / "s.csv", "asc": d / "s.asc", "trc": d / "s.trc"}
    assert (
        main(["simulate", "--out", str(out["csv"]), "--duration", "0.3", "--sweep", "1500:1600"])
        == 0
    )
    for ext in ("asc", "trc"):
        argv = ["can-sim", "--interface", "none", "--log", str(out[ext]), "--duration", "0.2"]
        assert main([*argv, "--sweep", "2000:2050"]) == 0
    return out


CELLS = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "1e308", "true", "", "x", "0x10", "1,2", "\u00e9"]),
    st.floats().map(repr),
    st.text(max_size=6),
)


def mutated_copy(src: Path, dst_dir: Path, mutate) -> Path:
    """Copy ``src`` and the files read with it into ``dst_dir``, ``src`` mutated."""
    stem = src.name.split(".")[0]
    for p in src.parent.iterdir():
        if p.name.startswith(stem + "."):
            (dst_dir / p.name).write_bytes(p.read_bytes())
    dst = dst_dir / src.name
    dst.write_bytes(mutate(src.read_bytes()))
    return dst


@FUZZ
@given(row=st.integers(0, 400), col=st.integers(0, 12), cell=CELLS, cut=st.booleans())
@example(row=5, col=1, cell="nan", cut=False)
def test_csv_content(
    recordings: dict[str, Path],
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    row: int,
    col: int,
    cell: str,
    cut: bool,
) -> None:
    def mutate(data: bytes) -> bytes:
        lines = data.decode().split("\n")
        r = row % len(lines)
        cells = lines[r].split(",")
        cells[col % len(cells)] = cell
        lines[r] = ",".join(cells)
        text = "\n".join(lines).encode("utf-8", "surrogatepass")
        return text[: len(text) * 2 // 3] if cut else text

    csv = mutated_copy(recordings["csv"], tmp_path_factory.mktemp("csv"), mutate)
    check(["orders", str(csv), "--bench", str(EXAMPLES_DIR / "i3-bench.toml")], capsys)


@FUZZ
@given(raw=st.binary(max_size=64), at=st.integers(0, 10_000))
@example(raw=b"\xff\xfe", at=300)
def test_csv_bytes(
    recordings: dict[str, Path],
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    raw: bytes,
    at: int,
) -> None:
    csv = mutated_copy(
        recordings["csv"], tmp_path_factory.mktemp("csvb"), lambda d: d[:at] + raw + d[at:]
    )
    check(["orders", str(csv), "--bench", str(EXAMPLES_DIR / "i3-bench.toml")], capsys)


DBC_LINES = [i for i, ln in enumerate(DBC.splitlines()) if ln.startswith(("BO_", " SG_"))]


@FUZZ
@given(
    line_no=st.sampled_from(DBC_LINES),
    number=st.sampled_from(["0", "256", "257", "2048", "-1", "65", "4294967295", "1e9", "x"]),
    which=st.integers(0, 8),
)
@example(
    line_no=next(i for i in DBC_LINES if DBC.splitlines()[i].startswith("BO_ 257")),
    number="256",
    which=0,
)
def test_dbc(
    recordings: dict[str, Path],
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    line_no: int,
    number: str,
    which: int,
) -> None:
    lines = DBC.splitlines()
    nums = list(re.finditer(r"-?\d+(\.\d+)?", lines[line_no]))
    m = nums[which % len(nums)]
    lines[line_no] = lines[line_no][: m.start()] + number + lines[line_no][m.end() :]
    dbc = tmp_path_factory.mktemp("dbc") / "bench.dbc"
    dbc.write_text("\n".join(lines))
    code = check(
        [
            "run",
            "--source",
            f"file:{recordings['asc']}",
            "--dbc",
            str(dbc),
            "--rerun",
            "off",
            "--quiet",
        ],
        capsys,
    )
    if line_no == DBC_LINES[0] and number == "256":  # a duplicate id is a DBC error
        assert code == 2


TIMES = st.one_of(
    st.sampled_from(["1e11", "100000000000.000000", "-1", "nan", "inf", "0", "1e308", "x"]),
    st.floats(0, 1e12).map(lambda t: f"{t:.6f}"),
)


@FUZZ
@given(
    kind=st.sampled_from(["asc", "trc"]), line=st.integers(0, 420), time=TIMES, garble=st.booleans()
)
@example(kind="asc", line=200, time="100000000000.000000", garble=False)
def test_can_log_lines(
    recordings: dict[str, Path],
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    kind: str,
    line: int,
    time: str,
    garble: bool,
) -> None:
    def mutate(data: bytes) -> bytes:
        lines = data.decode().split("\n")
        r = line % len(lines)
        fields = lines[r].split()
        if fields:
            # the timestamp: first field in ASC, second in TRC; garble: a data byte
            k = (len(fields) - 1) if garble else (0 if kind == "asc" else min(1, len(fields) - 1))
            fields[k] = time if not garble else "ZZ"
        lines[r] = " " + " ".join(fields)
        return "\n".join(lines).encode()

    log = mutated_copy(recordings[kind], tmp_path_factory.mktemp(kind), mutate)
    check(["run", "--source", f"file:{log}", "--rerun", "off", "--quiet"], capsys)


# -- command-line options -----------------------------------------------------------------------

NUMBERS = st.one_of(
    st.sampled_from(["nan", "inf", "-inf", "1e308", "-1", "0", "1e-300", "", "x", "true", "2000"]),
    st.floats(-1e6, 1e6).map(repr),
)


@FUZZ
@given(
    template=st.sampled_from(
        [
            ["modes", "--rpm", "{v}"],
            ["excitation", "--rpm", "{v}"],
            ["run", "--seed", "{v}", "--json", ""],
            ["run", "--fs", "{v}", "--json", "{missing}"],
            ["simulate", "--fs", "{v}", "--duration", "0", "--out", "{out}"],
            ["replay", "{log}", "--speed", "{v}", "--json", "{missing}"],
        ]
    ),
    value=NUMBERS,
)
@example(template=["modes", "--rpm", "{v}"], value="nan")
@example(template=["excitation", "--rpm", "{v}"], value="1e308")
def test_cli_numbers(
    recordings: dict[str, Path],
    tmp_path_factory: pytest.TempPathFactory,
    capsys: pytest.CaptureFixture[str],
    template: list[str],
    value: str,
) -> None:
    d = tmp_path_factory.mktemp("cli")
    paths = {"v": value, "missing": str(d / "none" / "r.json"), "out": str(d / "x.csv")}
    paths["log"] = str(d / "none.mcap")
    argv = [a.format(**paths) for a in template]
    code = check(argv, capsys)
    if "{missing}" in template or '""' in template:
        assert code == 2  # the output path is refused before any work
    if value in ("nan", "inf", "-inf") and template[0] in ("modes", "excitation"):
        assert code == 2
