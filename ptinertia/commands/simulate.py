"""``ptinertia simulate``: synthesise a bench run and write it as CSV, MF4 or MCAP.

The simulated bench (``ptinertia.sources.open_source("sim", ...)``) streams
straight into the writer chosen by the output extension: ``.csv`` (one file per
sample group plus one per edge channel and a ``.meta.json`` with the truth),
``.mf4`` (one file) or ``.mcap`` (a raw-only recording with the bench file in
it, which ``replay`` and ``report`` run the chain on). The files read back
through ``file:PATH`` sources.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from acquisition.sim.sweep import parse_sweep
from acquisition.stream import EdgeBlock, SampleBlock
from ptinertia.commands.arg_types import finite_float
from ptinertia.commands.arg_types import seed as seed_type
from ptinertia.config import load_bench
from ptinertia.outputs import (
    REFUSE,
    atomic_directory_outputs,
    check_output,
    input_files,
    move_into,
)
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.registry import writer_class
from ptinertia.sources import open_source


def add_parser(subparsers: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        name, help=help_text, description=__doc__.splitlines()[0] if __doc__ else None
    )
    p.add_argument("--bench", default=str(DEFAULT_BENCH), help="bench file (default: %(default)s)")
    p.add_argument(
        "--sweep", help="RPM_START:RPM_END, or one RPM for a constant speed (default: the bench's)"
    )
    p.add_argument("--duration", type=finite_float, help="sweep duration, s (default: the bench's)")
    p.add_argument("--hold", type=finite_float, help="hold at the start speed before the sweep, s")
    p.add_argument(
        "--fs", type=finite_float, help="accelerometer sample rate, Hz (default: the bench's)"
    )
    p.add_argument(
        "--noise-db",
        type=finite_float,
        help="SNR per channel, dB: 20 log10(rms signal / noise std)",
    )
    p.add_argument("--seed", type=seed_type, help="random seed of the as-built bench and the noise")
    p.add_argument(
        "--tacho", choices=("edges", "sampled"), help="tacho delivery (default: the bench's)"
    )
    p.add_argument("--out", required=True, help="output file, .csv, .mf4 or .mcap")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    return p


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The ``open_source("sim", ...)`` overrides the options ask for."""

    out: dict[str, Any] = {}
    if args.sweep is not None:
        out["rpm_start"], out["rpm_end"] = parse_sweep(args.sweep)
    for opt, key in (
        ("duration", "duration_s"),
        ("hold", "hold_s"),
        ("fs", "accel_rate_hz"),
        ("noise_db", "noise_snr_db"),
        ("seed", "seed"),
    ):
        value = getattr(args, opt)
        if value is not None:
            out[key] = value
    if args.tacho is not None:
        out["tacho"] = {"delivery": args.tacho}
    return out


def simulated_files(out: Path) -> list[Path]:
    """The files ``simulate`` writes whose names are known before the run (a CSV's group
    files are named after the groups, found only once the source is open)."""
    if out.suffix.lower() == ".csv":
        return [out, out.with_name(out.name[: -len(out.suffix)] + ".meta.json")]
    return [out]


def simulate(
    bench_path: str | Path,
    out: str | Path,
    progress: bool = False,
    force: bool = False,
    **overrides: Any,
) -> dict[str, Any]:
    """Simulate ``bench_path`` into ``out``; returns a summary (files, samples, edges).

    An existing output is refused unless ``force`` (ptinertia.outputs, policy REFUSE)."""

    out = Path(out)
    writer_cls = writer_class(out.suffix)  # an unsupported extension fails before the work
    bench_path = Path(bench_path)
    for path in simulated_files(out):
        check_output(path, "--out", input_files(bench_path), force, REFUSE)
    bench = load_bench(bench_path)
    text = bench_path.read_text(encoding="utf-8")
    samples: dict[str, int] = {}
    edges: dict[str, int] = {}
    with open_source("sim", bench, bench_text=text, **overrides) as source:
        layout = source.layout
        duration = source.profile.duration_s  # type: ignore[attr-defined]
        bar = _progress(duration, progress)
        # written in a private directory beside the target, moved out once complete:
        # an interrupted or failed run leaves no half file and no old file damaged
        with atomic_directory_outputs(out.parent) as tmp_dir:
            with writer_cls(tmp_dir / out.name) as writer:
                writer.start(layout)
                for item in source:
                    writer.write(item)
                    if isinstance(item, SampleBlock):
                        samples[item.group] = samples.get(item.group, 0) + item.n_samples
                        if item.group == layout.groups[0].name and bar is not None:
                            bar.update(item.n_samples / layout.groups[0].rate_hz)
                    elif isinstance(item, EdgeBlock):
                        edges[item.channel] = edges.get(item.channel, 0) + item.times_s.size
            files = move_into(writer.paths, out.parent)
        if bar is not None:
            bar.close()
    return {
        "files": [str(p) for p in files],
        "duration_s": duration,
        "samples": samples,
        "edges": edges,
        "groups": {g.name: g.rate_hz for g in layout.groups},
    }


def _progress(total_s: float, wanted: bool) -> Any:
    if not wanted:
        return None
    from tqdm import tqdm

    # delay: the bar shows only for runs longer than ~2 s; not a TTY (CI, pipes): no bar
    return tqdm(
        total=round(total_s, 3),
        unit="s",
        delay=2.0,
        file=sys.stderr,
        disable=not sys.stderr.isatty(),
        desc="simulate",
        bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} s",
    )


def run(args: argparse.Namespace) -> int:
    summary = simulate(
        args.bench, args.out, progress=True, force=args.force, **overrides_from_args(args)
    )
    rates = ", ".join(
        f"{g} {r:g} Hz ({summary['samples'].get(g, 0)} samples)"
        for g, r in summary["groups"].items()
    )
    edges = ", ".join(f"{c} {n} edges" for c, n in summary["edges"].items())
    print(f"simulated {summary['duration_s']:g} s: {rates}" + (f"; {edges}" if edges else ""))
    for f in summary["files"]:
        print(f"wrote {f}")
    return 0
