"""``ptinertia modes``: the six rigid-body modes of the powertrain on its mounts.

Without ``--rpm``: undamped modes at zero speed (real shapes). With ``--rpm``:
complex modes with the mounts' loss factors and the crank train's gyroscopic
coupling at that speed. Each mode is named after the degree of freedom that
holds most of its kinetic energy (roll = about the crank axis, as in the paper).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from ptinertia.commands.arg_types import rpm as rpm_type
from ptinertia.config import load_bench
from ptinertia.errors import UsageError
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.to_physics import build_model


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("--bench", default=str(DEFAULT_BENCH), help="bench file (default: %(default)s)")
    p.add_argument(
        "--rpm",
        type=rpm_type,
        default=None,
        help="crank speed for damped gyroscopic modes, rev/min",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def compute(bench_path: str, rpm: float | None) -> dict[str, Any]:
    if rpm is not None and rpm < 0:
        raise UsageError(f"--rpm: expected a speed >= 0, got {rpm:g}")
    bench = load_bench(bench_path)
    if not bench.mounts:
        raise UsageError(f"{bench_path}: no [[mounts]]: a free body has no rigid-body modes")
    model = build_model(bench)
    modes = model.modes(rpm)
    return {
        "bench": bench.meta.name,
        "rpm": rpm,
        "labels": list(modes.labels),
        "modes": [
            {
                "frequency_hz": float(modes.frequency_hz[j]),
                "damping_ratio": float(modes.damping_ratio[j]),
                "dominant": modes.dominant()[j],
                "energy_pct": {
                    lab: float(100 * modes.energy[i, j]) for i, lab in enumerate(modes.labels)
                },
                "shape": {
                    lab: {
                        "re": float(modes.shapes[i, j].real),
                        "im": float(modes.shapes[i, j].imag),
                    }
                    for i, lab in enumerate(modes.labels)
                },
            }
            for j in range(6)
        ],
    }


def format_table(data: dict[str, Any]) -> str:
    rpm = data["rpm"]
    what = (
        "undamped, zero speed"
        if rpm is None
        else f"with mount loss and gyroscopic coupling at {rpm:g} rpm"
    )
    labels = data["labels"]
    lines = [f"Rigid-body modes of {data['bench']} ({what})", "kinetic energy per DOF in %", ""]
    header = ["mode", "freq Hz", "damping %", "dominant", *labels]
    table = [header]
    for j, mode in enumerate(data["modes"], start=1):
        table.append(
            [
                str(j),
                f"{mode['frequency_hz']:.2f}",
                "-" if rpm is None else f"{100 * mode['damping_ratio']:.1f}",
                mode["dominant"],
                *(f"{mode['energy_pct'][lab]:.0f}" for lab in labels),
            ]
        )
    widths = [max(len(r[k]) for r in table) for k in range(len(header))]
    for r in table:
        lines.append(
            "  ".join(
                v.ljust(w) if k == 3 else v.rjust(w)
                for k, (v, w) in enumerate(zip(r, widths, strict=True))
            )
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    data = compute(args.bench, args.rpm)
    print(json.dumps(data, indent=1) if args.json else format_table(data))
    return 0
