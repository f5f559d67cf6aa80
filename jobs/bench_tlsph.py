"""Benchmark: the TLSPH step on a 3D elastoplastic block under gravity (issue 3).

Runs the real stage (halo refreshes, eq. (13), JST eqs. (11)-(12), hourglass control,
eq. (14), Hencky + Drucker-Prager return, positions) on a block clamped at its base and
prints one CSV row: particle-steps per second per core, neighbours per particle, pair
interactions per second per core (reference pairs x steps / wall / cores), bytes per
particle. Compare the pair rate with LAMMPS-SMD TLSPH (issue 3: ~9e6 pair interactions/s
per core, not installed here). Run on 1 then 2 ranks for the speed-up:

    mpirun -n 1 .venv/bin/python jobs/bench_tlsph.py --particles 1e5 --steps 20
    mpirun -n 2 .venv/bin/python jobs/bench_tlsph.py --particles 1e5 --steps 20
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile

import numpy as np

from decomposition import world
from decomposition.reduce import broadcast
from parsph.io import read_stats
from parsph.run import run
from parsph.scene import load_scene

SCENE = """
[scene]
name = "bench_tlsph"
[domain]
dim = 3
particle_size = {d}
lo = [-0.1, -0.1, -0.1]
hi = [1.1, 1.1, 1.1]
[run]
end_time = 1.0e9
max_steps = {steps}
[output]
every = 1.0e9
progress = false
[materials.soil]
model = "drucker_prager"
density = 2000.0
poisson_ratio = 0.3
young_modulus = 1.0e7
friction_angle = 30.0
cohesion = 1.0e3
[[bodies]]
name = "block"
material = "soil"
shape = "box"
lo = [0.0, 0.0, 0.0]
hi = [1.0, 1.0, 1.0]
[[constraints]]
name = "base"
lo = [-0.1, -0.1, -0.1]
hi = [1.1, 1.1, {base}]
velocity = [0.0, 0.0, 0.0]
"""

COLUMNS = ["benchmark", "dim", "particles", "ranks", "steps", "s_per_step",
           "particle_steps_per_s_per_core", "neighbours_per_particle",
           "pair_interactions_per_s_per_core", "bytes_per_particle"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=float, default=1e5)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--csv", default=None, help="append the row to this CSV file")
    args = ap.parse_args()
    comm = world()
    n_side = int(round(args.particles ** (1.0 / 3.0)))
    d = 1.0 / n_side
    text = SCENE.format(d=d, steps=args.steps, base=1.5 * d)
    tmp = broadcast(comm, tempfile.mkdtemp(prefix="parsph-bench-") if comm.rank == 0 else None)
    path = os.path.join(tmp, "scene.toml")
    if comm.rank == 0:
        with open(path, "w") as fh:
            fh.write(text)
    comm.Barrier()
    summary = run(load_scene(path), os.path.join(tmp, "out"), comm=comm, progress=False)
    if comm.rank == 0:
        stats = read_stats(os.path.join(tmp, "out", "stats.csv"))
        per_step = np.asarray(stats["wall_s_tlsph"])[1:]  # step 1 excluded (warm-up)
        s_step = float(np.median(per_step))
        n = summary["particles"]
        nb = summary["neighbours_per_particle"]
        row = {"benchmark": "tlsph", "dim": 3, "particles": n, "ranks": comm.size,
               "steps": len(per_step), "s_per_step": f"{s_step:.4g}",
               "particle_steps_per_s_per_core": f"{n / s_step / comm.size:.4g}",
               "neighbours_per_particle": f"{nb:.1f}",
               "pair_interactions_per_s_per_core": f"{n * nb / s_step / comm.size:.4g}",
               "bytes_per_particle": f"{summary['bytes_per_particle']:.0f}"}
        writer = csv.DictWriter(sys.stdout, COLUMNS)
        writer.writerow(row)
        if args.csv:
            new = not os.path.exists(args.csv)
            with open(args.csv, "a", newline="") as fh:
                w = csv.DictWriter(fh, COLUMNS)
                if new:
                    w.writeheader()
                w.writerow(row)
        import shutil

        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
