"""Monte Carlo studies: simulated sweeps with drawn errors, each through the real dsp and estimator.

Run ``i`` of a study draws from its own generator, seeded by
``SeedSequence(seed).spawn(runs)[i]`` on the client, never from worker state:
the draws, and so every number of the study, are the same whatever the number
of workers. Each layout sees the same draws. A task receives the bench path, the
layout's sensors and the run's ``[simulation]`` overrides, and simulates its run.

What ``--vary`` draws (each from the bench file's declared tolerances, ``[estimator]``,
or its ``[simulation]`` values where the estimator declares none):

- ``noise``: white noise at ``[simulation] noise_snr_db`` (40 dB if unset), a new
  realisation per run;
- ``gain``: each channel's gain ``1 + N(0, gain_tolerance_pct)``;
- ``alignment``: each sensor turned by ``alignment_tolerance_deg`` about a random axis;
- ``position``: each sensor moved by ``position_tolerance_m`` in a random direction;
- ``unbalance``: a residual unbalance of ``[simulation] residual_unbalance_kgm``
  (0.5 g m if unset) at a uniformly drawn angle;
- ``gas``: the engine burns ``N(0, gas_tolerance_pct)`` % more than ``[gas]`` says
  (needs the parametric gas model: the heat release is what is off);
- ``spin_inertia``: the crank train spins with ``N(0, spin_inertia_tolerance_pct)`` %
  more inertia than ``[engine]`` says;
- ``masses``: the pistons and the rods weigh ``N(0, piston_mass_tolerance_pct)`` and
  ``N(0, conrod_mass_tolerance_pct)`` % more;
- ``mounts``: each mount ``N(0, mount_stiffness_tolerance_pct)`` % stiffer, independently.

Errors not varied keep the bench's ``[simulation]`` values.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ptinertia.batch.cluster import ClusterSpec, failure_line, open_client, run_tasks
from ptinertia.batch.plots import plot_study
from ptinertia.batch.study_stats import (
    TermStats,
    cog_rms_mm,
    inertia_score_pct,
    term_stats,
    write_ranking,
    write_runs,
    write_stats,
)
from ptinertia.config import Bench, ConfigError, decode_toml, load_bench, parse_bench
from ptinertia.errors import UsageError, user_error_types
from ptinertia.no_estimate import no_estimate_reason
from ptinertia.runner import RunOptions, run_source
from ptinertia.sources import REALISTIC_SIMULATION, open_source

SIMULATED = (
    "noise", "gain", "alignment", "position", "unbalance", "gas", "spin_inertia", "masses", "mounts",
)  # fmt: skip
STUDY_BLOCK_S = 0.5  # s of simulated stream per block in a study run
DEFAULT_VARY = ("noise", "gain", "alignment", "position", "unbalance")
BENCH_LAYOUT = "bench"


@dataclass(frozen=True)
class Layout:
    """A candidate sensor layout: ``sensors`` as ``[[sensors]]`` tables of a bench file."""

    name: str
    sensors: tuple[dict[str, Any], ...] | None = None  # None: the bench file's own


@dataclass(frozen=True)
class RunResult:
    """One simulated run: ``terms[name] = (estimate, std, truth)`` in SI units, or ``error``."""

    terms: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    error: str | None = None


def parse_vary(text: str | None) -> tuple[str, ...]:
    """``--vary`` as the names of the errors to draw; an unknown name -> UsageError."""
    if text is None:
        return DEFAULT_VARY
    names = tuple(dict.fromkeys(v.strip() for v in text.split(",") if v.strip()))
    for name in names:
        if name not in SIMULATED:
            raise UsageError(f"--vary: unknown error {name!r}; known: {', '.join(SIMULATED)}")
    return names


def run_seeds(seed: int, runs: int) -> list[np.random.SeedSequence]:
    """One independent seed per run, from the study's seed and the run's index only."""
    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")
    return np.random.SeedSequence(seed).spawn(runs)


def draw_run(bench: Bench, vary: Sequence[str], seed: np.random.SeedSequence) -> dict[str, Any]:
    """The ``[simulation]`` overrides of one run (JSON-plain values)."""
    rng = np.random.default_rng(seed)
    # drawn always and in a fixed order, so that varying one error never reshuffles another
    sim_seed = int(rng.integers(0, 2**31 - 1))
    angle_deg = float(rng.uniform(0.0, 360.0))
    gas_draw = float(rng.standard_normal())
    spin_draw, piston_draw, conrod_draw = (float(x) for x in rng.standard_normal(3))
    mount_draws = rng.standard_normal(len(bench.mounts))
    sim, tol = bench.simulation, bench.estimator
    out: dict[str, Any] = {"seed": sim_seed}
    if "noise" in vary:
        out["noise_snr_db"] = sim.noise_snr_db or REALISTIC_SIMULATION["noise_snr_db"]
    if "gain" in vary:
        out["gain_error_pct"] = tol.gain_tolerance_pct
    if "alignment" in vary:
        out["misalignment_deg"] = tol.alignment_tolerance_deg
    if "position" in vary:
        out["position_error_m"] = tol.position_tolerance_m
    if "unbalance" in vary:
        out["residual_unbalance_kgm"] = (
            sim.residual_unbalance_kgm or REALISTIC_SIMULATION["residual_unbalance_kgm"]
        )
        out["residual_unbalance_deg"] = angle_deg
    # the model inputs, each inside the tolerance the estimator declares for it
    if "gas" in vary:
        out["heat_release_error_pct"] = _relative(tol.gas_tolerance_pct * gas_draw)
    if "spin_inertia" in vary:
        out["spin_inertia_error_pct"] = _relative(tol.spin_inertia_tolerance_pct * spin_draw)
    if "masses" in vary:
        out["piston_mass_error_pct"] = _relative(tol.piston_mass_tolerance_pct * piston_draw)
        out["conrod_mass_error_pct"] = _relative(tol.conrod_mass_tolerance_pct * conrod_draw)
    if "mounts" in vary:
        out["mount_stiffness_error_pct"] = [
            _relative(tol.mount_stiffness_tolerance_pct * float(x)) for x in mount_draws
        ]
    return out


def _relative(pct: float) -> float:
    """A drawn relative error in %, kept above -90 % (a part cannot lose its mass)."""
    return max(pct, -90.0)


def load_layouts(path: str | None, bench: Bench) -> list[Layout]:
    """The bench's own layout, then each ``[[layouts]]`` of ``path`` (checked against ``bench``).

    ``path`` holds ``[[layouts]]`` tables, each a ``name`` and its ``[[layouts.sensors]]``
    (the keys of a bench file's ``[[sensors]]``).
    """
    layouts = [Layout(BENCH_LAYOUT)]
    if path is None:
        return layouts
    try:
        # as a bench file is read: UTF-8 with or without a byte order mark, anything
        # else one line
        data = tomllib.loads(decode_toml(Path(path).read_bytes(), path))
    except OSError as err:
        raise UsageError(f"--layouts: cannot read {path} ({err.strerror})") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML ({err})") from None
    entries = data.get("layouts")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{path}: expected [[layouts]] tables, each a name and its sensors")
    for k, entry in enumerate(entries):
        name = entry.get("name") if isinstance(entry, dict) else None
        if not isinstance(name, str) or not name or name in {x.name for x in layouts}:
            raise ConfigError(f"{path}: layouts[{k}]: expected a unique name, got {name!r}")
        layout = Layout(name, tuple(entry.get("sensors") or ()))
        with_layout(bench, layout, f"{path}: layout {name!r}")  # validates it
        layouts.append(layout)
    return layouts


def with_layout(bench: Bench, layout: Layout, where: str = "layout") -> Bench:
    """``bench`` with the sensors of ``layout``."""
    if layout.sensors is None:
        return bench
    data = bench.model_dump(mode="json")
    data["sensors"] = [dict(s) for s in layout.sensors]
    return parse_bench(data, where)


def check_vary(bench: Bench, vary: Sequence[str]) -> None:
    """What the simulator cannot draw for this bench: a one-line error before any run."""
    if "gas" in vary and bench.gas.model != "parametric":
        raise UsageError(
            f"--vary gas: needs [gas] model = 'parametric' (the heat release is what is off), "
            f"the bench has {bench.gas.model!r}"
        )


def simulate_run(
    bench_path: str, layout: Layout, overrides: dict[str, Any], duration_s: float | None
) -> RunResult:
    """One simulated sweep through the dsp and the estimator (runs on a worker)."""
    try:
        bench = with_layout(load_bench(bench_path), layout)
        extra = {} if duration_s is None else {"duration_s": duration_s}
        # nobody watches a study run live: half-second blocks instead of the live 0.1 s halve
        # the per-block work of dsp and estimator (5 realistic runs: 7.5 -> 4.3 s of CPU;
        # estimates and stds within 5e-13 relative; benchmarks/bench_pipeline.py)
        extra["block_s"] = STUDY_BLOCK_S
        source = open_source("sim", bench, **overrides, **extra)
        text = Path(bench_path).read_text(encoding="utf-8")
        summary, doc = run_source(bench, text, source, "sim", RunOptions(quiet=True))
    except user_error_types() as err:
        return RunResult(error=str(err))
    if doc is None:
        return RunResult(
            error=f"no estimate: {no_estimate_reason(summary.rejected, summary.orders_rejected)}"
        )
    return RunResult(terms=run_terms(doc))


def run_terms(doc: dict[str, Any]) -> dict[str, tuple[float, float, float]]:
    """``term -> (estimate, std, truth)`` of a simulated run's result document."""
    truth = doc["truth"]
    out: dict[str, tuple[float, float, float]] = {}
    inertia = doc["inertia_kgm2"]
    for name, value in inertia["value"].items():
        out[name] = (value, inertia["std"][name], truth["inertia_kgm2"]["value"][name])
    for i, name in enumerate(("Gx", "Gy", "Gz")):
        out[name] = (doc["cog_m"]["value"][i], doc["cog_m"]["std"][i], truth["cog_m"]["value"][i])
    if doc.get("mass_kg"):
        mass = doc["mass_kg"]
        out["mass"] = (mass["value"], mass["std"], truth["mass_kg"]["value"])
    return out


@dataclass(frozen=True)
class StudyOutcome:
    """What a study found: the draws per run, each layout's runs, per-term figures, the ranking
    (``(layout, inertia score %, cog RMS mm, runs with an estimate)``, best first)."""

    draws: list[dict[str, Any]]
    results: dict[str, list[RunResult]]
    stats: dict[str, dict[str, TermStats]]
    ranking: list[tuple[str, float, float, int]]


def run_study(
    bench_path: str,
    runs: int,
    vary: Sequence[str],
    layouts: Sequence[Layout],
    seed: int,
    duration_s: float | None,
    out_dir: Path,
    spec: ClusterSpec,
    progress: bool = True,
) -> StudyOutcome:
    """``runs`` simulated sweeps per layout on the cluster ``spec``; the figures written to
    ``out_dir`` (``study.csv``, ``runs.csv``, ``layouts.csv``, ``study.png``)."""
    # imported here: tqdm's bar only for studies and campaigns
    from tqdm import tqdm

    if runs < 1:
        raise UsageError(f"--runs: expected a positive number, got {runs}")
    bench = load_bench(bench_path)
    check_vary(bench, vary)
    draws = [draw_run(bench, vary, s) for s in run_seeds(seed, runs)]
    calls = [(bench_path, layout, draw, duration_s) for layout in layouts for draw in draws]
    out_dir.mkdir(parents=True, exist_ok=True)
    with (
        open_client(spec) as client,
        tqdm(total=len(calls), unit="run", disable=not progress) as bar,
    ):
        raw = run_tasks(
            client, simulate_run, calls, on_done=lambda i, r: bar.update(1), key="study"
        )
    results: dict[str, list[RunResult]] = {}
    for k, layout in enumerate(layouts):
        results[layout.name] = [
            r if isinstance(r, RunResult) else RunResult(error=failure_line(r))
            for r in raw[k * runs : (k + 1) * runs]
        ]
    ok = {name: [r.terms for r in per if r.error is None] for name, per in results.items()}
    stats = {name: term_stats(terms) for name, terms in ok.items()}
    ranking = sorted(
        ((name, inertia_score_pct(t), cog_rms_mm(t), len(t)) for name, t in ok.items()),
        key=lambda row: (not row[3], row[1]),
    )
    write_stats(stats, out_dir / "study.csv")
    write_runs(draws, results, out_dir / "runs.csv")
    write_ranking(ranking, out_dir / "layouts.csv")
    shown = {name: s for name, s in stats.items() if s}
    if shown:
        errors = {
            name: {t: [(r[t][0] - r[t][2], r[t][1]) for r in ok[name] if t in r] for t in s}
            for name, s in shown.items()
        }
        units = {t: st.unit for s in shown.values() for t, st in s.items()}
        coverage = {name: {t: st.coverage for t, st in s.items()} for name, s in shown.items()}
        plot_study(errors, units, coverage, out_dir / "study.png")
    return StudyOutcome(draws, results, stats, ranking)
