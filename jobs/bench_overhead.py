"""Benchmark: the fixed cost of a coupled step (Python, collectives, set-up) and its cost
per particle.

A 2D coupled scene (a water column beside an elastic block in a tank: both phases and the
strong coupling from the first step, walls three particles thick) is run at several
particle sizes under
``mpirun -n R``. At each size two runs of K1 and K2 steps (after an untimed warm-up that
loads the numba kernels and PETSc) give the seconds per step from the difference of
their wall times, so the scene's build and the first step's set-up cancel; the pair is
run ``--repeats`` times and the least per-step time kept (a shared VM's noise only ever
adds time: with one pair of 10 and 60 steps the fitted fixed cost ranged over 0.5-2.9 ms
in three calls). A least-squares
line through (particles, s/step) gives the **fixed cost per step** (its intercept) and the
cost per particle-step (its slope); the seconds per step at the size nearest 1,000
particles are printed too. Issue goal: fixed cost <= 1 ms for a 2D coupled scene of
about 1,000 particles.

    .venv/bin/python jobs/bench_overhead.py
    .venv/bin/python jobs/bench_overhead.py --ranks 1 2 --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record, run_benchmark, worker_line  # noqa: E402

#: the tank; every span is a whole number of particles at the default sizes
SCENE = """
[scene]
name = "overhead_tank"
[domain]
dim = 2
particle_size = {d}
lo = [{lo}, {lo}]
hi = [{hix}, 1.0]
[run]
end_time = 1.0e9
[output]
every = 1.0e9
progress = false
[gravity]
g = [0.0, -9.81]
[materials.water]
model = "newtonian"
density = 1000.0
viscosity = 1.0e-3
[materials.block]
model = "hencky"
density = 1800.0
young_modulus = 1.0e6
poisson_ratio = 0.3
[[bodies]]
name = "water"
material = "water"
shape = "box"
lo = [0.0, 0.0]
hi = [0.4, 0.4]
[[bodies]]
name = "block"
material = "block"
shape = "box"
lo = [0.7, 0.0]
hi = [1.0, 0.2]
[[walls]]
name = "floor"
shape = "box"
lo = [{lo}, {lo}]
hi = [{hix}, 0.0]
[[walls]]
name = "left"
shape = "box"
lo = [{lo}, 0.0]
hi = [0.0, 0.8]
[[walls]]
name = "right"
shape = "box"
lo = [1.0, 0.0]
hi = [{hix}, 0.8]
"""
#: particle sizes d (m): about 260, 680, 960, 2,000 and 3,000 particles
SIZES = (0.05, 0.025, 0.02, 0.0125, 0.01)


def scene(d):
    """The tank's TOML at particle size ``d`` (walls 3 d thick)."""
    return SCENE.format(d=d, lo=-3 * d, hix=1.0 + 3 * d)


def worker(args):
    """One size under mpirun: rank 0 prints 'OVERHEAD {json}'."""
    from decomposition import world

    comm = world()
    text = scene(args.size)
    run_benchmark(comm, text, ["run.max_steps=2"])  # warm-up
    per_step = float("inf")
    for _ in range(args.repeats):
        walls = []
        for k in (args.k1, args.k2):
            comm.Barrier()
            t0 = time.perf_counter()
            summary, _ = run_benchmark(comm, text, [f"run.max_steps={k}"])
            comm.Barrier()
            walls.append(time.perf_counter() - t0)
        per_step = min(per_step, (walls[1] - walls[0]) / (args.k2 - args.k1))
    if comm.rank == 0:
        print("OVERHEAD " + json.dumps(dict(particles=int(summary["particles"]),
                                             s_per_step=per_step)), flush=True)


def run_worker(ranks, size, k1, k2, repeats):
    cmd = ["mpirun", "-n", str(ranks), sys.executable, os.path.abspath(__file__), "--worker",
           "--size", repr(size), "--k1", str(k1), "--k2", str(k2), "--repeats", str(repeats)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode:
        sys.exit(f"overhead worker failed ({out.returncode}): {' '.join(cmd)}\n"
                 f"{out.stdout[-2000:]}\n{out.stderr[-3000:]}")
    return json.loads(worker_line(out.stdout, "OVERHEAD ", f"overhead worker ({' '.join(cmd)})"))


def fit(points):
    """Least-squares line s = a + b n through (n, s): returns (a, b)."""
    import numpy as np

    n, s = np.asarray(points, dtype=float).T
    b, a = np.polyfit(n, s, 1)
    return float(a), float(b)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ranks", type=int, nargs="+", default=[1])
    ap.add_argument("--sizes", type=float, nargs="+", default=list(SIZES))
    ap.add_argument("--k1", type=int, default=10, help="steps of the shorter run")
    ap.add_argument("--k2", type=int, default=160, help="steps of the longer run")
    ap.add_argument("--repeats", type=int, default=3,
                    help="pairs of runs per size; the least per-step time is kept")
    ap.add_argument("--csv", default=None)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--size", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args)
    if len(args.sizes) < 2 or args.k2 <= args.k1 or args.repeats < 1:
        sys.exit("bench_overhead: need two or more --sizes, --k2 > --k1 and --repeats >= 1")
    for ranks in args.ranks:
        points = []
        for size in args.sizes:
            res = run_worker(ranks, size, args.k1, args.k2, args.repeats)
            points.append((res["particles"], res["s_per_step"]))
            record(args.csv, "overhead", "parsph", 2, res["particles"], ranks,
                   {"s_per_step": res["s_per_step"], "particle_size": size})
        a, b = fit(points)
        n1k, s1k = min(points, key=lambda p: abs(p[0] - 1000))
        record(args.csv, "overhead_fit", "parsph", 2, n1k, ranks,
               {"fixed_ms_per_step": 1e3 * a, "us_per_particle_step": 1e6 * b,
                "ms_per_step_near_1000": 1e3 * s1k})


if __name__ == "__main__":
    main()
