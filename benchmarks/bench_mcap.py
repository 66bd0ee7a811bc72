"""MCAP recording: write and read speed, bytes per hour, raw payload against float32 size.

Stream: 10 accelerometer channels at 25.6 kHz in 0.1 s blocks (three engine
orders plus white noise at 40 dB SNR, so the mantissas are as incompressible
as real data), a 60-tooth tacho as edge timestamps, and what a live run adds:
one order frame and one gating record per revolution (3 orders x 10 channels)
and the full estimate (12 parameters, covariances) every 0.25 s, at 3000 rpm.
The items are built before the clock starts; BLAS threads pinned to one.

    /work/venv/bin/python benchmarks/bench_mcap.py [--seconds 60] [--repeat 3] [--compression zstd|lz4|none] [--levels]

``--levels``: the recorder's zstd level, the trade-off of issue 24 item 4: the full run's
chunks recompressed at levels -5, -1, 1, 3, 6: file / payload, and CPU per minute of data
to compress (the writer thread of a live run) and to decompress (every replay). Measured
(best of 3, load 10 on 2 cores): -1 (the default) 0.951, 0.026 s, 0.007 s; 3 0.882,
0.087 s, 0.048 s: level 3 saves 7 % of the file for 3.3x the compression and 7x the
decompression CPU.

Prints: write and read speed as multiples of real time (CPU time, best of
``--repeat``), file bytes per hour (compressed) and raw payload bytes per
hour, the ratio of the raw payload to the float32 size of the samples, and
the share of each topic. Writing takes two threads (the recorder compresses
and writes chunks on its own): the figure that matters to a live run is the
CPU time of the calling thread, the one that runs the pipeline; the CPU
time of both threads and the wall time are printed beside it. Reading is
single-threaded (process CPU time; the data CRC of McapSource runs on a thread of its own).

Measured (issue 24, 60 s, best of 3, two runs each side by side, load 4.7-6.6): write, full
run, calling thread 0.108-0.118 s on main (0142dad) -> 0.070-0.077 s (both threads 0.172-0.186
-> 0.127-0.147 s): sample blocks cast and records packed on the writer thread, the gating from
a layout (and CRCs through ISA-L, since taken out again); read raw items 0.040 -> 0.027-0.031 s, McapSource 0.039-0.041 ->
0.028-0.032 s: sample blocks read without the protobuf class, the data CRC beside the set-up.
Then (issue 24, the replay's source thread; best of 5, side by side with d450fdd, load 2.2):
read raw items 0.029 -> 0.022 s, McapSource 0.031 -> 0.022 s; by thread, open 1.4 -> 0.7 ms
(the summary read from its checked bytes, replay/summary.py), reading thread 23.5 -> 16.8 ms
(a chunk's message heads in one struct call, one zstd decompressor per walk, a sample
block's head matched against its group's bytes); what is left is file reads, zstd and the
float32 -> float64 widening, which release the GIL. ``as_recorded`` (6 ms) is printed
apart: the pipeline's reader skips it for a recording (``McapSource.samples_as_recorded``).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import zstandard  # noqa: E402

from acquisition.stream import (  # noqa: E402
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    StreamLayout,
)
from replay.mcap_records import chunk_payload, ends_data, records  # noqa: E402
from replay.reader import open_log  # noqa: E402
from replay.recorder import ZSTD_LEVEL, McapRecorder  # noqa: E402
from replay.recording_head import RecordingInfo  # noqa: E402
from replay.schemas import PARAMETERS  # noqa: E402
from replay.source import McapSource  # noqa: E402

FS = 25_600.0
N_CH = 10
BLOCK = 2560
RPM = 3000.0
TEETH = 60


def make_stream(seconds: float) -> tuple[StreamLayout, list[Any]]:
    """Raw items plus ``("frame", frame, outcome)`` and ``("estimate", update)`` markers, in time order."""
    from dsp.frames import OrderFrame
    from estimator.outcome import FrameOutcome
    from estimator.result import Estimate, EstimateUpdate

    rng = np.random.default_rng(1)
    acc = SampleGroup(
        "accel", FS, tuple(ChannelSpec(f"s{i // 3}_{'xyz'[i % 3]}", "m/s^2") for i in range(N_CH))
    )
    layout = StreamLayout((acc,), ("tacho",))
    rev_s = 60.0 / RPM
    amp = rng.standard_normal((3, N_CH)) + 1j * rng.standard_normal((3, N_CH))
    names = tuple(p for p in PARAMETERS if p != "inv_mass")  # an i3: the mass is weighed
    n = len(names)
    items: list[Any] = []
    next_frame, next_estimate = rev_s, 0.25
    for k in range(int(seconds * FS) // BLOCK):
        t = (k * BLOCK + np.arange(BLOCK)) / FS
        phi = 2 * np.pi * RPM / 60 * t
        x = sum(
            (amp[i][:, None] * np.exp(1j * h * phi)).real for i, h in enumerate((1.0, 1.5, 3.0))
        )
        x = x + 0.01 * np.std(x) * rng.standard_normal(x.shape)
        items.append(SampleBlock("accel", k * BLOCK, x.astype(np.float32).astype(np.float64)))
        t_end = (k + 1) * BLOCK / FS
        edges = (
            np.arange(math.ceil(t[0] * TEETH / rev_s), math.ceil(t_end * TEETH / rev_s))
            * rev_s
            / TEETH
        )
        items.append(EdgeBlock("tacho", edges))
        while next_frame < t_end - rev_s:  # a frame needs the whole cycle around it
            a = amp * (1 + 1e-3 * rng.standard_normal(amp.shape))
            frame = OrderFrame(
                next_frame,
                RPM,
                2 * np.pi * next_frame / rev_s,
                (1.0, 1.5, 3.0),
                tuple(c.name for c in acc.channels),
                a,
                np.ones(N_CH, bool),
                1e-4,
                np.full(N_CH, 1e-5),
                frozenset(),
            )
            outcome = FrameOutcome(
                next_frame, RPM, (1.0, 1.5, 3.0), {}, None, {1.0: 1e-3, 1.5: 2e-3, 3.0: 1e-3}
            )
            items.append(("frame", frame, outcome))
            if next_frame >= next_estimate:
                c = rng.standard_normal((n, n))
                cov = c @ c.T * 1e-6
                est = Estimate(
                    names,
                    rng.standard_normal(n),
                    cov + cov,
                    cov,
                    cov,
                    np.ones(n, bool),
                    False,
                    150.0,
                    np.zeros(3),
                    int(next_frame / rev_s),
                    int(next_frame / rev_s),
                    {"rpm_unsteady": 3},
                    {},
                    (1500.0, RPM),
                    None,
                    1.0,
                )
                items.append(("estimate", EstimateUpdate(next_frame, RPM, est)))
                next_estimate += 0.25
            next_frame += rev_s
    return layout, items


def write(
    path: Path, layout: StreamLayout, items: list[Any], compression: str = "zstd"
) -> McapRecorder:
    rec = McapRecorder(path, compression=compression)
    rec.start(RecordingInfo(layout=layout, bench_text="[bench]\n", source="bench_mcap"))
    block: list[Any] = []  # the frames between two items, handed over as the pipeline does
    for item in items:
        if isinstance(item, tuple) and item[0] == "frame":
            block.append(item)
            continue
        if block:
            _frames(rec, block)
            block = []
        if isinstance(item, tuple):
            rec.on_estimate(item[1])
        else:
            rec.on_item(item)
    if block:
        _frames(rec, block)
    rec.close(None)
    return rec


def _frames(rec: McapRecorder, block: list[Any]) -> None:
    rec.prepare_frames([b[1] for b in block])
    for _, frame, outcome in block:
        rec.on_frame(frame, outcome)


def best_of(repeat: int, fn: Any) -> tuple[float, Any]:
    """Best CPU time of this process over ``repeat`` calls (the machine may be shared:
    wall time then measures the neighbours)."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t0)
    return best, out


def best_write(repeat: int, fn: Any) -> tuple[tuple[float, float, float], Any]:
    """Best (calling thread CPU, process CPU, wall) times over ``repeat`` calls, s."""
    runs, out = [], None
    for _ in range(repeat):
        t0, c0, w0 = time.thread_time(), time.process_time(), time.perf_counter()
        out = fn()
        runs.append((time.thread_time() - t0, time.process_time() - c0, time.perf_counter() - w0))
    main, cpu, wall = (min(col) for col in zip(*runs, strict=True))
    return (main, cpu, wall), out


LEVELS = (-5, -1, 1, 3, 6)  # zstd levels compared (issue 24 item 4)


def source_split(path: Path, repeat: int) -> tuple[float, float, float, float]:
    """A replay's source, split by thread (CPU s, each best of ``repeat``): McapSource's
    open on the opening thread, the data CRC's thread (process minus opening thread until
    the check is done), the reading thread's iteration, and ``as_recorded`` over the items
    (which the pipeline's reader skips for a recording: /tmp/prof/stage_prof.py's ``src``
    counts it)."""
    from ptinertia.stage_threads import as_recorded

    runs = []
    for _ in range(repeat):
        p0, t0 = time.process_time(), time.thread_time()
        source = McapSource(path)
        t1 = time.thread_time()
        source.log.verify()
        p1, t2 = time.process_time(), time.thread_time()
        for _item in source:  # items dropped as a replay's consumer drops them
            pass
        t3 = time.thread_time()
        rounding = 0.0
        for item in McapSource(path):
            t4 = time.thread_time()
            as_recorded(item)
            rounding += time.thread_time() - t4
        runs.append((t1 - t0, (p1 - p0) - (t2 - t0), t3 - t2, rounding))
    opened, crc, reading, rounding = (min(r[k] for r in runs) for k in range(4))
    return opened, crc, reading, rounding


def chunk_payloads(path: Path) -> list[bytes]:
    """The uncompressed records of every chunk of a recording."""
    with open(path, "rb") as fh:
        out = []
        for opcode, offset, length in records(fh):
            if ends_data(opcode, length):
                break
            if opcode == 0x06:  # a chunk
                fh.seek(offset)
                out.append(chunk_payload(fh.read(length)))
        return out


def level_table(path: Path, seconds: float, repeat: int) -> None:
    """The recorder's zstd level: file / payload, and CPU per minute of data to compress
    (the MCAP writer thread of a live run) and to decompress (every replay), best of
    ``repeat``, on the chunks of ``path`` recompressed at each of :data:`LEVELS`."""
    payloads = chunk_payloads(path)
    total = sum(len(p) for p in payloads)
    print(f"zstd level (chunks of the full run recompressed; CPU s per minute, best of {repeat}):")
    for level in LEVELS:
        compress = zstandard.ZstdCompressor(level=level).compress
        t_c, packed = best_of(repeat, lambda c=compress: [c(p) for p in payloads])
        decompress = zstandard.ZstdDecompressor().decompress
        t_d, _ = best_of(repeat, lambda d=decompress, k=packed: [d(x) for x in k])
        minute = 60.0 / seconds
        default = " (the recorder's default)" if level == ZSTD_LEVEL else ""
        print(
            f"  level {level:3d}: file / payload {sum(len(x) for x in packed) / total:.3f}, "
            f"compress {t_c * minute:.3f} s, decompress {t_d * minute:.3f} s{default}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="stream length, s")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd")
    parser.add_argument("--levels", action="store_true", help="compare zstd levels too")
    args = parser.parse_args()
    seconds = args.seconds
    layout, items = make_stream(seconds)
    raw_items = [i for i in items if not isinstance(i, tuple)]
    samples = sum(i.data.size for i in raw_items if isinstance(i, SampleBlock))
    with tempfile.TemporaryDirectory() as tmp:
        full = Path(tmp) / "run.mcap"
        raw = Path(tmp) / "raw.mcap"
        t_write, rec = best_write(args.repeat, lambda: write(full, layout, items, args.compression))
        t_raw, _ = best_write(args.repeat, lambda: write(raw, layout, raw_items, args.compression))

        def read_items() -> int:
            return sum(1 for _ in open_log(full).items())

        def read_source() -> int:
            return sum(1 for _ in McapSource(full))

        def read_all() -> int:
            log = open_log(full)
            return sum(1 for _ in log.frames()) + sum(1 for _ in log.estimates())

        cut = Path(tmp) / "cut.mcap"
        data = full.read_bytes()
        cut.write_bytes(data[: len(data) - 1000])  # no footer: the unfinished-file path
        del data

        def read_unfinished() -> int:
            return sum(1 for _ in open_log(cut).items())

        def read_reference() -> int:
            log = open_log(full)
            return sum(1 for _ in log.messages(log.raw_topics, reference=True))

        t_items, n_items = best_of(args.repeat, read_items)
        t_source, _ = best_of(args.repeat, read_source)
        t_all, _ = best_of(args.repeat, read_all)
        t_cut, n_cut = best_of(args.repeat, read_unfinished)
        t_ref, _ = best_of(args.repeat, read_reference)
        split = source_split(full, args.repeat)
        size, size_raw = full.stat().st_size, raw.stat().st_size
        if args.levels:
            level_table(full, seconds, args.repeat)

    hour = 3600.0 / seconds
    raw_payload = rec.stats.payload_bytes["/raw/accel"]
    print(
        f"compression {args.compression}; stream: {seconds:g} s, {N_CH} channels at {FS:g} Hz, tacho {TEETH} teeth, {RPM:g} rpm; "
        f"{n_items} raw items, {samples / 1e6:.1f} M samples"
    )
    for what, (t_main, t_cpu, t_wall) in (("full run", t_write), ("raw only", t_raw)):
        print(
            f"write, {what:<9} {t_main:7.3f} s  -> {seconds / t_main:6.0f}x real time "
            f"(calling thread CPU; both threads {t_cpu:.3f} s CPU = {seconds / t_cpu:.0f}x, "
            f"wall {t_wall:.3f} s = {seconds / t_wall:.0f}x)"
        )
    print(f"                  {rec.stats.chunks} chunks, {size / 1e6:.0f} MB")
    print(
        f"read raw items    {t_items:7.3f} s  -> {seconds / t_items:6.0f}x real time (open_log + items)"
    )
    print(f"McapSource        {t_source:7.3f} s  -> {seconds / t_source:6.0f}x real time")
    print(
        "  by thread (CPU s per minute): open {:.4f}, data CRC thread {:.4f}, reading thread "
        "{:.4f}; as_recorded {:.4f} (skipped for a recording)".format(
            *(60.0 / seconds * t for t in split)
        )
    )
    print(
        f"read unfinished   {t_cut:7.3f} s  -> {seconds / t_cut:6.0f}x real time (no footer; {n_cut} items)"
    )
    print(
        f"mcap SeekingReader{t_ref:7.3f} s  -> {seconds / t_ref:6.0f}x real time (raw messages, not decoded)"
    )
    print(f"read frames+est.  {t_all:7.3f} s  -> {seconds / t_all:6.0f}x real time")
    print(
        f"file per hour:    full run {size * hour / 1e9:.2f} GB, raw only {size_raw * hour / 1e9:.2f} GB"
    )
    print(
        f"raw payload/hour: {raw_payload * hour / 1e9:.2f} GB; float32 size of the samples "
        f"{4 * samples * hour / 1e9:.2f} GB; payload / float32 = {raw_payload / (4 * samples):.4f}"
    )
    print(f"compression:      file / payload = {size / sum(rec.stats.payload_bytes.values()):.3f}")
    total = sum(rec.stats.payload_bytes.values())
    for topic, nbytes in sorted(rec.stats.payload_bytes.items(), key=lambda kv: -kv[1]):
        print(
            f"  {topic:<18} {rec.stats.messages[topic]:7d} msgs  {nbytes * hour / 1e9:6.3f} GB/h  "
            f"{100 * nbytes / total:5.1f} %"
        )


if __name__ == "__main__":
    main()
