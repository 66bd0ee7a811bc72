"""``ptinertia export``: the estimate as a bench-file fragment, plain tables or a Nastran CONM2.

Formats: ``toml`` (a ``[powertrain]`` table for a bench file), ``json`` and ``csv``
(value, std, 95 % interval per quantity, SI), ``nastran`` (a large-field CONM2
card; Nastran's I21 = integral(x1 x2 dm) = ptinertia's Ixy, see docs/report-and-export.md).
An inline 3 has no free force, so its mass is not estimated: give ``--mass`` or
``--bench`` (the weighed mass) for ``toml`` and ``nastran``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ptinertia.commands.arg_types import finite_float
from ptinertia.config import load_bench, loads_bench
from ptinertia.errors import UsageError
from ptinertia.export import FORMATS, UNITS, export, properties_from_result
from ptinertia.outputs import WARN, atomic_write, check_output, input_files
from replay.reader import open_log


def add_parser(sub: Any, name: str, help_text: str) -> None:
    p = sub.add_parser(name, help=help_text, description=__doc__)
    p.add_argument("result", help="result document (ptinertia run --json), or a run's LOG.mcap")
    p.add_argument("--format", required=True, choices=FORMATS, help="output format")
    p.add_argument("--out", help="output file (default: standard output)")
    p.add_argument("--force", action="store_true", help="overwrite without the warning line")
    p.add_argument(
        "--mass", type=finite_float, metavar="KG", help="mass to use when it was not estimated"
    )
    p.add_argument(
        "--bench", help="bench TOML whose (weighed) mass to use when it was not estimated"
    )
    nas = p.add_argument_group("nastran")
    nas.add_argument("--eid", type=int, default=1, help="CONM2 element id (default 1)")
    nas.add_argument("--grid", type=int, default=1, help="grid id the mass hangs on (default 1)")
    nas.add_argument(
        "--grid-at",
        metavar="X,Y,Z",
        help="grid location in m, bench frame: write CID 0 and the offset (default: CID -1, cog coordinates)",
    )
    nas.add_argument(
        "--units", default="si", choices=tuple(UNITS), help="si (kg, m) or mm-t-s (t, mm)"
    )


def _result(path: Path) -> tuple[dict[str, Any], float | None]:
    """The result document and the recording's bench mass (None for a JSON file)."""
    if path.suffix.lower() == ".json":
        try:
            return json.loads(path.read_text(encoding="utf-8")), None
        except (OSError, json.JSONDecodeError) as err:
            raise UsageError(f"{path}: not a readable result document ({err})") from None
    log = open_log(path)
    doc = log.result
    if doc is None:
        final = log.final_estimate()
        if final is None:
            raise UsageError(
                f"{path}: the recording holds no final estimate (use ptinertia replay first)"
            )
        doc = final.to_json()
    doc = {**doc, "source": doc.get("source", log.source)}
    mass = (
        loads_bench(log.bench_text, f"{path}:bench.toml").powertrain.mass_kg
        if log.bench_text
        else None
    )
    return doc, mass


def _grid_at(text: str | None) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise UsageError(f"--grid-at: expected X,Y,Z in m, got {text!r}") from None
    return x, y, z


def run(args: argparse.Namespace) -> int:
    if args.out is not None:
        check_output(args.out, "--out", input_files(args.result, args.bench), args.force, WARN)
    doc, log_mass = _result(Path(args.result))
    bench_mass = load_bench(args.bench).powertrain.mass_kg if args.bench else log_mass
    props = properties_from_result(doc, mass=args.mass, bench_mass=bench_mass)
    kwargs: dict[str, Any] = {}
    if args.format == "nastran":
        kwargs = {
            "eid": args.eid,
            "grid": args.grid,
            "grid_at": _grid_at(args.grid_at),
            "units": args.units,
        }
    text = export(props, args.format, **kwargs)
    if args.out is not None:
        atomic_write(args.out, text)
        print(f"{args.format} written to {args.out}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0
