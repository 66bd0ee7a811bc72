"""One flipped bit per recording: how many replays come back silently changed (goal 0).

Records a few short simulated sweeps (``ptinertia run --duration 6``), replays
each clean, then replays copies with one bit flipped at a random position
(uniform over the file) through the ``ptinertia replay`` command, in process,
and sorts every outcome:

identical
    exit 0, the result document equal to the clean replay's.
skipped, reported
    exit 0, a different result, and the document's ``recording_skipped`` says what was skipped.
refused
    exit 1 or 2 with one line on stderr.
SILENTLY CHANGED
    exit 0, a different result, nothing skipped reported (the failure this counts).
traceback / over budget
    an exception escaped the command, or a replay took longer than its budget.

Usage: ``python benchmarks/bench_bitflips.py [--flips 150] [--bases 3] [--seed 0]``.
Prints one line per category and the silent count; exit status 1 if any replay
changed silently, escaped with a traceback or ran over budget.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import random
import signal
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path
from typing import Any

from ptinertia.cli import main

BUDGET_S = 120  # a replay of a 6 s sweep takes ~1-3 s; past this it hangs


class OverBudget(Exception):
    pass


def _alarm(signum: int, frame: Any) -> None:
    raise OverBudget


def run_cli(argv: list[str]) -> tuple[int | None, str, str]:
    """Exit code (None: traceback or over budget), stdout, stderr of ``ptinertia argv``."""
    out, err = io.StringIO(), io.StringIO()
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(BUDGET_S)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code: int | None = main(argv)
    except OverBudget:
        code, err = None, io.StringIO("over budget\n")
    except SystemExit as exc:  # argparse
        code = int(exc.code or 0)
    except Exception:
        code = None
        err.write(traceback.format_exc())
    finally:
        signal.alarm(0)
    return code, out.getvalue(), err.getvalue()


def replay(path: Path, json_path: Path) -> tuple[int | None, dict[str, Any] | None, str]:
    json_path.unlink(missing_ok=True)
    code, _, err = run_cli(["replay", str(path), "--quiet", "--json", str(json_path)])
    doc = json.loads(json_path.read_text()) if code == 0 and json_path.exists() else None
    return code, doc, err


def classify(code: int | None, doc: dict[str, Any] | None, err: str, clean: dict[str, Any]) -> str:
    if code is None:
        return "over budget" if err.startswith("over budget") else "traceback"
    if code != 0:
        lines = [line for line in err.splitlines() if line.strip()]
        return "refused" if lines and "Traceback" not in err else "refused without a line"
    if doc is None:
        return "traceback"
    if doc == clean:
        return "identical"
    if doc.get("recording_skipped"):
        return "skipped, reported"
    return "SILENTLY CHANGED"


def main_bench() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flips", type=int, default=150)
    parser.add_argument("--bases", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="bitflips-") as tmp_dir:
        tmp = Path(tmp_dir)
        bases: list[tuple[bytes, dict[str, Any]]] = []
        for k in range(args.bases):
            rec = tmp / f"base{k}.mcap"
            argv = ["run", "--duration", "6", "--seed", str(k + 1), "--rerun", "off", "--quiet"]
            code, _, err = run_cli([*argv, "--record", str(rec)])
            if code != 0:
                raise SystemExit(f"recording {k} failed: {err.strip()}")
            code, clean, err = replay(rec, tmp / "clean.json")
            if code != 0 or clean is None:
                raise SystemExit(f"clean replay {k} failed: {err.strip()}")
            bases.append((rec.read_bytes(), clean))
        outcomes: Counter[str] = Counter()
        examples: dict[str, str] = {}
        slowest = 0.0
        for i in range(args.flips):
            data, clean = bases[i % len(bases)]
            bit = rng.randrange(8 * len(data))
            flipped = bytearray(data)
            flipped[bit // 8] ^= 1 << (bit % 8)
            path = tmp / "flipped.mcap"
            path.write_bytes(flipped)
            t0 = time.perf_counter()
            code, doc, err = replay(path, tmp / "flipped.json")
            slowest = max(slowest, time.perf_counter() - t0)
            outcome = classify(code, doc, err, clean)
            outcomes[outcome] += 1
            last = (err.strip().splitlines() or [""])[-1]
            examples.setdefault(outcome, f"byte {bit // 8} of {len(data)}: {last[:160]}")
    print(f"{args.flips} recordings ({args.bases} sweeps of 6 s), one flipped bit each:")
    for name in (
        "identical",
        "skipped, reported",
        "refused",
        "refused without a line",
        "SILENTLY CHANGED",
        "traceback",
        "over budget",
    ):
        print(f"  {name:24} {outcomes[name]:4d}   {examples.get(name, '')}")
    print(f"slowest replay {slowest:.1f} s (budget {BUDGET_S} s)")
    bad = outcomes["SILENTLY CHANGED"] + outcomes["traceback"] + outcomes["over budget"]
    print(f"silently changed: {outcomes['SILENTLY CHANGED']} (goal 0)")
    return 1 if bad or outcomes["refused without a line"] else 0


if __name__ == "__main__":
    raise SystemExit(main_bench())
