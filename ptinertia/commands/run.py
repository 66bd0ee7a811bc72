"""``ptinertia run``: acquire, track orders, estimate, record, show.

With no option at all it runs the simulated example bench (the i3 sweep
1500 -> 4500 rpm in 60 s) end to end and prints the estimate against the truth.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from acquisition.can.logs import is_can_log
from ptinertia.commands.arg_types import finite_float
from ptinertia.commands.arg_types import seed as seed_type
from ptinertia.config import DBC_KEY, bench_file_paths, load_bench
from ptinertia.errors import UsageError
from ptinertia.no_estimate import no_estimate_reason
from ptinertia.outputs import REFUSE, WARN, check_output, input_files
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.recorded_bench import file_attachments, with_mount_scale
from ptinertia.runner import RunOptions, print_table, run_source, write_json
from ptinertia.sinks import Sink
from ptinertia.sources import REALISTIC_SIMULATION, open_source
from ptinertia.to_can import parse_bus_options
from ptinertia.viewer.foxglove_scene import FoxgloveScene
from replay.recorder import ZSTD_LEVEL, McapRecorder

CORRECTIONS = (
    "suspension",
    "gyroscopic",
    "unbalance",
    "crank_offset",
    "self_calibration",
    "channel_weights",
)


def add_parser(sub: Any, name: str, help_text: str) -> None:
    p = sub.add_parser(name, help=help_text, description=__doc__)
    p.add_argument(
        "--bench",
        default=None,
        help="bench TOML: required with a file or CAN source (the bench the data was "
        "measured on); the simulated source defaults to the i3 example",
    )
    p.add_argument(
        "--source",
        default="sim",
        help="sim (simulated bench, default), file:PATH (.csv, .mf4, CAN logs), can:INTERFACE:CHANNEL",
    )
    p.add_argument("--json", metavar="PATH", help="write the result document here")
    p.add_argument("--record", metavar="PATH", help="record everything to this MCAP file")
    add_force_flag(p)
    p.add_argument(
        "--record-level",
        metavar="N",
        type=int,
        default=ZSTD_LEVEL,
        help=f"zstd level of the recording (default {ZSTD_LEVEL}: fast; 3 makes the file about "
        "7 %% smaller for 4x the CPU, see docs/recording-format.md)",
    )
    p.add_argument(
        "--rerun",
        metavar="MODE",
        default=None,
        help="spawn | connect[=ADDR] | save=PATH | serve[=ADDR] | off "
        "(default: spawn where there is a display, else save an .rrd next to the recording)",
    )
    p.add_argument(
        "--orders", help="orders to track, e.g. 1,1.5,2 (default: the bench's [dsp] orders)"
    )
    p.add_argument(
        "--no",
        action="append",
        default=[],
        choices=CORRECTIONS,
        metavar="CORRECTION",
        help=f"switch a correction off (repeatable): {', '.join(CORRECTIONS)}",
    )
    add_mount_scale_flag(p)
    p.add_argument("--quiet", action="store_true", help="no progress line")
    sim = p.add_argument_group("simulated source (--source sim)")
    sim.add_argument("--sweep", metavar="FROM:TO", help="rpm sweep, e.g. 1500:4500")
    sim.add_argument("--duration", type=finite_float, metavar="S", help="sweep duration in s")
    sim.add_argument("--fs", type=finite_float, metavar="HZ", help="accelerometer sample rate")
    sim.add_argument("--noise-db", type=finite_float, metavar="DB", help="white noise SNR in dB")
    sim.add_argument("--seed", type=seed_type, help="random seed of the simulated imperfections")
    sim.add_argument(
        "--realistic", action="store_true", help="1 %% gains, 1 deg, 2 mm, 40 dB, unbalance"
    )
    sim.add_argument("--paced", action="store_true", help="pace the simulator to the wall clock")
    can = p.add_argument_group("CAN source (--source can:INTERFACE:CHANNEL, CAN log files)")
    can.add_argument(
        "--dbc", help="DBC mapping frames to channels (default: the bench's [can] dbc)"
    )
    can.add_argument("--bitrate", type=int, help="nominal bit rate, bit/s")
    can.add_argument("--data-bitrate", type=int, help="CAN FD data bit rate, bit/s")
    can.add_argument("--fd", action=argparse.BooleanOptionalAction, default=None, help="CAN FD bus")
    can.add_argument(
        "--bus-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="interface-specific can.Bus argument (repeatable; beside [can] bus_options)",
    )
    can.add_argument(
        "--start-timeout",
        type=float,
        metavar="S",
        help="end, saying what to check, when no frame came within S s (default: [can] "
        "start_timeout_s)",
    )


def parse_orders(text: str | None) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise UsageError(f"--orders: expected numbers like 1,1.5,2, got {text!r}") from None


def sim_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The ``[simulation]`` overrides given on the command line."""
    out: dict[str, Any] = {}
    if args.realistic:
        out.update(REALISTIC_SIMULATION)
    if args.sweep:
        try:
            lo, hi = (float(v) for v in args.sweep.split(":"))
        except ValueError:
            raise UsageError(
                f"--sweep: expected FROM:TO in rpm, e.g. 1500:4500, got {args.sweep!r}"
            ) from None
        out.update(rpm_start=lo, rpm_end=hi)
    if args.duration is not None:
        out["duration_s"] = args.duration
    if args.noise_db is not None:
        out["noise_snr_db"] = args.noise_db
    if args.seed is not None:
        out["seed"] = args.seed
    if args.fs is not None:
        out["accel_rate_hz"] = args.fs
    # Live (paced) runs deliver 0.1 s blocks, as a DAQ would; as fast as possible,
    # larger blocks cost less per sample in the dsp stage (results agree to 1e-9).
    out["paced"] = bool(args.paced)
    out["block_s"] = 0.1 if args.paced else 0.5
    return out


def can_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """CAN options given on the command line (for can: sources and CAN log files)."""
    out: dict[str, Any] = {}
    if args.dbc:
        out["dbc"] = args.dbc
    if args.bitrate is not None:
        out["bitrate"] = args.bitrate
    if args.data_bitrate is not None:
        out["data_bitrate"] = args.data_bitrate
    if args.fd is not None:
        out["fd"] = args.fd
    if args.bus_option:
        out["bus_kwargs"] = parse_bus_options(args.bus_option)
    if args.start_timeout is not None:
        if not args.start_timeout > 0:
            raise UsageError(f"--start-timeout: expected seconds > 0, got {args.start_timeout:g}")
        out["start_timeout_s"] = args.start_timeout
    return out


def viewer_sinks(mode: str | None, record: str | None) -> list[Sink]:
    """The Rerun sink for ``--rerun`` (imported only when a view is asked for)."""
    if mode == "off":
        return []
    try:
        # here, not at the top: the sink imports rerun (heavy, and absent from some installs),
        # which a headless run never needs
        from ptinertia.viewer import rerun_sink as viewer
    except ImportError:
        if mode is None:
            return []
        raise UsageError("--rerun: the viewer is not available in this installation") from None
    parsed = viewer.parse_rerun_option(mode, record)
    return [] if parsed is None else [viewer.RerunSink(parsed)]


def recorder_sinks(path: str | None, level: int = ZSTD_LEVEL) -> list[Sink]:
    """The recorder, then the Foxglove 3D scene it also writes (the recorder stays first:
    its ``on_can_frames`` is the CAN source's listener); ``level`` is the zstd level."""
    if path is None:
        return []
    recorder = McapRecorder(path, level=level)
    return [recorder, FoxgloveScene(recorder)]


def add_force_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--force",
        action="store_true",
        help="overwrite an existing recording (result documents are replaced with a warning)",
    )


def check_outputs(args: argparse.Namespace, inputs: list[Path]) -> None:
    """``--json`` and ``--record`` checked before any work (ptinertia.outputs)."""
    if args.json is not None:
        check_output(args.json, "--json", inputs, args.force, WARN)
    if args.record is not None:
        check_output(args.record, "--record", inputs, args.force, REFUSE)
        if args.json is not None and Path(args.json).resolve() == Path(args.record).resolve():
            raise UsageError(f"--json and --record name the same file {args.json}")


def run(args: argparse.Namespace) -> int:
    if args.bench is None and args.source != "sim":
        # a recording read with the example bench's sensor positions, mounts and tacho
        # would give a confident, wrong estimate: the bench must be named
        raise UsageError(
            f"--source {args.source}: needs --bench B.toml, the bench the data was "
            "measured on (its sensors, tacho, mounts and [channels]); only the "
            "simulated source defaults to the i3 example"
        )
    bench_path = Path(args.bench) if args.bench is not None else DEFAULT_BENCH
    file_source = args.source.partition(":")[2] if args.source.startswith("file:") else None
    check_outputs(args, input_files(bench_path, file_source, args.dbc))
    bench = with_mount_scale(load_bench(bench_path), args.mount_scale)
    bench_text = bench_path.read_text(encoding="utf-8")
    overrides = sim_overrides(args) if args.source == "sim" else {}
    if args.source != "sim" and any(
        getattr(args, k) not in (None, False)
        for k in ("sweep", "duration", "noise_db", "seed", "fs")
    ):
        raise UsageError("--sweep/--duration/--noise-db/--seed/--fs apply to --source sim only")
    if args.source == "sim":
        overrides["bench_text"] = bench_text
    is_can = args.source.startswith("can:")
    kind, _, arg = args.source.partition(":")
    is_can_file = kind == "file" and is_can_log(arg)
    can = can_overrides(args)
    if can and args.source == "sim":
        raise UsageError(
            "--dbc/--bitrate/--data-bitrate/--fd/--bus-option/--start-timeout apply to CAN "
            "sources only"
        )
    overrides.update(can)
    recorders = recorder_sinks(args.record, args.record_level)
    files = bench_file_paths(bench)
    if args.dbc:
        files[DBC_KEY] = args.dbc
    if not (is_can or is_can_file):
        files.pop(DBC_KEY, None)  # a DBC is recorded with the CAN frames it decodes
    if (is_can or is_can_file) and recorders:
        # the raw frames and the DBC go into the log, so it can be decoded again (replay --dbc)
        overrides["frame_listener"] = recorders[0].on_can_frames  # type: ignore[attr-defined]
    attachments = file_attachments(list(files.values())) if recorders else {}
    source = open_source(args.source, bench, **overrides)
    sinks = recorders + viewer_sinks(args.rerun, args.record)
    options = RunOptions(
        orders=parse_orders(args.orders),
        corrections_off=tuple(args.no),
        quiet=args.quiet,
        live=is_can or bool(overrides.get("paced")),
        sinks=tuple(sinks),
        attachments=attachments,
    )
    summary, doc = run_source(bench, bench_text, source, args.source, options)
    if doc is None or summary.estimate is None:
        # a live bus that stayed silent says what to check rather than why frames were rejected
        reason = getattr(source, "no_data_reason", None) or no_estimate_reason(
            summary.rejected, summary.orders_rejected
        )
        print(f"ptinertia run: no estimate: {reason}", file=sys.stderr)
        return 1
    physical = print_table(summary.estimate, doc)
    if args.json is not None:
        write_json(doc, args.json)
        print(f"result written to {args.json}")
    if not physical:  # the reason is printed; the JSON says "consistent": false
        return 1
    if args.record:
        print(f"recording written to {args.record}")
    return 130 if summary.interrupted else 0


def add_mount_scale_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--mount-scale",
        action="store_true",
        help="estimate one stiffness scale per mount (as [estimator] mount_scale = true): "
        "for mount data you do not trust",
    )
