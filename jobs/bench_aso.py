"""Benchmark: the Aso landslide to rest, its cost by stage before, during and after the slide.

Runs the built-in ``aso`` scene (or ``--scene``) at ``--d`` metres on the ranks it is
started on, from the geostatic stage to rest (the scene's ``run.rest_fraction``, else its
end time), and prints in the long CSV format of ``jobs/benchlib.py``:

- the wall time of the whole run (the process's: start-up, geostatic stage, steps,
  output), the start-up's (set-up, geostatic stage, first step) and the simulated time
  it reached;
- seconds per step of the step loop's clock (``stats.csv`` ``elapsed_s``: everything a
  step costs, output and checks included), mean and median, in three phases: *before*
  the kinetic energy first passes 1 % of its peak, *during* (up to the last step above
  it: the shaking and the slide) and *after* (the deposit coming to rest); with the
  stages' shares (the solid, the fluid, the phase change, migration, halo, neighbour
  lists, output) and the mean number of fluid rows;
- moving particles (soil + fluid) x steps per second per core in each phase;
- the whole process's peak RSS of every rank (MiB) and bytes per particle;
- the projected wall time at ``--project`` metres (the paper's 3 m) on ``--cores`` cores:
  particles x d^-3, steps x d^-1 (the CFL step, eq. (49), is proportional to d), the
  cost per moving particle-step of each phase as measured here, and a parallel efficiency
  ``--efficiency`` from here to there (an assumption, printed).

A run stopped by a signal (SIGTERM, SIGUSR1: a batch system's time limit; it writes its
checkpoint) still reports what it measured, with ``stopped_by_signal`` = 1.

    mpirun -n 2 .venv/bin/python jobs/bench_aso.py --d 8 --out out/aso_d8
    mpirun -n 2 .venv/bin/python jobs/bench_aso.py --d 4 --out out/aso_d4 --csv out/bench/aso.csv
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from decomposition import world
from decomposition.reduce import allgather

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import bytes_per_particle, peak_rss_mib, record, step_times  # noqa: E402

PARTS = {"solid": ("wall_s_solid",), "fluid": ("wall_s_fluid",),
         "phase_change": ("wall_s_phase_change",),
         "infrastructure": ("wall_s_migrate", "wall_s_halo", "wall_s_neighbours"),
         "output": ("wall_s_output",)}


def phases(stats) -> dict:
    """Masks of the steps before, during and after the slide (module docstring): the
    slide is the stretch from the first to the last step whose kinetic energy is above 1 %
    of its peak (the shaking and the flow it sets off)."""
    ke = np.asarray(stats["kinetic_energy"], float)
    idx = np.arange(len(ke))
    above = np.flatnonzero(ke > 1e-2 * ke.max()) if ke.max() > 0.0 else np.array([0])
    first, last = int(above[0]), int(above[-1])
    return {"before": idx < first, "during": (idx >= first) & (idx <= last),
            "after": idx > last}


def figures(stats, comm_size: int, wall_s: float, particles_moving) -> dict:
    """The per-phase figures of one run's ``stats.csv`` (rank 0)."""
    startup, per_step = step_times(stats)
    # the first row's time includes the set-up: not a step's
    step_s = np.concatenate([[np.nan], per_step])
    moving = np.asarray(particles_moving, float)
    out = {"steps": len(step_s), "t_end_s": float(stats["time"][-1]), "wall_s": wall_s,
           "n_fluidised": int(float(stats["n_fluidised"][-1])),
           # set-up, the geostatic stage and the first step
           "startup_s": startup}
    for name, mask in phases(stats).items():
        mask = mask & np.isfinite(step_s)
        out[f"{name}_steps"] = int(mask.sum())
        if not mask.any():
            continue
        s = step_s[mask]
        out[f"{name}_s_per_step_mean"] = float(s.mean())
        out[f"{name}_s_per_step_median"] = float(np.median(s))
        out[f"{name}_wall_s"] = float(s.sum())
        for part, cols in PARTS.items():
            if all(c in stats for c in cols):
                share = sum(np.asarray(stats[c], float)[mask] for c in cols).sum() / s.sum()
                out[f"{name}_share_{part}"] = float(share)
        out[f"{name}_moving_particle_steps_per_s_per_core"] = float(
            moving[mask].sum() / s.sum() / comm_size)
        out[f"{name}_fluid_rows_mean"] = float(np.asarray(stats["n_fluid"], float)[mask].mean())
    return out


def project(fig, d: float, to: float, cores: int, ranks: int, efficiency: float) -> dict:
    """The projected wall time at ``to`` metres on ``cores`` cores (module docstring)."""
    scale = (d / to) ** 4  # particles x d^-3, steps x d^-1
    total = fig["startup_s"] * scale  # (the geostatic stage is a solid's steps too)
    for name in ("before", "during", "after"):
        total += fig.get(f"{name}_wall_s", 0.0) * scale
    return {"projected_d_m": to, "projected_cores": cores,
            "projected_efficiency": efficiency,
            "projected_wall_h": total * ranks / cores / efficiency / 3600.0}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="aso")
    ap.add_argument("--d", type=float, default=8.0, help="particle size (m)")
    ap.add_argument("--out", default=None, help="keep the run here (default: a scratch "
                    "directory, removed)")
    ap.add_argument("--set", action="append", default=[], help="extra scene overrides")
    ap.add_argument("--csv", default=None, help="append the rows to this CSV file")
    ap.add_argument("--project", type=float, default=3.0, help="project to this d (m)")
    ap.add_argument("--cores", type=int, default=256, help="... on this many cores")
    ap.add_argument("--efficiency", type=float, default=0.7,
                    help="assumed parallel efficiency from this run's cores to --cores")
    args, petsc_args = ap.parse_known_args()
    petsc_args = [a for a in petsc_args if a != "--"]
    import shutil
    import tempfile

    from decomposition.reduce import broadcast
    from parsph.errors import Preempted
    from parsph.io import read_stats
    from parsph.scene.loader import load_scene
    from parsph.step.run import run

    comm = world()
    t0 = time.perf_counter()
    out = args.out or broadcast(comm, tempfile.mkdtemp(prefix="parsph-bench-")
                                if comm.rank == 0 else None)
    scene = load_scene(args.scene, [f"domain.particle_size={args.d}", "output.progress=false",
                                    *args.set])
    try:
        summary = run(scene, out, comm=comm, petsc_args=petsc_args, progress=False)
        stopped = 0
    except Preempted:  # stopped by a signal (a batch system's limit): report what ran
        summary, stopped = None, 1
    wall = time.perf_counter() - t0
    rss = allgather(comm, peak_rss_mib())
    if comm.rank != 0:
        return
    stats = read_stats(os.path.join(out, "stats.csv"))
    moving = np.asarray(stats["n_solid"], float) + np.asarray(stats["n_fluid"], float)
    fig = figures(stats, comm.size, wall, moving)
    fig["stopped_by_signal"] = stopped
    if summary is None:
        summary = {"dim": scene.domain.dim, "particles": int(stats["n_particles"][-1])}
    fig.update({f"peak_rss_mib_rank{r}": float(m) for r, m in enumerate(rss)})
    fig["bytes_per_particle"] = bytes_per_particle(rss, summary["particles"])
    fig.update(project(fig, args.d, args.project, args.cores, comm.size, args.efficiency))
    record(args.csv, f"aso_d{args.d:g}", "parsph", summary["dim"], summary["particles"],
           comm.size, fig)
    if not args.out:
        shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
