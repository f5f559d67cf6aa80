"""Benchmark: the coupled slope failure (TLSPH + IISPH + phase change), time by stage.

Runs the built-in ``slope_failure`` scene (or ``--scene``) to ``--end-time`` and prints,
in the long CSV format of ``jobs/benchlib.py``: seconds per step (median over the steps
with fluid, and over the TLSPH-only steps before the first phase change), split into the
TLSPH stage, the fluid assembly, the viscous and PPE KSP solves, the fluid stage's halo
refreshes, the phase-change bookkeeping (view rebuilds) and the infrastructure (migrate,
current halo, neighbours); particle-steps per second per core of the coupled step; and
the load balance over time (largest over smallest owned solid and fluid counts per rank,
at the quarters of the run).

    .venv/bin/python jobs/bench_coupled.py --end-time 1.0
    mpirun -n 2 .venv/bin/python jobs/bench_coupled.py --end-time 1.0 --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from decomposition import world

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record, run_benchmark  # noqa: E402

STAGES = ("solid", "fluid_assembly", "visc_solve", "ppe_solve", "fluid_halo", "phase_change")
INFRA = ("migrate", "halo", "neighbours")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="slope_failure")
    ap.add_argument("--end-time", type=float, default=1.0, help="simulated seconds")
    ap.add_argument("--set", action="append", default=[], help="extra scene overrides")
    ap.add_argument("--csv", default=None, help="append the rows to this CSV file")
    args, petsc_args = ap.parse_known_args()
    petsc_args = [a for a in petsc_args if a != "--"]
    comm = world()
    summary, stats = run_benchmark(
        comm, args.scene, [f"run.end_time={args.end_time}", f"output.every={args.end_time}",
                           "output.progress=false", *args.set], petsc_args)
    if comm.rank != 0:
        return

    def col(name):
        return np.asarray(stats[name], dtype=float)

    n_fluid = col("n_fluid")
    infra = sum(col(f"wall_s_{k}") for k in INFRA)
    total = infra + col("wall_s_coupled")
    coupled = n_fluid > 0
    coupled[:2] = False  # JIT warm-up
    solid_only = (n_fluid == 0)
    solid_only[:2] = False
    n = summary["particles"]
    metrics = {"steps": len(total), "steps_with_fluid": int(coupled.sum()),
               "n_fluidised": int(col("n_fluidised")[-1]),
               "wall_s": float(summary["wall_s"])}
    if solid_only.any():
        metrics["s_per_step_tlsph_only"] = float(np.median(total[solid_only]))
    if coupled.any():
        s_step = float(np.median(total[coupled]))
        metrics["s_per_step_coupled"] = s_step
        for k in STAGES:
            metrics[f"s_per_step_{k}"] = float(np.median(col(f"wall_s_{k}")[coupled]))
        metrics["s_per_step_infrastructure"] = float(np.median(infra[coupled]))
        metrics["particle_steps_per_s_per_core"] = n / s_step / comm.size
        metrics["ppe_iterations"] = float(np.median(col("ppe_iterations")[coupled]))
        metrics["visc_iterations"] = float(np.median(col("visc_iterations")[coupled]))
    for q in (1, 2, 3, 4):  # load balance as the landslide moves
        k = min(len(total) - 1, q * len(total) // 4)
        for phase in ("solid", "fluid"):
            lo, hi = col(f"n_{phase}_rank_min")[k], col(f"n_{phase}_rank_max")[k]
            metrics[f"{phase}_per_rank_t{q}_min"] = int(lo)
            metrics[f"{phase}_per_rank_t{q}_max"] = int(hi)
    record(args.csv, f"coupled_{args.scene}", "parsph", summary["dim"], n, comm.size, metrics)


if __name__ == "__main__":
    main()
