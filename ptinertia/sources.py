"""Open a source from a short spec: ``sim``, ``file:PATH``, ``can:INTERFACE:CHANNEL``.

The spec names the backend (:mod:`ptinertia.registry`, imported lazily); the
bench file says which channels the estimate needs, so a CSV or MF4 recording
is checked against it on opening (a missing channel is a :class:`SourceError`
naming it, not a silent hole later on). CAN logs and live buses are checked by
their own openers against the DBC; MCAP replays by theirs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from acquisition.can.logs import is_can_log
from acquisition.channels import check_channels
from acquisition.sim.sweep import RpmProfile
from acquisition.stream import Source, SourceError
from ptinertia.config import Bench, Simulation, Tacho, parse_bench
from ptinertia.registry import file_kind, source_backend
from ptinertia.to_acquisition import (
    channel_needs,
    recorded_channel_needs,
    sweep_profile,
    tacho_spec,
)
from ptinertia.to_can import can_settings
from ptinertia.to_physics import build_simulated_model

# options of the simulated source that are not bench-file keys
SIM_OPTIONS = (
    "block_s",
    "paced",
    "profile",
    "tacho_rise_s",
    "table_rtol",
    "table_degree",
    "bench_text",
    "clock",
    "sleep",
)
FILE_OPTIONS = ("block_s",)

# The "realistic" bench of the accuracy figures (run --realistic, tests, benchmarks):
# 40 dB noise, 1 % gain, 1 deg alignment and 2 mm position errors, a residual unbalance.
REALISTIC_SIMULATION = {
    "noise_snr_db": 40.0,
    "gain_error_pct": 1.0,
    "misalignment_deg": 1.0,
    "position_error_m": 0.002,
    "residual_unbalance_kgm": 5e-4,
    "residual_unbalance_deg": 40.0,
}
FILE_SUFFIXES = (".csv", ".mf4", ".mdf", ".blf", ".asc", ".trc", ".log", ".mcap")


def open_source(spec: str, bench: Bench, **overrides: Any) -> Source:
    """Open the source ``spec`` for ``bench``.

    Parameters
    ----------
    spec : str
        ``"sim"`` (the simulated bench); ``"file:PATH"``: a CSV base file or an
        MF4 recording (:mod:`acquisition.files.csvfile`, :mod:`acquisition.files.mdf`), a
        CAN log (``.blf .asc .trc .log``, or an MF4 of raw CAN frames), an MCAP
        recording to replay (a bare path with one of those extensions works
        too); ``"can:INTERFACE:CHANNEL"`` a live bus (either part defaults to
        the bench's ``[can]``).
    bench : Bench
    **overrides
        ``sim``: any ``[simulation]`` key (``rpm_start``, ``duration_s``,
        ``noise_snr_db``, ``seed``, ...), ``accel_rate_hz``, ``tacho`` (a dict
        of ``[tacho]`` keys or a ``Tacho``), and the options ``block_s``,
        ``paced``, ``profile`` (an :class:`RpmProfile` replacing the default
        sweep), ``tacho_rise_s``, ``table_rtol``, ``table_degree``,
        ``bench_text``. CSV and MF4: ``block_s``. CAN, CAN logs and MCAP: the
        options of their openers.

    Raises
    ------
    SourceError
        Unknown spec or option, unreadable file, a channel the bench needs
        missing from the file.
    ConfigError
        An override that makes the bench invalid.
    """
    kind, sep, arg = spec.partition(":")
    if spec == "sim":
        return open_simulated(bench, **overrides)
    if kind == "file" and sep:
        return open_file(arg, bench, **overrides)
    if kind == "can" and sep:
        source: Source = source_backend("can")(
            arg, can_settings(bench.can), channel_needs(bench), **overrides
        )
        return source
    if Path(spec).suffix.lower() in FILE_SUFFIXES:
        return open_file(spec, bench, **overrides)
    raise SourceError(
        f"source {spec!r}: expected 'sim', 'file:PATH' ({', '.join(FILE_SUFFIXES)}) "
        "or 'can:INTERFACE:CHANNEL'"
    )


def _unknown(options: dict[str, Any], known: tuple[str, ...] | list[str], what: str) -> None:
    bad = sorted(set(options) - set(known))
    if bad:
        raise SourceError(f"{what}: unknown option {bad[0]!r}; known: {', '.join(sorted(known))}")


def simulated_bench(bench: Bench, **overrides: Any) -> Bench:
    """``bench`` with ``[simulation]``, ``accel_rate_hz`` and ``[tacho]`` overrides, validated."""
    sim_keys = set(Simulation.model_fields)
    sim_upd = {k: v for k, v in overrides.items() if k in sim_keys}
    data = bench.model_dump(mode="json")
    data["simulation"].update(sim_upd)
    if "accel_rate_hz" in overrides:
        data["sampling"]["accel_rate_hz"] = overrides["accel_rate_hz"]
    tacho = overrides.get("tacho")
    if isinstance(tacho, Tacho):
        data["tacho"] = tacho.model_dump(mode="json")
    elif isinstance(tacho, dict):
        data["tacho"].update(tacho)
    elif tacho is not None:
        raise SourceError(
            f"tacho: expected a dict of [tacho] keys or a Tacho, got {type(tacho).__name__}"
        )
    return parse_bench(data, "overrides")


def open_simulated(bench: Bench, **overrides: Any) -> Source:
    """The simulated bench of ``bench`` (see :func:`open_source` for the overrides)."""
    known = [*Simulation.model_fields, "accel_rate_hz", "tacho", *SIM_OPTIONS]
    _unknown(overrides, known, "source 'sim'")
    bench = simulated_bench(bench, **{k: v for k, v in overrides.items() if k not in SIM_OPTIONS})
    options = {k: v for k, v in overrides.items() if k in SIM_OPTIONS}
    sim = bench.simulation
    profile = options.pop("profile", None)
    if profile is None:
        profile = sweep_profile(sim)
    elif not isinstance(profile, RpmProfile):
        raise SourceError(f"profile: expected an RpmProfile, got {type(profile).__name__}")
    metadata: dict[str, Any] = {"bench": bench.model_dump(mode="json")}
    text = options.pop("bench_text", None)
    if text is not None:
        metadata["bench_text"] = str(text)
    model, truth = build_simulated_model(bench, sim)
    cls = source_backend("sim")
    source: Source = cls(
        model,
        tacho=tacho_spec(bench.tacho),
        accel_rate_hz=bench.sampling.accel_rate_hz,
        profile=profile,
        max_order=sim.max_order,
        noise_snr_db=sim.noise_snr_db,
        seed=sim.seed,
        truth=truth,
        metadata=metadata,
        record_pressure=bench.estimator.gas_torque == "pressure",
        dead_channels=tuple(sim.dead_channels),
        **options,
    )
    return source


def open_file(path: str | Path, bench: Bench, **overrides: Any) -> Source:
    """A recording chosen by its extension.

    CSV and MF4 pass on only the channels ``bench`` reads, found by the names of its
    ``[channels]`` table and converted to the pipeline's units.
    """
    path = Path(path)
    # a CAN log by its extension (also compressed: run.asc.gz) or an MF4 of raw CAN frames
    kind = "can-log" if is_can_log(path) else file_kind(path.suffix)
    if kind == "can-log":
        log: Source = source_backend(kind)(
            path, can_settings(bench.can), channel_needs(bench), **overrides
        )
        return log
    if kind == "mcap":
        replayed: Source = source_backend(kind)(path, channel_needs(bench), **overrides)
        return replayed
    _unknown(overrides, FILE_OPTIONS, f"source 'file:{path}'")
    needs = recorded_channel_needs(bench)
    source: Source = source_backend(kind)(path, needs=needs, **overrides)
    try:
        check_channels(source.layout, needs, str(path))
    except BaseException:
        source.close()
        raise
    return source
