"""The estimator benchmark's scenario families run alone (``bench_estimator.py --only
noise|model|unbalance``): noise without an elastic mode, the model inputs drawn inside their
tolerances, and an off-centre residual unbalance located (the figures in bench_estimator's
docstring, items 9-11)."""

from __future__ import annotations

from typing import Any

import numpy as np
from estimator_cases import (
    ELASTIC_140,
    I3,
    I4,
    REALISTIC,
    TERMS,
    covered,
    errors,
    line,
    run_case,
)

from ptinertia.batch.cluster import ClusterSpec, map_on_cluster


def noise_alone(seeds: int, jobs: int, dur: dict[str, Any]) -> None:
    """Part 9: no elastic mode from noise alone; the 140 Hz mode still confirmed."""
    noisy = [
        (I3, {**dur, "noise_snr_db": db, "seed": s}, (), None)
        for db in (40.0, 30.0)
        for s in range(1, seeds + 1)
    ]
    elastic = [
        (I3, {**dur, **REALISTIC, "seed": s, "elastic_mode": ELASTIC_140}, (), None)
        for s in range(6)
    ]
    realistic = [(I3, {**dur, **REALISTIC, "seed": s}, (), None) for s in range(seeds)]
    docs = map_on_cluster(ClusterSpec(workers=jobs), run_case, noisy + elastic + realistic)
    real, docs = docs[len(noisy) + len(elastic) :], docs[: len(noisy) + len(elastic)]
    for i, db in enumerate((40.0, 30.0)):
        group = docs[i * seeds : (i + 1) * seeds]
        modes = [d["elastic_mode"] for d in group if d.get("elastic_mode")]
        worst = max(max(abs(v) for k, v in errors(d).items() if k in TERMS) for d in group)
        print(
            f"== rigid i3, noise alone at {db:.0f} dB, {seeds} seeds: elastic mode reported in "
            f"{len(modes)}/{seeds} {modes if modes else ''}; worst term error {worst:.2f} %"
        )
    group = docs[2 * seeds :]
    print(
        f"== elastic mode at 140 Hz (realistic errors), seeds 0-5: confirmed in "
        f"{sum(d.get('elastic_mode') is not None for d in group)}/6 at "
        + ", ".join(
            f"{d['elastic_mode']['frequency_hz']:.0f}" for d in group if d.get("elastic_mode")
        )
        + " Hz; cog error "
        + ", ".join(f"{errors(d)['cog_mm']:.1f}" for d in group)
        + " mm"
    )
    modes = [d["elastic_mode"] for d in real if d.get("elastic_mode")]
    print(
        f"== realistic i3 (rigid; noise and sensor errors), {seeds} seeds: elastic mode reported "
        f"in {len(modes)}/{seeds}; model flagged inconsistent in "
        f"{sum(not d.get('consistent', True) for d in real)}/{seeds}; seeds with orders rejected "
        f"as non_rigid {sum(bool(d['frames']['orders_rejected'].get('non_rigid')) for d in real)}"
    )


MODEL_INPUTS = ("gas", "spin_inertia", "masses", "mounts")
NO_MODEL_TOLERANCES = {
    "gas_tolerance_pct": 0.0,
    "spin_inertia_tolerance_pct": 0.0,
    "piston_mass_tolerance_pct": 0.0,
    "conrod_mass_tolerance_pct": 0.0,
    "mount_stiffness_tolerance_pct": 0.0,
    "crankcase_pressure_tolerance_pa": 0.0,
}


def model_inputs_drawn(seeds: int, jobs: int, dur: dict[str, Any]) -> None:
    """Part 10: model inputs drawn inside their declared tolerances, with the realistic errors."""
    from ptinertia.batch.study import draw_run, run_seeds
    from ptinertia.config import load_bench

    bench = load_bench(I3)
    draws = [draw_run(bench, MODEL_INPUTS, s) for s in run_seeds(0, seeds)]
    runs = [(I3, {**dur, **REALISTIC, **d}, (), None) for d in draws]
    without = [(*case, NO_MODEL_TOLERANCES) for case in runs]
    docs = map_on_cluster(ClusterSpec(workers=jobs), run_case, runs + without)
    tol = bench.estimator
    print(
        f"== realistic i3 with the model inputs drawn inside their declared tolerances, {seeds} "
        f"seeds (1 sigma: heat release {tol.gas_tolerance_pct:g} %, spin inertia "
        f"{tol.spin_inertia_tolerance_pct:g} %, pistons {tol.piston_mass_tolerance_pct:g} %, "
        f"rods {tol.conrod_mass_tolerance_pct:g} %, each mount "
        f"{tol.mount_stiffness_tolerance_pct:g} %)"
    )
    keys = ("heat_release_error_pct", "spin_inertia_error_pct", "piston_mass_error_pct")
    for k in keys:
        v = np.array([d[k] for d in draws])
        print(f"   drawn {k}: {', '.join(f'{x:+.1f}' for x in v)}")
    for label, group in (
        ("model tolerances declared", docs[:seeds]),
        ("model tolerances left out (0)", docs[seeds:]),
    ):
        errs = [errors(d) for d in group]
        cov = [covered(d) for d in group]
        print(f"-- {label}")
        for k in (*TERMS, "cog_mm"):
            v = np.array([e[k] for e in errs])
            unit = "mm" if k == "cog_mm" else "%"
            text = f"  {k:7} mean |err| {np.mean(np.abs(v)):6.2f} {unit}  max |err| {np.max(np.abs(v)):6.2f} {unit}"
            if k in TERMS:
                half = [
                    100
                    * 1.96
                    * d["inertia_kgm2"]["std"][k]
                    / abs(d["truth"]["inertia_kgm2"]["value"][k])
                    for d in group
                ]
                text += f"  95% +- {np.median(half):6.2f} % (median)"
                text += f"  covers truth in {sum(c[k] for c in cov)}/{seeds}"
            else:
                for g in ("Gx", "Gy", "Gz"):
                    text += f"  {g} covered {sum(c[g] for c in cov)}/{seeds}"
            print(text)
        all_cov = sum(all(c.values()) for c in cov)
        print(f"  all nine intervals cover the truth in {all_cov}/{seeds} seeds")


OFF_CENTRE = {
    "residual_unbalance_kgm": 1e-3,
    "residual_unbalance_deg": 120.0,
    "residual_unbalance_axial_m": 0.08,
}


def unbalance_errors(doc: dict[str, Any]) -> dict[str, float]:
    """Amplitude error %, phase error deg, location error mm of the estimated unbalance."""
    t, u = doc["truth"]["unbalance"], doc["unbalance"]
    phase = (u["angle_deg"]["value"] - t["angle_deg"] + 180.0) % 360.0 - 180.0
    out = {"mr_%": 100 * (u["mr_kgm"]["value"] - t["mr_kgm"]) / t["mr_kgm"], "phase_deg": phase}
    if u.get("axial_m"):
        out["axial_mm"] = 1e3 * (u["axial_m"]["value"] - t["axial_m"])
    return out


def unbalance_covered(doc: dict[str, Any]) -> dict[str, bool]:
    """Whether the 95 % intervals of the unbalance's amplitude, phase and location hold the truth."""
    u, err = doc["unbalance"], unbalance_errors(doc)
    t = doc["truth"]["unbalance"]
    out = {
        "mr": abs(err["mr_%"] * t["mr_kgm"] / 100) <= 1.96 * (u["mr_kgm"]["std"] or 0.0),
        "phase": abs(err["phase_deg"]) <= 1.96 * (u["angle_deg"]["std"] or 0.0),
    }
    if "axial_mm" in err:
        out["axial"] = abs(err["axial_mm"]) <= 1.96e3 * (u["axial_m"]["std"] or 0.0)
    return out


def unbalance_located(seeds: int, jobs: int, dur: dict[str, Any]) -> None:
    """Part 10: an unbalance off the reference point, located; the inline 4's unbalance."""
    located = {"unbalance_location": True}  # [estimator] unbalance_location = true
    off = [(I3, {**dur, **OFF_CENTRE}, (), None, located)]
    real = [
        (I3, {**dur, **REALISTIC, **OFF_CENTRE, "seed": s}, (), None, located) for s in range(seeds)
    ]
    i4 = [(I4, {**dur, **REALISTIC, "seed": s}, (), None, located) for s in range(min(seeds, 10))]
    docs = map_on_cluster(ClusterSpec(workers=jobs), run_case, off + real + i4)
    clean, real_docs, i4_docs = docs[0], docs[1 : 1 + seeds], docs[1 + seeds :]
    print("== i3, 1 g m unbalance at 120 deg 80 mm along the crank from the reference point")
    ue = unbalance_errors(clean)
    print(
        line("noise-free", errors(clean)),
        f" unbalance {ue['mr_%']:+.3f} %, {ue['phase_deg']:+.3f} deg, "
        f"{ue.get('axial_mm', float('nan')):+.2f} mm; "
        f"couple {1e3 * clean['unbalance']['couple_kgm2']['value']:.5f} g m^2",
    )
    errs = [errors(d) for d in real_docs]
    cov = [covered(d) for d in real_docs]
    smallest = [min(np.linalg.eigvalsh(_truth_tensor(d))) for d in real_docs]
    print(f"== the same with the realistic errors, {seeds} seeds")
    for k in TERMS:
        v = np.array([e[k] for e in errs])
        if k in ("Ixx", "Iyy", "Izz"):
            a = np.abs(v)
            what = f"mean |err| {np.mean(a):5.2f}, max {np.max(a):5.2f} % (of its value)"
        else:  # products against the smallest principal moment
            t = np.array([d["truth"]["inertia_kgm2"]["value"][k] for d in real_docs])
            a = np.abs(v / 100 * t) / np.array(smallest) * 100
            what = f"mean |err| {np.mean(a):5.2f}, max {np.max(a):5.2f} % of the smallest principal moment"
        print(f"  {k:4} {what}; interval holds the truth in {sum(c[k] for c in cov)}/{seeds}")
    cog = np.array([e["cog_mm"] for e in errs])
    print(
        f"  cog  mean error {np.mean(cog):.2f}, max {np.max(cog):.2f} mm; intervals hold Gx/Gy/Gz in "
        + "/".join(str(sum(c[g] for c in cov)) for g in ("Gx", "Gy", "Gz"))
        + f" of {seeds}"
    )
    ues = [unbalance_errors(d) for d in real_docs]
    ucs = [unbalance_covered(d) for d in real_docs]
    for key, unit, cover in (
        ("mr_%", "%", "mr"),
        ("phase_deg", "deg", "phase"),
        ("axial_mm", "mm", "axial"),
    ):
        v = np.array([u.get(key, np.nan) for u in ues])
        print(
            f"  unbalance {key.split('_')[0]:6} mean |err| {np.nanmean(np.abs(v)):.2f}, "
            f"max {np.nanmax(np.abs(v)):.2f} {unit}; "
            f"interval holds the truth in {sum(c.get(cover, False) for c in ucs)}/{seeds}"
        )
    i4_err = [unbalance_errors(d)["mr_%"] for d in i4_docs if d.get("unbalance")]
    i4_cov = [sum(covered(d).values()) for d in i4_docs]
    print(
        f"== inline 4, realistic (0.5 g m at 40 deg), {len(i4_docs)} seeds: unbalance estimated in "
        f"{len(i4_err)}, amplitude error max {np.max(np.abs(i4_err)) if i4_err else float('nan'):.1f} %; "
        f"seeds whose nine intervals all hold the truth {sum(c == 9 for c in i4_cov)}/{len(i4_docs)}"
    )


def _truth_tensor(doc: dict[str, Any]) -> np.ndarray:
    from estimator.result import tensor_from_terms

    t = doc["truth"]["inertia_kgm2"]["value"]
    return tensor_from_terms(np.array([t[k] for k in TERMS]))
