"""Benchmark: memory and speed of a 3D coupled step, bytes per particle and where they go.

The scene (``SCENE``) is a 3D tank on a floor three particles thick: a water column
resting against a weak Drucker-Prager block, touching it (no gap: the column's last
lattice plane and the block's first are one particle size apart), so from the first step
the column slumps, presses on the block and the strong coupling acts on the block's face
(``n_coupled`` > 0). The block (cohesion 10 Pa, softening, ``phase_change.eps_p_limit =
1e-5``: the trigger low so that a run of a few steps sees it) yields under its own weight
and the water's push and fluidises from the second step on into Bingham debris
(``viscosity_max`` 1e4 m^2/s); from the step after, the fluid's viscous step is implicit
and its PETSc system is solved every step (``visc_iterations`` > 0; the water alone is
explicit). A smoke run at 20,898 particles fluidised 138, 651, 1,068 and 1,634 of the
8,100 soil rows by steps 2, 3, 4 and 5. So the timed steps hold every part of the
coupled step: both phases, the coupling, the PPE and the viscous solve, phase change and
the solid view's rebuild (which makes the steps uneven: hence the mean).

The scene is built at the particle size that gives about ``--particles`` particles and
stepped ``--steps`` times under ``mpirun -n R``, after an untimed warm-up at a small size
in the same process (four steps, phase change and the implicit viscous solve among them:
numba kernels, PETSc, hypre loaded). Printed (long CSV format of
``jobs/benchlib.py``), per run:

- **speed as a user waits for it**: the step loop's clock (``stats.csv`` ``elapsed_s``,
  :func:`benchlib.step_times`), so every step's AMG set-ups, migrations, halo, neighbour
  lists, checks, statistics and output are in. The first row's ``elapsed_s`` holds the
  run's set-up (particle build, first lists) and its first step and is printed apart as
  ``startup_s``; ``s_per_step`` is the **mean** over the ``--steps - 1`` steps after it
  (so ``--steps`` >= 2), ``s_per_step_median`` beside it, and each stage's mean seconds
  per step beside (``s_per_step_<stage>``; their sum is less than the step).
  ``particle_steps_per_s_per_core`` is particles / ``s_per_step`` / ranks (walls
  included), ``moving_particle_steps_per_s_per_core`` the same with the soil and fluid
  rows only (walls apart);
- **the physics that acted**: ``n_fluidised`` (soil rows fluidised by the end),
  ``n_coupled_mean`` (solid rows in the fluid's systems per step), ``visc_iterations_mean``,
  ``ppe_iterations_mean``, ``fluid_fraction`` (means over the steps after the first);
- **memory**: ``bytes_per_particle_peak_rss``, the whole process's peak RSS (``VmHWM``:
  interpreter, numba, MPI, PETSc, hypre, particle fields) of every rank during the
  measured run (the peak reset after the warm-up, :func:`benchlib.reset_peak_rss`;
  ``peak_rss_since_start = 1`` says the reset failed and the peak is the process's
  lifetime one), summed over ranks, over all particles (walls included);
  ``peak_rss_mib_per_rank`` the largest rank's and ``peak_rss_mib_rank<r>`` each rank's;
  the estimate of ``parsph check`` for the same scene; and the resident-set growth inside
  each PETSc system's assembly (the matrix PETSc keeps) and solve (hypre's copy and its
  AMG hierarchy), summed over the steps and ranks, per particle (the rest is particle
  fields, neighbour lists, CSR work arrays and the process itself).

With ``--ranks 1 2`` at the same ``--particles``, a row ``memory_coupled_3d_scaling`` gives
``speedup_1_to_2`` (mean s/step on 1 rank over that on 2). Issue goals: <= 2 KB per
particle at >= 1e6 particles, the largest scene a 24 GB machine can step; >= 3e5
particle-steps/s per core, 1 -> 2 ranks >= 1.8x.

    .venv/bin/python jobs/bench_memory.py --particles 1e5
    .venv/bin/python jobs/bench_memory.py --particles 1e6 --ranks 2 --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import (  # noqa: E402
    FLUIDS, bytes_per_particle, peak_rss_mib, record, reset_peak_rss, run_benchmark,
    step_figures, step_times, worker_line)

#: the tank: x in [0, 1] m, the slab y in [0, Y], z up; every span a whole number of d.
#: The debris column (x 0.1-0.5, 0.4 high) rests against the block (x 0.5-1.0, 0.3 high):
#: lattice points sit at cell centres, so the two faces are one d apart (touching).
SCENE = """
[scene]
name = "memory_tank_3d"
[domain]
dim = 3
particle_size = {d!r}
lo = [{dlo!r}, {dlo!r}, {dlo!r}]
hi = [{dhix!r}, {dhiy!r}, 0.8]
[run]
end_time = 1.0e9
[output]
every = 1.0e9
progress = false
[gravity]
g = [0.0, 0.0, -9.81]
[phase_change]
eps_p_limit = {eps_p_limit!r}
fluid = "debris"
{fluids}[materials.soil]
model = "drucker_prager"
density = 1800.0
young_modulus = 1.0e6
poisson_ratio = 0.3
friction_angle = 19.5
cohesion = {cohesion!r}
dilatancy_angle = 0.0
hardening = -0.1e3
residual_cohesion = 0.0
[[bodies]]
name = "water"
material = "water"
shape = "box"
lo = [0.1, 0.0, 0.0]
hi = [0.5, {y!r}, 0.4]
[[bodies]]
name = "block"
material = "soil"
shape = "box"
lo = [0.5, 0.0, 0.0]
hi = [1.0, {y!r}, 0.3]
[[walls]]
name = "floor"
shape = "box"
lo = [{lo!r}, {lo!r}, {lo!r}]
hi = [{hix!r}, {hiy!r}, 0.0]
"""
#: the block's cohesion (Pa) and the plastic strain past which it fluidises: weak, so it
#: yields and fluidises within the first steps (a benchmark of a few steps times them)
COHESION = 10.0
EPS_P_LIMIT = 1.0e-5


def scene(particles: float, width: float = 0.25) -> tuple[str, float]:
    """The tank's TOML with about ``particles`` particles, and its particle size."""
    # column 0.16 w + block 0.15 w + the floor 3 d (1 + 6 d)(w + 3 d), over d^3: solve
    # for d by bisection
    def count(d):
        return (0.31 * width + 3 * d * (1.0 + 6 * d) * (width + 3 * d)) / d ** 3

    lo, hi = 1e-4, 0.2
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if count(mid) > particles else (lo, mid)
    # a whole number of particles across every span (the slab's width: as near
    # ``width`` as the lattice allows)
    d = 0.1 / max(1, round(0.1 / lo))
    y = d * max(1, round(width / d))
    # the domain a particle beyond the floor (no lattice point on its bounds by round-off)
    return SCENE.format(d=d, lo=-3 * d, hix=1.0 + 3 * d, hiy=y + 3 * d, y=y,
                        dlo=-4 * d, dhix=1.0 + 4 * d, dhiy=y + 4 * d,
                        cohesion=COHESION, eps_p_limit=EPS_P_LIMIT, fluids=FLUIDS), d


#: stages timed in stats.csv (their mean s/step printed beside the whole step's)
STAGES = ("solid", "fluid_assembly", "visc_solve", "ppe_solve", "fluid_halo", "phase_change",
          "migrate", "halo", "neighbours", "output")


def worker(args):
    """One run under mpirun: rank 0 prints 'MEMORY {json}'."""
    import numpy as np

    import solvers.operator as operator
    import solvers.system as system
    from decomposition import world
    from decomposition.reduce import allgather, barrier, global_sum
    from parsph.scene.budget import estimate
    from parsph.step.pipeline import plan
    from parsph.scene.loader import load_scene

    comm = world()
    warm, _ = scene(5e3)  # (its block fluidises at step 2, the viscous solve from step 3)
    run_benchmark(comm, warm, ["run.max_steps=4"])

    def rss():
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")

    growth = {}
    depth = [0]  # calls inside a measured call count in it, not again on their own

    def measured(cls, name, part):
        fn = getattr(cls, name)

        def wrapper(self, *a, **k):
            before = rss()
            depth[0] += 1
            try:
                return fn(self, *a, **k)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    key = f"{self.prefix.rstrip('_')}_{part}"
                    growth[key] = growth.get(key, 0) + max(0, rss() - before)
        setattr(cls, name, wrapper)

    measured(system.LinearSystem, "assemble_csr", "matrix")
    measured(system.LinearSystem, "assemble_csr_over", "matrix")  # the PPE, no copy
    measured(system.LinearSystem, "solve", "solve")
    # the matrix-free viscous system: its scalar matrix with the AMG set-up on it
    measured(operator.OperatorSystem, "assemble_preconditioner", "matrix")
    text, d = scene(args.particles)
    exact = reset_peak_rss()  # the warm-up's peak is not the measured run's
    barrier(comm)
    summary, stats = run_benchmark(comm, text, [f"run.max_steps={args.steps}", *args.set])
    peaks = allgather(comm, peak_rss_mib())
    exact = all(allgather(comm, exact))
    parts = {k: global_sum(comm, v) for k, v in sorted(growth.items())}
    if comm.rank != 0:
        return
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:  # the estimate `parsph check` prints
        path = os.path.join(tmp, "scene.toml")
        with open(path, "w") as fh:
            fh.write(text)
        sc = load_scene(path)
        est = estimate(comm, sc, plan(sc))
    n = summary["particles"]

    def col(name):
        return np.asarray(stats[name], dtype=float) if name in stats else None

    # speed: the whole step by the step loop's clock, the mean of the steps after the
    # first (its row holds the run's set-up: startup_s), the median beside
    fig = step_figures(stats)
    out = {"particles": n, "particle_size": d, "steps": fig["steps"],
           "startup_s": fig["startup_s"], "s_per_step": fig["s_per_step_mean"],
           "s_per_step_median": fig["s_per_step_median"]}
    later = slice(1, None)
    _, per_step = step_times(stats)  # the steps after the first
    wall = float(per_step.sum())
    moving = col("n_solid") + col("n_fluid")
    out["particle_steps_per_s_per_core"] = n * per_step.size / wall / comm.size \
        if wall > 0 else float("nan")
    out["moving_particle_steps_per_s_per_core"] = float(moving[later].sum()) / wall / comm.size \
        if wall > 0 else float("nan")
    for k in STAGES:
        c = col(f"wall_s_{k}")
        if c is not None and len(c) > 1:
            out[f"s_per_step_{k}"] = float(c[later].mean())
    # the physics that acted in the timed steps (the steps after the first)
    out["fluid_fraction"] = float(np.mean(col("n_fluid")[later])) / n
    out["solid_fraction_end"] = float(col("n_solid")[-1]) / n
    for k in ("n_fluidised", "n_failed"):
        if k in stats:
            out[k] = int(col(k)[-1])
    for k in ("n_coupled", "visc_iterations", "ppe_iterations"):
        if k in stats and per_step.size:
            out[f"{k}_mean"] = float(np.nanmean(col(k)[later]))
    # memory: the whole process's peak RSS of every rank over all particles
    out["bytes_per_particle_peak_rss"] = bytes_per_particle(peaks, n)
    out["peak_rss_mib_per_rank"] = max(peaks)
    out.update({f"peak_rss_mib_rank{r}": m for r, m in enumerate(peaks)})
    out["peak_rss_since_start"] = int(not exact)
    out["bytes_per_particle_fields"] = summary["bytes_per_particle"]
    out["bytes_per_particle_estimate"] = est["bytes_per_particle"]
    out.update({f"bytes_per_particle_{k}": v / n for k, v in parts.items()})
    print("MEMORY " + json.dumps(out), flush=True)


def run_worker(ranks, particles, steps, settings=()):
    cmd = ["mpirun", "-n", str(ranks), sys.executable, os.path.abspath(__file__), "--worker",
           "--particles", repr(particles), "--steps", str(steps),
           *(f"--set={s}" for s in settings)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode:
        sys.exit(f"memory worker failed ({out.returncode}): {' '.join(cmd)}\n"
                 f"{out.stdout[-2000:]}\n{out.stderr[-3000:]}")
    return json.loads(worker_line(out.stdout, "MEMORY ", f"memory worker ({' '.join(cmd)})"))


def write_record(runs, args) -> None:
    """The figures record ``bench_memory`` (``jobs/figures.py``; written where
    ``$PARSPH_FIGURES`` says): the figures of the largest ``--particles`` run, each as
    ``KEY_rR`` for its rank count R, and ``speedup_1_to_2`` when both ran."""
    from figures import record as record_figures

    largest = max(args.particles)
    fig = {}
    for (ranks, particles), (n, res) in sorted(runs.items()):
        if particles == largest:
            fig["particles"] = n
            fig.update({f"{k}_r{ranks}": v for k, v in res.items()
                        if isinstance(v, (int, float))})
    if "s_per_step_r1" in fig and "s_per_step_r2" in fig:
        fig["speedup_1_to_2"] = fig["s_per_step_r1"] / fig["s_per_step_r2"]
    ranks = " ".join(str(r) for r in args.ranks)
    record_figures("bench_memory", fig, ranks=max(args.ranks), source="jobs/bench_memory.py",
                   command=f"python jobs/bench_memory.py --particles {int(largest)} --ranks "
                           f"{ranks} --steps {args.steps}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=float, nargs="+", default=[1e5],
                    help="about this many particles (one run each)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1])
    ap.add_argument("--steps", type=int, default=4,
                    help="steps per run, >= 2 (the first holds the run's set-up: startup_s; "
                    "s/step is the mean over the others)")
    ap.add_argument("--csv", default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene setting, e.g. fluid.viscous_operator=assembled")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        args.particles = args.particles[0]
        return worker(args)
    if args.steps < 2:
        sys.exit("bench_memory: --steps >= 2 (the first step's row holds the run's set-up)")
    runs = {}
    for ranks in args.ranks:
        for particles in args.particles:
            res = run_worker(ranks, particles, args.steps, args.set)
            n = res.pop("particles")
            runs[(ranks, particles)] = (n, res)
            record(args.csv, "memory_coupled_3d", "parsph", 3, n, ranks, res)
    for particles in args.particles:  # 1 -> 2 ranks: the mean s/step of each
        if (1, particles) in runs and (2, particles) in runs:
            n, one = runs[(1, particles)]
            two = runs[(2, particles)][1]
            record(args.csv, "memory_coupled_3d_scaling", "parsph", 3, n, 2,
                   {"speedup_1_to_2": one["s_per_step"] / two["s_per_step"]})
    write_record(runs, args)


if __name__ == "__main__":
    main()
