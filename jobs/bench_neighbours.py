"""Benchmark: neighbour search + density summation on a moving lattice (issue: foundation).

Runs the real step (migrate, halo, cell-list neighbours, density summation eq. 33, kinematic
move) on a periodic block of particles and prints its figures in the long CSV format of
``jobs/benchlib.py``: particle-steps per second per core, neighbours per particle, bytes
per particle (and, with ``--breakdown``, seconds per step by stage).

    mpirun -n 2 .venv/bin/python jobs/bench_neighbours.py --dim 3 --particles 1e5 --steps 10
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from decomposition import world

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record, run_benchmark  # noqa: E402

SCENE = """
[scene]
name = "bench_neighbours"
[domain]
dim = {dim}
particle_size = {d}
lo = {lo}
hi = {hi}
periodic = {periodic}
[run]
end_time = 1.0e9
mode = "kinematic"
dt = {dt}
max_steps = {steps}
rebalance_tolerance = 1.5
[output]
every = 1.0e9
progress = false
[materials.m]
model = "kinematic"
density = 1000.0
[[bodies]]
name = "block"
material = "m"
shape = "box"
lo = {lo}
hi = {hi}
velocity = {vel}
"""

def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dim", type=int, default=3)
    ap.add_argument("--particles", type=float, default=1e5)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--csv", default=None, help="append the figures to this CSV (jobs/benchlib.py)")
    ap.add_argument("--breakdown", action="store_true", help="also seconds per step by stage")
    args = ap.parse_args()
    comm = world()
    dim = args.dim
    n_side = int(round(args.particles ** (1.0 / dim)))
    d = 1.0 / n_side
    lo = [0.0] * dim
    hi = [1.0] * dim
    vel = [0.3 * d] + [0.0] * (dim - 1)  # slow drift: particles cross the rank boundary
    text = SCENE.format(dim=dim, d=d, lo=lo, hi=hi, periodic=str([True] * dim).lower(),
                        dt=1.0, steps=args.steps, vel=vel)
    summary, stats = run_benchmark(comm, text)
    if comm.rank == 0:
        parts = [k for k in stats if k.startswith("wall_s_") and k != "wall_s_output"]
        per_step = np.sum([stats[k] for k in parts], axis=0)[1:]  # step 1 excluded (warm-up)
        s_step = float(np.median(per_step))
        n = summary["particles"]
        metrics = {"s_per_step": s_step,
                   "particle_steps_per_s_per_core": n / s_step / comm.size,
                   "neighbours_per_particle": summary["neighbours_per_particle"],
                   "bytes_per_particle": summary["bytes_per_particle"]}
        if args.breakdown:
            metrics.update({f"s_per_step_{k[7:]}": float(np.median(stats[k][1:])) for k in parts})
        record(args.csv, "neighbours+density", "parsph", dim, n, comm.size, metrics)


if __name__ == "__main__":
    main()
