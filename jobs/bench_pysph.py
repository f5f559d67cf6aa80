"""Benchmark: the IISPH dam break side by side with PySPH (issue 4).

Simulates the collapse of the ``dam_break`` scene's water column (a = 0.146 m wide, 2a
high, tank 4a long, water rho = 1000 kg/m^3, nu = 1e-6 m^2/s) to the same end time at
the same particle spacing d = a / ``--divisions`` with

- parsph (``python -m parsph run dam_break``: GMRES + BoomerAMG on the PPE to rtol 1e-8,
  every solve converged or the run stops) on 1 and 2 ranks, and
- PySPH's ``IISPHScheme`` (Ihmsen et al. 2014: relaxed Jacobi, omega = 0.5, stops at a
  1 % mean density error after 2-30 sweeps; its dam_break_2d settings: quintic spline,
  h = 1.3 d, 4 wall layers, CFL 0.3 adaptive step) on one core (its IISPH does not run
  under MPI),

alternately, ``--repeats`` times each (noise between identical runs reaches 25 %), and
prints one row per code and rank count (medians): particles, steps, run wall time (each
code's own timer, start-up excluded: parsph's "done ... s wall", PySPH's "Run took"),
process wall time, particle-steps/s, the mean front error against Martin & Moyce (1952)
and Koshizuka & Oka (1996) (``parsph.verify.fluid.front_errors``, the scene's
reference; front = rightmost fluid particle below 0.1 a, + d/2, sampled at the same
frame times), and the wall-time ratio parsph / PySPH. Goal of issue 4: ratio <= 0.5 with
a front error no worse than PySPH's.

PySPH is installed from PyPI (it builds from source in a few minutes) into a scratch
venv outside the repository (``--pysph-venv``, default under the temp dir) if missing:

    python jobs/bench_pysph.py --divisions 105 --end-time 0.1 --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import csv
import glob
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import mpirun_parsph, record, worker_line  # noqa: E402

A, RHO, NU, G = 0.146, 1000.0, 1.0e-6, 9.81  # as parsph/scenes/dam_break.toml
TANK_LENGTH, TANK_HEIGHT = 4.0 * A, 0.35

PYSPH_SCRIPT = """# PySPH IISPH dam break, written by parsph's jobs/bench_pysph.py
import json, sys, time
import numpy as np
from pysph.base.kernels import QuinticSpline
from pysph.base.utils import get_particle_array
from pysph.solver.application import Application
from pysph.solver.utils import iter_output
from pysph.sph.iisph import IISPHScheme

A, D, TF, EVERY, RHO, NU, G = {a!r}, {d!r}, {tf!r}, {every!r}, {rho!r}, {nu!r}, {g!r}
LENGTH, HEIGHT, HDX, LAYERS = {length!r}, {height!r}, 1.3, 4


class DamBreak(Application):
    def create_scheme(self):
        return IISPHScheme(fluids=["fluid"], solids=["boundary"], dim=2, nu=NU, rho0=RHO,
                           gy=-G)

    def configure_scheme(self):
        h = HDX * D
        times = EVERY * np.arange(1, int(round(TF / EVERY)) + 1)
        self.scheme.configure_solver(kernel=QuinticSpline(dim=2), tf=TF, pfreq=10 ** 9,
                                     dt=0.125 * h / np.sqrt(2 * G * 2 * A),
                                     adaptive_timestep=True, output_at_times=times)

    def create_particles(self):
        n, ny = int(round(A / D)), int(round(2 * A / D))
        xf, yf = [(np.arange(k) + 0.5) * D for k in (n, ny)]
        xf, yf = [c.ravel() for c in np.meshgrid(xf, yf)]
        xf += 0.25 * D  # as PySPH's dam_break_2d: keeps the column off the left wall
        nx = int(round(LENGTH / D))
        xw, yw = [c.ravel() for c in np.meshgrid(
            (np.arange(-LAYERS, nx + LAYERS) + 0.5) * D,
            (np.arange(-LAYERS, int(HEIGHT / D)) + 0.5) * D)]
        keep = (xw < 0) | (xw > LENGTH) | (yw < 0)
        h, m = HDX * D, RHO * D * D
        fluid = get_particle_array(name="fluid", x=xf, y=yf, h=h, m=m, rho=RHO)
        wall = get_particle_array(name="boundary", x=xw[keep], y=yw[keep], h=h, m=m,
                                  rho=RHO)
        self.scheme.setup_properties([fluid, wall])
        return [fluid, wall]


if __name__ == "__main__":
    app = DamBreak()
    t0 = time.perf_counter()
    app.run()
    process = time.perf_counter() - t0
    with open(app.info_filename) as fh:
        info = json.load(fh)
    T, X = [], []
    for sd, fl in iter_output(app.output_files, "fluid"):
        x, y = fl.get("x", "y")
        T.append(float(sd["t"]))
        X.append(float(x[y < 0.1 * A + 1e-9].max()))
    pas = app.particles
    print("PYSPH_RESULT " + json.dumps(dict(
        steps=app.solver.count, t=app.solver.t, run_s=info["cpu_time"], setup_s=process
        - info["cpu_time"], fluid=pas[0].get_number_of_particles(),
        particles=sum(p.get_number_of_particles() for p in pas), time=T, front_x=X)))
"""


def ensure_pysph(venv):
    """The python of a scratch venv with PySPH, installing it there from PyPI if missing."""
    py = os.path.join(venv, "bin", "python")
    if not glob.glob(os.path.join(venv, "lib", "python3*", "site-packages", "pysph")):
        print(f"# installing pysph into {venv} (builds from source, a few minutes)",
              file=sys.stderr, flush=True)
        subprocess.run(["python3", "-m", "venv", venv], check=True)
        subprocess.run([os.path.join(venv, "bin", "pip"), "install", "-q", "pysph"],
                       check=True)
    return py


def lattice_neighbours(radius):
    """Neighbours (self included) of an interior particle of the square lattice: the
    lattice points within ``radius`` (in units of d)."""
    k = np.arange(-int(radius) - 1, int(radius) + 2)
    return int(np.count_nonzero(k[:, None] ** 2 + k[None, :] ** 2 < radius ** 2))


def mean_front_error(T, Z):
    """Mean |Z - Z_exp| / Z_exp over both experiments at their times in (0.5, T.max()]:
    the scene's reference (``parsph.verify.fluid.dam_break``) on a (T, Z) series."""
    from parsph.verify.fluid import DAM_BREAK_DATA, front_errors

    errs = []
    for fname in DAM_BREAK_DATA:
        _, sim, ze = front_errors(np.asarray(T), np.asarray(Z), fname)
        errs.extend(np.abs(sim - ze) / ze)
    return float(np.mean(errs)) if errs else float("nan")


def run_pysph(py, work, tag, d, end, every):
    path = os.path.join(work, "dam_break_iisph.py")
    with open(path, "w") as fh:
        fh.write(PYSPH_SCRIPT.format(a=A, d=d, tf=end, every=every, rho=RHO, nu=NU, g=G,
                                     length=TANK_LENGTH, height=TANK_HEIGHT))
    out = os.path.join(work, f"pysph_{tag}")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PYTHON"))}
    t0 = time.perf_counter()
    proc = subprocess.run([py, path, "-d", out], cwd=work, env=env, capture_output=True,
                          text=True)
    wall = time.perf_counter() - t0
    if proc.returncode:
        sys.exit(f"PySPH failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    res = json.loads(worker_line(proc.stdout, "PYSPH_RESULT ", f"PySPH run ({path})"))
    T = np.array(res["time"]) * math.sqrt(2 * G / A)
    Z = (np.array(res["front_x"]) + 0.5 * d) / A
    return dict(particles=res["particles"], fluid=res["fluid"], steps=res["steps"],
                t_end=res["t"], run_s=res["run_s"], process_s=wall, T=T, Z=Z,
                ppe_iterations="Jacobi to 1 %", neighbours=lattice_neighbours(3 * 1.3))


def run_parsph(ranks, out, d, end, every, extra=()):
    """One parsph run into ``out``; its files are read later by :func:`read_parsph`."""
    sets = [f"domain.particle_size={d!r}", f"run.end_time={end!r}", f"output.every={every!r}",
            *extra]
    return dict(out=out, d=d, neighbours=lattice_neighbours(2.4),
                **mpirun_parsph(ranks, "dam_break", out, sets))


def read_parsph(res):
    """Add particle counts, PPE iterations and the front series of a parsph run."""
    from parsph.verify.fluid import front_positions
    from parsph.io import read_stats

    stats = read_stats(os.path.join(res["out"], "stats.csv"))
    res["T"], res["Z"] = front_positions(res["out"], A, res["d"], G)
    res.update(particles=int(stats["n_particles"][0]), fluid=int(stats["n_fluid"][0]),
               ppe_iterations=float(np.median(stats["ppe_iterations"])),
               ppe_iterations_max=int(np.max(stats["ppe_iterations"])))
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--divisions", type=int, default=105,
                    help="a / d (105: 22,050 fluid particles, ~25k with the walls)")
    ap.add_argument("--end-time", type=float, default=0.1, help="simulated time (s)")
    ap.add_argument("--every", type=float, default=0.01, help="frame interval (s) of both")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--ranks", default="1,2", help="parsph rank counts")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra parsph scene override (e.g. fluid.cfl=0.2)")
    ap.add_argument("--pysph-venv", default=os.path.join(tempfile.gettempdir(),
                                                         "parsph-peers", "pysph"))
    ap.add_argument("--csv", default=None, help="append the figures to this CSV file "
                    "(long format of jobs/benchlib.py)")
    args = ap.parse_args()
    py = ensure_pysph(args.pysph_venv)
    d = A / args.divisions
    ranks = [int(r) for r in args.ranks.split(",")]
    work = tempfile.mkdtemp(prefix="pysph-bench-")
    load = os.getloadavg()[0]
    # warm-up: PySPH compiles its equations (cached in ~/.pysph), numba loads its cache
    run_pysph(py, work, "warm-up", d, 2 * args.every, args.every)
    run_parsph(ranks[0], os.path.join(work, "warm-up"), d, 2 * args.every, args.every,
               args.set)
    samples = {}
    for rep in range(args.repeats):
        for code, r in [("pysph", 1)] + [("parsph", r) for r in ranks]:  # alternate
            out = os.path.join(work, f"parsph_{r}_{rep}")
            res = (run_pysph(py, work, rep, d, args.end_time, args.every) if code == "pysph" else
                   run_parsph(r, out, d, args.end_time, args.every, args.set))
            samples.setdefault((code, r), []).append(res)
            print(f"# {code} ranks={r} run {rep + 1}: {res['run_s']:.4g} s, {res['steps']} "
                  f"steps to t = {res['t_end']:.4g} s", file=sys.stderr, flush=True)
    rows, fronts = [], {}
    for (code, r), runs in samples.items():
        first = read_parsph(runs[0]) if code == "parsph" else runs[0]
        run_s = statistics.median(x["run_s"] for x in runs)
        row = {"code": code, "ranks": r, "particles": first["particles"],
               "fluid": first["fluid"], "neighbours": first["neighbours"],
               "steps": first["steps"], "t_end": first["t_end"], "run_s": run_s,
               "process_s": statistics.median(x["process_s"] for x in runs),
               "particle_steps_per_s": first["particles"] * first["steps"] / run_s,
               "ppe_iterations": first["ppe_iterations"],
               "ppe_iterations_max": first.get("ppe_iterations_max", 30),
               "front_error": mean_front_error(first["T"], first["Z"])}
        fronts[(code, r)] = first
        rows.append(row)
    ref = next(x for x in rows if x["code"] == "pysph")
    for row in rows:
        row["ratio_vs_pysph"] = row["run_s"] / ref["run_s"]
        metrics = {k: row[k] for k in ("fluid", "steps", "t_end", "run_s", "process_s",
                                        "particle_steps_per_s", "front_error",
                                        "ratio_vs_pysph")}
        if row["code"] == "parsph":
            metrics["ppe_iterations"] = row["ppe_iterations"]
            metrics["ppe_iterations_max"] = row["ppe_iterations_max"]
        record(args.csv, "iisph_dam_break_vs_pysph", row["code"], 2, row["particles"],
               row["ranks"], metrics)
    print(f"# d = a/{args.divisions} = {d:.6g} m, end time {args.end_time} s "
          f"(T = {args.end_time * math.sqrt(2 * G / A):.3g}), frames every {args.every} s; "
          f"medians of {args.repeats} alternating run(s); load average {load:.2f} at start")
    writer = csv.DictWriter(sys.stdout, list(rows[0]))
    writer.writeheader()
    writer.writerows([{k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()}
                      for r in rows])
    from parsph.verify.fluid import DAM_BREAK_DATA, experiment

    print("# front Z = z/a at the experiments' times: T, experiment, "
          + ", ".join(f"{c}@{r}" for c, r in fronts))
    for fname in DAM_BREAK_DATA:
        for Te, Ze in zip(*experiment(fname)):
            if 0.5 < Te <= args.end_time * math.sqrt(2 * G / A):
                sims = [np.interp(Te, f["T"], f["Z"]) for f in fronts.values()]
                print(f"# {fname.split('_')[0]:10s} {Te:5.2f} {Ze:5.2f} "
                      + " ".join(f"{z:5.2f}" for z in sims))
    import shutil

    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
