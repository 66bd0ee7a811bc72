"""What the sensor positions cost the products of inertia (simulated i3, through the real dsp).

Products are small (Iyz = 0.21 kg m^2 against Ixx = 4.6), and a sensor moved by
dr reads Omega' x dr: on the dominant roll that looks like a little pitch or yaw.
With three triaxial sensors the rigid fit's redundancy cannot tell a moved sensor
from a turned or re-gained one (estimator/redundancy.py), so self-calibration does
not estimate the positions; this prints what their error costs.

Prints, over N seeds (products relative to their own value):
1. noise-free, the sensors moved by 2 mm and no other error, default settings;
2. the realistic scenario (40 dB, 1 % gains, 1 deg, residual unbalance) with
   self_calibration = true, the sensors moved by 2, 1 and 0.5 mm.

Usage: python benchmarks/bench_sensor_positions.py [--seeds 6] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import cloudpickle
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_estimator
from bench_estimator import I3, REALISTIC, errors, run_case

from ptinertia.batch.cluster import ClusterSpec, map_on_cluster

# workers need not find benchmarks/ on their path: its functions travel with the tasks
cloudpickle.register_pickle_by_value(bench_estimator)

PRODUCTS = ("Ixy", "Ixz", "Iyz")
MOVES_MM = (2.0, 1.0, 0.5)
TARGET_PCT = 2.0


def _job(*args: Any) -> dict[str, float]:
    """The errors of ``run_case(*args)``, in a worker process."""
    return errors(run_case(*args))


def report(label: str, errs: list[dict[str, float]]) -> None:
    cells = []
    for k in PRODUCTS:
        v = np.abs([e[k] for e in errs])
        cells.append(f"{k} mean {v.mean():5.2f} % max {v.max():5.2f} %")
    within = sum(max(abs(e[k]) for k in PRODUCTS) < TARGET_PCT for e in errs)
    cog = np.mean([e["cog_mm"] for e in errs])
    print(
        f"{label:34} " + "  ".join(cells) + f"  cog {cog:.2f} mm"
        f"  all products within {TARGET_PCT:g} %: {within}/{len(errs)} seeds"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    seeds = range(a.seeds)
    moved_only = [(I3, {"position_error_m": 0.002, "seed": s}, ()) for s in seeds]
    calibrated = {
        mm: [
            (
                I3,
                {**REALISTIC, "position_error_m": mm / 1000.0, "seed": s},
                (),
                None,
                {"self_calibration": True},
            )
            for s in seeds
        ]
        for mm in MOVES_MM
    }
    # the runs on a local Dask cluster of --jobs worker processes (ptinertia.batch.cluster)
    groups = [moved_only, *calibrated.values()]
    flat = map_on_cluster(ClusterSpec(workers=a.jobs), _job, [c for g in groups for c in g])
    per_group = [flat[sum(map(len, groups[:k])) :][: len(g)] for k, g in enumerate(groups)]
    first, rest = per_group[0], dict(zip(calibrated, per_group[1:], strict=True))
    print(f"== i3, products of inertia against the sensor position error, seeds 0-{a.seeds - 1}")
    report("noise-free, 2 mm only, default", first)
    for mm, errs in rest.items():
        report(f"realistic, {mm:g} mm, self-calibrated", errs)


if __name__ == "__main__":
    main()
