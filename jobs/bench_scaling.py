"""Benchmark: strong and weak scaling of the TLSPH and IISPH steps, bytes per particle.

For each case, three runs of a scene under ``mpirun`` (``--repeats`` times
each, alternating; medians of the seconds per step):

- N particles on 1 rank (particle size d), the same N on 2 ranks (strong scaling), and
  about 2N on 2 ranks (particle size d / 2^(1/D): weak scaling, the particles per rank
  held constant);
- TLSPH: ``slope_failure_solid`` (Drucker-Prager soil on a rough floor, the demo scene:
  the wall contact adds a search of the walls near the soil every step) and
  ``elastic_plate`` (no walls, like the 3D block of ``bench_tlsph.py``), and a block
  filling a periodic box in 2D and 3D (halo rows on every rank, one rank included: the
  halo's fixed cost and cost per row, ``docs/scaling.md``); IISPH: ``dam_break`` (GMRES
  + BoomerAMG pressure and viscous solves).

Figures per run (long CSV format of ``jobs/benchlib.py``): seconds per step and
particle-steps/s per core (median over the steps after the first two), halo seconds per
step (the infrastructure halo plus every ``update_halo`` refresh inside the stage, timed by
wrapping it) and halo rows per rank (max over ranks), owned rows per rank (max), bytes per
particle from peak RSS (the rise of every rank's peak resident set during the run, after
an untimed warm-up run of the same scene that loads the numba kernels and PETSc, summed
over ranks and divided by N) next to the driver's own field accounting, and the peak RSS
per rank. On the 2-rank rows: ``strong_speedup`` = t(1 rank, N) / t(2 ranks, N);
``weak_efficiency`` = particle-steps/s per core at (2 ranks, 2N) over that at (1 rank, N),
which is t1 / t2 when the count exactly doubles (``weak_t1_over_t2`` is the raw ratio).

    .venv/bin/python jobs/bench_scaling.py --csv out/bench/bench.csv
    .venv/bin/python jobs/bench_scaling.py --cases tlsph --size tlsph=0.01 --steps 20
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record, run_benchmark, worker_line  # noqa: E402

#: A block filling a periodic box, Drucker-Prager soil drifting at 1 cm/s: every rank, even
#: a single one, has halo rows (the periodic images), so the halo's fixed cost per step and
#: its cost per row are measured without walls or boundaries.
PERIODIC_BLOCK = """
[scene]
name = "periodic_block"
[domain]
dim = {dim}
particle_size = {d}
lo = {lo}
hi = {hi}
periodic = {periodic}
[run]
end_time = 1.0e9
[output]
every = 1.0e9
[gravity]
g = {zero}
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
lo = {lo}
hi = {hi}
velocity = {vel}
"""


def periodic_block(dim):
    return PERIODIC_BLOCK.format(dim=dim, d=0.05, lo=[0.0] * dim, hi=[1.0] * dim,
                                 periodic=str([True] * dim).lower(), zero=[0.0] * dim,
                                 vel=[0.01] + [0.0] * (dim - 1))


#: case -> (built-in scene or TOML text, the stage whose seconds make a step with the
#: infrastructure, particle size d of the 1-rank run, dimension)
CASES = {
    # TLSPH with wall contact: 1.3e5 particles (88,011 soil, 41,400 floor and back wall)
    "tlsph": ("slope_failure_solid", "tlsph", 0.005, 2),
    # TLSPH without walls (the case of the 3D block of bench_tlsph.py): 1.2e5 particles
    "tlsph_plate": ("elastic_plate", "tlsph", 0.0002, 2),
    # TLSPH on periodic blocks: 99,856 (2D) and 97,336 (3D) particles
    "tlsph_periodic": (periodic_block(2), "tlsph", 1.0 / 316, 2),
    "tlsph_periodic_3d": (periodic_block(3), "tlsph", 1.0 / 46, 3),
    # IISPH: 7.5e4 particles (69,938 fluid)
    "iisph": ("dam_break", "iisph", 0.00078, 2),
}
INFRASTRUCTURE = ("migrate", "halo", "neighbours")
SKIP = 2  # steps excluded from the medians (JIT warm-up, first matrices)


def worker(args):
    """One run under mpirun: rank 0 prints 'SCALING {json}'."""
    import resource

    import numpy as np

    import parsph.core.context as prun
    from decomposition import world
    from decomposition.reduce import global_max, global_sum

    comm = world()
    scene, stage, _, _ = CASES[args.cases]
    quiet = ["output.progress=false"]
    run_benchmark(comm, scene, quiet + ["run.max_steps=2"])  # warm-up: kernels, PETSc

    halo_s, halo_rows = {}, [0]
    update_halo = prun.Context.update_halo

    def timed_update_halo(ctx, names):
        t0 = time.perf_counter()
        update_halo(ctx, names)
        halo_s[ctx.step] = halo_s.get(ctx.step, 0.0) + time.perf_counter() - t0
        halo_rows[0] = max(halo_rows[0], ctx.halo.n_halo)

    prun.Context.update_halo = timed_update_halo
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    summary, stats = run_benchmark(
        comm, scene, quiet + [f"domain.particle_size={args.particle_size!r}",
                              f"run.max_steps={args.steps}", "run.end_time=1e9",
                              "output.every=1e9"])
    prun.Context.update_halo = update_halo
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    rise = global_sum(comm, peak - base)
    peak_max = global_max(comm, peak)
    rows_max = global_max(comm, halo_rows[0])
    if comm.rank != 0:
        return
    n = summary["particles"]

    def col(name):
        return np.asarray(stats[name], dtype=float)[SKIP:]

    per_step = sum(col(f"wall_s_{k}") for k in INFRASTRUCTURE + (stage,))
    inner = [halo_s.get(s, 0.0) for s in range(SKIP, int(stats["step"][-1]))]
    halo = col("wall_s_halo") + np.asarray(inner[: len(per_step)]
                                           + [0.0] * (len(per_step) - len(inner)))
    out = {"particles": n, "s_per_step": float(np.median(per_step)),
           "s_per_step_halo": float(np.median(halo)),
           "halo_rows_per_rank": int(rows_max),
           "owned_per_rank": int(max(stats["n_owned_max"])),
           "neighbours_per_particle": summary["neighbours_per_particle"],
           "bytes_per_particle_rss": rise / n,
           "bytes_per_particle_fields": summary["bytes_per_particle"],
           "peak_rss_mib_per_rank": peak_max / 2.0 ** 20}
    if "ppe_iterations" in stats:
        out["ppe_iterations"] = float(np.median(col("ppe_iterations")))
    print("SCALING " + json.dumps(out), flush=True)


def run_worker(ranks, case, particle_size, steps):
    cmd = ["mpirun", "-n", str(ranks), sys.executable, os.path.abspath(__file__), "--worker",
           "--cases", case, "--particle-size", repr(particle_size), "--steps", str(steps)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        sys.stderr.write(out.stdout + out.stderr)
        raise SystemExit(f"benchmark run failed: {' '.join(cmd)}")
    return json.loads(worker_line(out.stdout, "SCALING ", f"scaling worker ({' '.join(cmd)})"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated, of: "
                    + ", ".join(CASES))
    ap.add_argument("--size", action="append", default=[], metavar="CASE=D",
                    help="particle size of a case's 1-rank run (default in CASES)")
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--csv", default=None, help="append the figures to this CSV file "
                    "(long format of jobs/benchlib.py)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--particle-size", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args)
    sizes = {k: v[2] for k, v in CASES.items()}
    sizes.update({k: float(v) for k, v in (item.split("=", 1) for item in args.size)})
    for case in args.cases.split(","):
        d = sizes[case]
        dim = CASES[case][3]
        runs = [(1, d), (2, d), (2, d / 2.0 ** (1.0 / dim))]  # twice the particles
        samples = {}
        for rep in range(args.repeats):
            for ranks, size in runs:
                res = run_worker(ranks, case, size, args.steps)
                samples.setdefault((ranks, size), []).append(res)
                print(f"# {case} ranks={ranks} d={size:.6g} run {rep + 1}: "
                      f"{res['s_per_step']:.4g} s/step", file=sys.stderr, flush=True)
        rows = {}
        for key, res in samples.items():
            row = dict(res[0])
            for k in ("s_per_step", "s_per_step_halo"):
                row[k] = statistics.median(r[k] for r in res)
            row["particle_steps_per_s_per_core"] = row["particles"] / row["s_per_step"] / key[0]
            row["halo_fraction"] = row["s_per_step_halo"] / row["s_per_step"]
            rows[key] = row
        one, strong, weak = (rows[k] for k in runs)
        strong["strong_speedup"] = one["s_per_step"] / strong["s_per_step"]
        weak["weak_efficiency"] = (weak["particle_steps_per_s_per_core"]
                                   / one["particle_steps_per_s_per_core"])
        weak["weak_t1_over_t2"] = one["s_per_step"] / weak["s_per_step"]
        for (ranks, size), row in zip(runs, (one, strong, weak)):
            n = row.pop("particles")
            metrics = {"particle_size": size, "steps": args.steps - SKIP, **row}
            record(args.csv, f"scaling_{case}", "parsph", dim, n, ranks, metrics)


if __name__ == "__main__":
    main()
