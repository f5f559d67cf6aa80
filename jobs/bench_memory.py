"""Benchmark: memory and speed of a 3D coupled step, bytes per particle and where they go.

A 3D coupled scene (a water column beside a Drucker-Prager block with phase change, on a
floor three particles thick: both phases, the strong coupling and both PETSc systems
from the first step) is built at the particle size that gives about ``--particles``
particles and stepped ``--steps`` times under ``mpirun -n R``, after an untimed warm-up
at a small size (numba kernels, PETSc, hypre loaded). Printed (long CSV format of
``jobs/benchlib.py``): bytes per particle from peak RSS (the rise of every rank's peak
resident set over the run, summed over ranks, over the particles: PETSc and hypre
included), the largest peak RSS of a rank, the estimate of ``parsph check`` for the
same scene, and the resident-set growth inside each PETSc system's assembly (the
matrix PETSc keeps) and solve (hypre's copy and its AMG hierarchy), summed over the
steps and ranks, per particle: the growth between those calls is the rest (particle
fields, neighbour lists, the CSR work arrays). And the speed: seconds per step (median
of the steps after the first, infrastructure included) and particle-steps per second
per core. Issue goals: <= 2 KB per particle at >= 1e6 particles, the largest scene a
24 GB machine can step; >= 3e5 particle-steps/s per core, 1 -> 2 ranks >= 1.8x.

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
from benchlib import record, run_benchmark, worker_line  # noqa: E402

#: the tank: x in [0, 1] m, the slab y in [0, Y], z up; every span a whole number of d
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
eps_p_limit = 0.5
fluid = "debris"
[materials.water]
model = "newtonian"
density = 1000.0
viscosity = 1.0e-3
[materials.debris]
model = "bingham"
density = 1800.0
viscosity = 1.0e-3
viscosity_max = 1.0e4
cohesion = 10.0
friction_angle = 19.5
[materials.soil]
model = "drucker_prager"
density = 1800.0
young_modulus = 1.0e6
poisson_ratio = 0.3
friction_angle = 19.5
cohesion = 1.0e3
dilatancy_angle = 0.0
hardening = -0.1e3
residual_cohesion = 0.0
[[bodies]]
name = "water"
material = "water"
shape = "box"
lo = [0.0, 0.0, 0.0]
hi = [0.4, {y!r}, 0.4]
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

def scene(particles: float, width: float = 0.25) -> tuple[str, float]:
    """The tank's TOML with about ``particles`` particles, and its particle size."""
    # water 0.16 w + block 0.15 w + the floor 3 d (1 + 6 d)(w + 3 d), over d^3: solve
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
                        dlo=-4 * d, dhix=1.0 + 4 * d, dhiy=y + 4 * d), d


def worker(args):
    """One run under mpirun: rank 0 prints 'MEMORY {json}'."""
    import resource

    import solvers.operator as operator
    import solvers.system as system
    from decomposition import world
    from decomposition.reduce import global_max, global_sum
    from parsph.scene.budget import estimate
    from parsph.step.pipeline import plan
    from parsph.scene.loader import load_scene

    comm = world()
    warm, _ = scene(5e3)
    run_benchmark(comm, warm, ["run.max_steps=2"])

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
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    summary, stats = run_benchmark(comm, text, [f"run.max_steps={args.steps}", *args.set])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    rise = global_sum(comm, peak - base)
    peak_max = global_max(comm, peak)
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
    out = {"particles": n, "particle_size": d, "bytes_per_particle_rss": rise / n,
           "peak_rss_mib_per_rank": peak_max / 2.0 ** 20,
           "bytes_per_particle_fields": summary["bytes_per_particle"],
           "bytes_per_particle_estimate": est["bytes_per_particle"]}
    out.update({f"bytes_per_particle_{k}": v / n for k, v in parts.items()})
    # speed: the median step after the first (its set-ups), infrastructure included
    import numpy as np

    walls = ("wall_s_coupled", "wall_s_migrate", "wall_s_halo", "wall_s_neighbours")
    per_step = np.median(sum(np.asarray(stats[c], float) for c in walls)[1:])
    out.update({"s_per_step": per_step, "fluid_fraction": float(np.mean(stats["n_fluid"])) / n,
                "particle_steps_per_s_per_core": n / per_step / comm.size})
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=float, nargs="+", default=[1e5],
                    help="about this many particles (one run each)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1])
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--csv", default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene setting, e.g. fluid.viscous_operator=assembled")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        args.particles = args.particles[0]
        return worker(args)
    for ranks in args.ranks:
        for particles in args.particles:
            res = run_worker(ranks, particles, args.steps, args.set)
            n = res.pop("particles")
            record(args.csv, "memory_coupled_3d", "parsph", 3, n, ranks, res)


if __name__ == "__main__":
    main()
