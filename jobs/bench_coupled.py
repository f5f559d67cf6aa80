"""Benchmark: the coupled slope failure (TLSPH + IISPH + phase change), time by stage.

Runs the built-in ``slope_failure`` scene (or ``--scene``) to ``--end-time``, after an
untimed warm-up in the same process (a small tank of the same dimension whose weak soil
fluidises in its first steps: the solid, fluid, coupling and phase-change kernels loaded,
PETSc and hypre set up; ``--no-warmup`` to skip it), and times every step as a user
waits for it: by the step loop's clock (``stats.csv`` ``elapsed_s``, wall seconds since
the run began, written after every step; ``benchlib.step_times``), so each step's AMG
set-ups, migrations, halo, neighbour lists, checks, statistics and output are in. The
first row holds the run's set-up (particle build, first lists) and its first step,
printed apart as ``startup_s``; every figure per step is the **mean** over the steps
after it, the median printed beside (``*_median``), never instead. Printed, in the long
CSV format of ``jobs/benchlib.py``:

- ``s_per_step``: the mean over every step after the first (the run as a user waits for
  it), ``s_per_step_max`` and ``step_of_max`` (a one-off cost such as a kernel loaded
  late shows there);
- ``s_per_step_coupled``: the mean over the steps with fluid, and
  ``s_per_step_tlsph_only`` over those before the first phase change (none of the first
  row); beside the coupled one, each stage's mean seconds per step over the same steps
  (``s_per_step_<stage>``, from the stages' own timers: the TLSPH stage, the fluid
  assembly, the viscous and PPE KSP solves, the fluid stage's halo refreshes, the
  phase-change bookkeeping, and the infrastructure: migrate, current halo, neighbours;
  their sum is less than the step: the rest is the time step's choice, the checks, the
  statistics and output);
- particle-steps per second per core of the coupled step (from its mean), the mean PPE
  and viscous iterations, and the load balance over time (largest and smallest owned
  solid and fluid counts per rank, at the quarters of the run).

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
from benchlib import record, reset_peak_rss, run_benchmark, step_times  # noqa: E402

STAGES = ("solid", "fluid_assembly", "visc_solve", "ppe_solve", "fluid_halo", "phase_change")
INFRA = ("migrate", "halo", "neighbours")


def warm_up(comm, dim: int) -> None:
    """Collective, untimed: a few steps of a small coupled tank of dimension ``dim`` whose
    soil fluidises in its first steps (``jobs/bench_overhead.py``'s in 2D,
    ``jobs/bench_memory.py``'s in 3D): the kernels and solvers a coupled run needs,
    loaded before the measured run."""
    if dim == 2:
        import bench_overhead

        text = bench_overhead.scene(0.05)
    else:
        import bench_memory

        text, _ = bench_memory.scene(3e3)
    run_benchmark(comm, text, ["run.max_steps=6", "phase_change.eps_p_limit=1e-5"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="slope_failure")
    ap.add_argument("--end-time", type=float, default=1.0, help="simulated seconds")
    ap.add_argument("--set", action="append", default=[], help="extra scene overrides")
    ap.add_argument("--no-warmup", action="store_true",
                    help="no untimed warm-up run before the measured one")
    ap.add_argument("--csv", default=None, help="append the rows to this CSV file")
    args, petsc_args = ap.parse_known_args()
    petsc_args = [a for a in petsc_args if a != "--"]
    comm = world()
    overrides = [f"run.end_time={args.end_time}", f"output.every={args.end_time}",
                 "output.progress=false", *args.set]
    if not args.no_warmup:
        from parsph.scene.loader import load_scene

        warm_up(comm, load_scene(args.scene, overrides).domain.dim)
    reset_peak_rss()  # the peak of the measured run, not the warm-up's
    summary, stats = run_benchmark(comm, args.scene, overrides, petsc_args)
    if comm.rank != 0:
        return

    def col(name):
        return np.asarray(stats[name], dtype=float)

    startup, step_s = step_times(stats)  # step_s[i]: the step of row i + 1
    if step_s.size == 0:
        sys.exit("bench_coupled: the run made one step; give a longer --end-time")
    rows = slice(1, None)  # the rows of the steps timed
    n_fluid = col("n_fluid")[rows]
    infra = sum(col(f"wall_s_{k}") for k in INFRA)[rows]
    coupled = n_fluid > 0
    solid_only = n_fluid == 0
    n = summary["particles"]
    worst = int(np.argmax(step_s))
    metrics = {"steps": len(step_s) + 1, "steps_with_fluid": int(coupled.sum()),
               "n_fluidised": int(col("n_fluidised")[-1]),
               "wall_s": float(summary["wall_s"]), "startup_s": startup,
               "s_per_step": float(step_s.mean()), "s_per_step_median": float(np.median(step_s)),
               "s_per_step_max": float(step_s[worst]),
               "step_of_max": int(col("step")[rows][worst]),
               # every rank's whole process at its peak (the run's summary)
               "peak_rss_mib_max": max(summary["peak_rss_mib"]),
               "bytes_per_particle_peak_rss": summary["bytes_per_particle_peak_rss"]}
    if solid_only.any():
        metrics["s_per_step_tlsph_only"] = float(step_s[solid_only].mean())
        metrics["s_per_step_tlsph_only_median"] = float(np.median(step_s[solid_only]))
    if coupled.any():
        s_step = float(step_s[coupled].mean())
        metrics["s_per_step_coupled"] = s_step
        metrics["s_per_step_coupled_median"] = float(np.median(step_s[coupled]))
        for k in STAGES:
            metrics[f"s_per_step_{k}"] = float(col(f"wall_s_{k}")[rows][coupled].mean())
        metrics["s_per_step_infrastructure"] = float(infra[coupled].mean())
        metrics["particle_steps_per_s_per_core"] = n / s_step / comm.size
        metrics["ppe_iterations"] = float(np.nanmean(col("ppe_iterations")[rows][coupled]))
        metrics["visc_iterations"] = float(np.nanmean(col("visc_iterations")[rows][coupled]))
    total = len(stats["step"])
    for q in (1, 2, 3, 4):  # load balance as the landslide moves
        k = min(total - 1, q * total // 4)
        for phase in ("solid", "fluid"):
            lo, hi = col(f"n_{phase}_rank_min")[k], col(f"n_{phase}_rank_max")[k]
            metrics[f"{phase}_per_rank_t{q}_min"] = int(lo)
            metrics[f"{phase}_per_rank_t{q}_max"] = int(hi)
    record(args.csv, f"coupled_{args.scene}", "parsph", summary["dim"], n, comm.size, metrics)


if __name__ == "__main__":
    main()
