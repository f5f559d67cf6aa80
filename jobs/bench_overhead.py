"""Benchmark: the fixed cost of a coupled step (Python, collectives, set-ups) and its cost
per particle.

A 2D coupled scene (a tank, walls three particles thick: a water column resting against
a Drucker-Prager block, touching it, its phase change armed) is run at several particle
sizes under ``mpirun -n R``. The water presses on the block from the first step (the
strong coupling acts on the block's face: ``n_coupled`` > 0) and flows over it; the
block (weak: cohesion 200 Pa, softening) yields, and where its plastic strain passes
``phase_change.eps_p_limit = 0.01`` it fluidises into Bingham debris, whose viscous step
is implicit (a PETSc system): every part of a coupled step acts. (Smoke runs of 160
steps: at d = 0.05 m, 262 particles, the block began to fluidise by step 23, 11 of its 24
rows by step 160; at d = 0.02 m, 958 particles, 41 of 150 by step 160, from between
steps 23 and 46; at d = 0.01 m, 2,998 particles, 91 of 600, from between steps 46 and
69; the viscous solve ran 5-8 iterations a step from then on.)

Each size runs, after an untimed warm-up in the same process (six steps of the same
scene with the trigger lowered, so that the block fluidises at once: numba kernels,
PETSc, the debris's viscous solve loaded), ``--repeats`` runs of ``--steps`` steps, each
timed as a user waits for it: by the step loop's clock (``stats.csv`` ``elapsed_s``,
``benchlib.step_times``), so every step's AMG set-ups, migrations, halo, neighbour
lists, checks, statistics and output are in. The first row's ``elapsed_s`` holds the
run's set-up and first step (printed apart as ``startup_s``); a run's figure is the
**mean** seconds per step over the steps after it. A size's ``s_per_step`` is the median
across its repeats of the runs' means, their spread beside (``s_per_step_min_run``,
``s_per_step_max_run``) and the median of the runs' per-step medians
(``s_per_step_median_step``): it is a mean over steps, not the least of the repeats.

A least-squares line through (particles, ``s_per_step``) gives the **fixed cost per step**
(its intercept) and the cost per particle-step (its slope); the mean seconds per step at
the size nearest 1,000 particles is printed too, and the steps' fluidised, coupled and
viscous-iteration counts (the physics that acted). Issue goal: fixed cost <= 1 ms for a
2D coupled scene of about 1,000 particles.

    .venv/bin/python jobs/bench_overhead.py
    .venv/bin/python jobs/bench_overhead.py --ranks 1 2 --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import (  # noqa: E402
    FLUIDS, record, reset_peak_rss, run_benchmark, step_figures, worker_line)

#: the tank; every span is a whole number of particles at the default sizes. The water
#: (x 0-0.4) rests against the block (x 0.4-0.7): lattice points at cell centres, the two
#: faces one d apart
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
[phase_change]
eps_p_limit = {eps_p_limit}
fluid = "debris"
{fluids}[materials.soil]
model = "drucker_prager"
density = 1800.0
young_modulus = 1.0e6
poisson_ratio = 0.3
friction_angle = 19.5
cohesion = {cohesion}
dilatancy_angle = 0.0
hardening = -0.1e3
residual_cohesion = 0.0
[[bodies]]
name = "water"
material = "water"
shape = "box"
lo = [0.0, 0.0]
hi = [0.4, 0.4]
[[bodies]]
name = "block"
material = "soil"
shape = "box"
lo = [0.4, 0.0]
hi = [0.7, 0.2]
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
#: the block's cohesion (Pa) and the plastic strain past which it fluidises
COHESION = 200.0
EPS_P_LIMIT = 0.01


def scene(d):
    """The tank's TOML at particle size ``d`` (walls 3 d thick)."""
    return SCENE.format(d=d, lo=-3 * d, hix=1.0 + 3 * d, cohesion=COHESION,
                        eps_p_limit=EPS_P_LIMIT, fluids=FLUIDS)


def worker(args):
    """One size under mpirun: rank 0 prints 'OVERHEAD {json}'."""
    import numpy as np

    from decomposition import world

    comm = world()
    text = scene(args.size)
    # warm-up: the block fluidises in its first steps (the trigger lowered) and the
    # debris's implicit viscous solve runs, so the kernels the measured runs load when
    # their block fluidises are loaded here, not in a timed step
    run_benchmark(comm, text, ["run.max_steps=6", "phase_change.eps_p_limit=1e-5"])
    reset_peak_rss()  # the peak of the measured runs, not the warm-up's
    runs = []
    for _ in range(args.repeats):
        summary, stats = run_benchmark(comm, text, [f"run.max_steps={args.steps}"])
        if comm.rank == 0:
            fig = step_figures(stats)

            def last(k):
                return float(np.asarray(stats[k], float)[-1]) if k in stats else 0.0

            def mean(k):
                return float(np.nanmean(np.asarray(stats[k], float)[1:])) if k in stats else 0.0

            fig.update(n_fluidised=last("n_fluidised"), n_coupled_mean=mean("n_coupled"),
                       visc_iterations_mean=mean("visc_iterations"),
                       bytes_per_particle_peak_rss=summary["bytes_per_particle_peak_rss"],
                       peak_rss_mib_max=max(summary["peak_rss_mib"]))
            runs.append(fig)
    if comm.rank == 0:
        means = [r["s_per_step_mean"] for r in runs]
        out = dict(particles=int(summary["particles"]), steps=runs[0]["steps"],
                   s_per_step=statistics.median(means), s_per_step_min_run=min(means),
                   s_per_step_max_run=max(means),
                   s_per_step_median_step=statistics.median(r["s_per_step_median"]
                                                           for r in runs),
                   startup_s=statistics.median(r["startup_s"] for r in runs))
        for k in ("n_fluidised", "n_coupled_mean", "visc_iterations_mean",
                  "bytes_per_particle_peak_rss", "peak_rss_mib_max"):
            out[k] = statistics.median(r[k] for r in runs)
        print("OVERHEAD " + json.dumps(out), flush=True)


def run_worker(ranks, size, steps, repeats):
    cmd = ["mpirun", "-n", str(ranks), sys.executable, os.path.abspath(__file__), "--worker",
           "--size", repr(size), "--steps", str(steps), "--repeats", str(repeats)]
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
    ap.add_argument("--steps", type=int, default=160,
                    help="steps per run (the first holds the run's set-up; the mean is over "
                    "the others)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="runs per size; the median of their mean s/step is kept, the spread "
                    "printed beside")
    ap.add_argument("--csv", default=None)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--size", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args)
    if len(args.sizes) < 2 or args.steps < 2 or args.repeats < 1:
        sys.exit("bench_overhead: need two or more --sizes, --steps >= 2 and --repeats >= 1")
    for ranks in args.ranks:
        points = []
        for size in args.sizes:
            res = run_worker(ranks, size, args.steps, args.repeats)
            n = res.pop("particles")
            points.append((n, res["s_per_step"]))
            record(args.csv, "overhead", "parsph", 2, n, ranks,
                   {**res, "particle_size": size, "repeats": args.repeats})
        a, b = fit(points)
        n1k, s1k = min(points, key=lambda p: abs(p[0] - 1000))
        record(args.csv, "overhead_fit", "parsph", 2, n1k, ranks,
               {"fixed_ms_per_step": 1e3 * a, "us_per_particle_step": 1e6 * b,
                "ms_per_step_near_1000": 1e3 * s1k})


if __name__ == "__main__":
    main()
