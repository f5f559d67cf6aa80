"""Benchmark: IISPH dam break, PPE iterations and time per step as the particle count grows.

Runs the built-in ``dam_break`` scene at a given particle size for a fixed number of
steps and prints its figures (long CSV format of ``jobs/benchlib.py``): PPE and viscous
KSP iterations (median over the steps; 0 viscous iterations = the explicit predictor of
``fluid.viscous_solver = auto``), the share of steps with a fresh AMG set-up
(``fluid.preconditioner_reuse``), seconds per step (mean over the steps) split into fluid
assembly (numba kernels, CSR blocks and PETSc matrices), solves (KSPSolve, set-up
included), the stage's halo refreshes and the infrastructure (migrate, halo,
neighbours), and particle-steps per second per core. ``s_per_step`` is the whole step by
the step loop's clock (``stats.csv`` ``elapsed_s``), the mean over the steps after the
first (its row holds the run's set-up: ``startup_s``), the median beside; the stages'
means leave out steps 1-2 (JIT cache loads, first matrices). ``peak_rss_mib_max`` and
``bytes_per_particle_peak_rss``: the whole process's peak RSS, the largest rank's and every
rank's over all particles.

    .venv/bin/python jobs/bench_iisph.py --divisions 20 --steps 30
    for n in 20 40 80; do mpirun -n 2 .venv/bin/python jobs/bench_iisph.py --divisions $n; done

``--divisions`` is a / d (column width over particle size): 4x the divisions is 16x the
particles. PETSc options after ``--`` pass through (e.g. ``-- -ppe_ksp_rtol 1e-10``).
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from decomposition import world

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record, run_benchmark, step_figures  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--divisions", type=int, default=20, help="a / d (dam_break: a = 0.146 m)")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--csv", default=None, help="append the row to this CSV file")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scene override, e.g. fluid.viscous_solver=implicit (repeatable)")
    args, petsc_args = ap.parse_known_args()
    petsc_args = [a for a in petsc_args if a != "--"]
    comm = world()
    d = 0.146 / args.divisions
    summary, stats = run_benchmark(
        comm, "dam_break", [f"domain.particle_size={d!r}", f"run.max_steps={args.steps}",
                            "output.every=0.3", "output.progress=false", *args.set], petsc_args)
    if comm.rank == 0:
        skip = slice(2, None)

        def col(name):
            return np.asarray(stats[name], dtype=float)[skip]

        infra = sum(col(f"wall_s_{k}") for k in ("migrate", "halo", "neighbours"))
        # the whole step by the step loop's clock, the mean over the steps after the
        # first (with fluid.preconditioner_reuse = k only one step in k pays the AMG
        # set-up, and the amortised cost is what a run takes), the median beside
        fig = step_figures(stats)
        s_step = fig["s_per_step_mean"]
        n = summary["particles"]
        metrics = {"steps": fig["steps"], "startup_s": fig["startup_s"],
                   "s_per_step_median": fig["s_per_step_median"],
                   "peak_rss_mib_max": max(summary["peak_rss_mib"]),
                   "bytes_per_particle_peak_rss": summary["bytes_per_particle_peak_rss"],
                   "ppe_iterations": float(np.median(col("ppe_iterations"))),
                   "visc_iterations": float(np.median(col("visc_iterations"))),
                   "ppe_setups_per_step": float(np.mean(col("ppe_setup"))),
                   "s_per_step": s_step,
                   "s_per_step_assembly": float(np.mean(col("wall_s_fluid_assembly"))),
                   "s_per_step_solve": float(np.mean(col("wall_s_fluid_solve"))),
                   "s_per_step_fluid_halo": float(np.mean(col("wall_s_fluid_halo"))),
                   "s_per_step_infrastructure": float(np.mean(infra)),
                   "particle_steps_per_s_per_core": n / s_step / comm.size}
        name = "iisph_dam_break" + "".join(f"[{item}]" for item in args.set)
        record(args.csv, name, "parsph", summary["dim"], n, comm.size, metrics)


if __name__ == "__main__":
    main()
