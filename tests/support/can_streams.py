"""The simulated i3 stream as CAN frames (DBC plan, assembly, comparison), shared by the CAN tests."""

from __future__ import annotations

import queue
import threading
from pathlib import Path

import numpy as np

from acquisition.can.frames import RawFrame
from acquisition.can.plan import CanPlan
from acquisition.stream import EdgeBlock, SampleBlock, SourceEvent
from ptinertia.commands.can_sim import simulate_to_bus
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import RunOptions, run_source
from ptinertia.sources import REALISTIC_SIMULATION, open_source

DBC = EXAMPLES_DIR / "bench.dbc"


REALISTIC = REALISTIC_SIMULATION
RUN = {**REALISTIC, "duration_s": 8.0, "rpm_start": 1500.0, "rpm_end": 4500.0, "seed": 3}
TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


SIM = {"duration_s": 3.0, "rpm_start": 1500.0, "rpm_end": 4500.0, "noise_snr_db": 40.0}


def can_bench_file(tmp_path: Path, name: str = "i3-bench.toml", dbc: Path | str = DBC) -> Path:
    """A copy of an example bench that names ``dbc`` in its ``[can]`` table."""
    text = (EXAMPLES_DIR / name).read_text()
    # The examples name their DBC relative to examples/; point at the one asked for.
    head, sep, _ = text.partition("\n[can]\n")
    assert sep, f"{name} has no [can] table"
    path = tmp_path / f"can-{name}"
    path.write_text(
        head
        + f'\n[can]\ndbc = "{Path(dbc).resolve()}"\ninterface = "virtual"\nchannel = "ptinertia"\n'
    )
    return path


class VirtualClock:
    """The live CAN source's clock in virtual time: it advances only when the source waits
    for frames that the (stub) bus will never send, so nothing sleeps and no test depends
    on how fast the machine is. ``quiet`` tells when the bus has nothing more to give."""

    def __init__(self, quiet=lambda: True):
        self.t = 0.0
        self.quiet = quiet
        self._lock = threading.Lock()

    def now(self):
        with self._lock:
            return self.t

    def sleep(self, seconds, stop):
        with self._lock:
            self.t += seconds
        return stop.is_set()

    def get(self, q, timeout):
        while True:
            try:
                return q.get_nowait()
            except queue.Empty:
                pass
            if self.quiet():
                with self._lock:
                    self.t += timeout
                raise queue.Empty
            # more is coming from the receive thread: wait for it (an event, not a time)
            try:
                return q.get(timeout=1.0)
            except queue.Empty:
                continue


def assemble(items, layout):
    """Per group (n_ch, n) arrays (NaN where no sample came), per edge channel the edge times, events."""
    groups = {}
    for g in layout.groups:
        blocks = [b for b in items if isinstance(b, SampleBlock) and b.group == g.name]
        n = max((b.first_index + b.n_samples for b in blocks), default=0)
        out = np.full((len(g.channels), n), np.nan)
        for b in blocks:
            assert np.all(np.isnan(out[:, b.first_index : b.first_index + b.n_samples])), (
                "sample given twice"
            )
            out[:, b.first_index : b.first_index + b.n_samples] = b.data
        groups[g.name] = out
    edges = {
        ch: np.concatenate(
            [b.times_s for b in items if isinstance(b, EdgeBlock) and b.channel == ch]
            or [np.zeros(0)]
        )
        for ch in layout.edge_channels
    }
    events = [e for e in items if isinstance(e, SourceEvent)]
    return groups, edges, events


def simulated(bench, **overrides):
    """The simulated source's layout and items (the reference)."""
    with open_source("sim", bench, **{**SIM, **overrides}) as src:
        return src.layout, list(src)


def sim_frames(bench, plan, faults=None, **overrides):
    """The frames ``can-sim`` sends for the same simulation, stamped with their DAQ time."""
    frames: list[RawFrame] = []
    summary = simulate_to_bus(
        bench,
        plan,
        bus=None,
        log_frame=frames.append,
        pace=False,
        faults=faults,
        sim_overrides={**SIM, **overrides},
    )
    return frames, summary


def quantum(plan: CanPlan, group: str) -> float:
    return max(sc.scale for m in plan.messages if m.group == group for sc in m.scalings) / 2


def check_same_stream(plan, sim_layout, sim_items, items):
    """The decoded items carry the simulated stream: every sample and edge, in place, within quantisation."""
    ref_g, ref_e, _ = assemble(sim_items, sim_layout)
    got_g, got_e, events = assemble(items, plan.layout)
    assert plan.layout.groups == sim_layout.groups
    assert plan.layout.edge_channels == sim_layout.edge_channels
    for name, ref in ref_g.items():
        got = got_g[name]
        assert got.shape == ref.shape, name
        assert not np.isnan(got).any(), f"{name}: {np.isnan(got).sum()} samples missing"
        assert np.abs(got - ref).max() <= quantum(plan, name) * (1 + 1e-9), name
    tick = next(m.tick_s for m in plan.messages if m.kind == "edges")
    for ch, ref in ref_e.items():
        assert got_e[ch].shape == ref.shape, ch
        assert np.abs(got_e[ch] - ref).max() <= tick / 2 + 1e-12
    assert not [e for e in events if e.kind == "gap"]


def realistic_bench(tmp_path: Path, bench_path: Path) -> Path:
    """The bench file with the realistic imperfections in its ``[simulation]`` (for the CLI)."""
    keys = "".join(f"{k} = {v}\n" for k, v in REALISTIC.items())
    path = tmp_path / "realistic.toml"
    path.write_text(bench_path.read_text().replace("[simulation]\n", "[simulation]\n" + keys))
    return path


def estimate(bench_path: Path, source, spec: str) -> dict:
    """The result document of the chain on ``source`` (the shared body)."""
    bench = load_bench(bench_path)
    summary, doc = run_source(
        bench,
        bench_path.read_text(),
        source,
        spec,
        RunOptions(quiet=True, live=spec.startswith("can")),
    )
    assert doc is not None and not summary.interrupted
    return doc
