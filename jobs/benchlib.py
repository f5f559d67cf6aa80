"""One CSV for every benchmark: long format, one row per measured figure.

Columns: ``benchmark, code, dim, particles, ranks, metric, value`` — so benchmarks with
different figures (particle-steps/s, KSP iterations, bytes per particle, …) and peer codes
measured side by side land in the same file, which ``jobs/bench.sh`` writes.

The rules a job that backs a figure of the README follows, with the helpers here: it
times the whole step by the step loop's clock (``stats.csv`` ``elapsed_s``,
:func:`step_times`) and reports the mean over the steps after the first (the first row,
which holds the run's set-up, apart as ``startup_s``), a median only beside it; memory is
the whole process's peak RSS on every rank (:func:`peak_rss_mib`, reset by
:func:`reset_peak_rss` after a warm-up in the same process), summed over the ranks,
over all particles.
"""
from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
import time

from base.memory import bytes_per_particle, peak_rss_mib, reset_peak_rss  # noqa: F401 (re-exported)

COLUMNS = ["benchmark", "code", "dim", "particles", "ranks", "metric", "value"]


def record(path, benchmark: str, code: str, dim: int, particles: int, ranks: int,
           metrics: dict) -> None:
    """Print the figures and append them to ``path`` (if given) in long format."""
    rows = [{"benchmark": benchmark, "code": code, "dim": dim, "particles": particles,
             "ranks": ranks, "metric": k, "value": f"{v:.6g}" if isinstance(v, float) else v}
            for k, v in metrics.items()]
    out = csv.DictWriter(sys.stdout, COLUMNS)
    for row in rows:
        out.writerow(row)
    if path:
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        new = not os.path.exists(path)
        with open(path, "a", newline="") as fh:
            w = csv.DictWriter(fh, COLUMNS)
            if new:
                w.writeheader()
            w.writerows(rows)


#: The fluids of the coupled tanks of jobs/bench_memory.py and jobs/bench_overhead.py (their
#: scenes' ``{fluids}``): the water column and the Bingham debris the soil fluidises into.
FLUIDS = """[materials.water]
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
"""


def step_times(stats, column: str = "elapsed_s"):
    """The run's wall time per step as a user waits for it, from ``stats.csv``.

    ``elapsed_s`` is the step loop's clock: wall seconds since the run began, written
    after every step (every step's set-ups, migrations, checks, statistics and output
    in). Returns ``(startup_s, per_step)``: the first row's ``elapsed_s`` (the run's
    set-up, particle build included, and its first step), and the numpy array of the
    steps after the first (the differences of ``elapsed_s``; empty for a run of one
    step). A figure per step is the **mean** of ``per_step``; a median may be printed
    beside it, never instead of it."""
    import numpy as np

    elapsed = np.asarray(stats[column], dtype=float)
    if elapsed.size == 0:
        raise ValueError("stats.csv has no rows: the run made no step")
    return float(elapsed[0]), np.diff(elapsed)


def step_figures(stats, prefix: str = "s_per_step") -> dict:
    """``startup_s``, ``steps``, ``{prefix}_mean`` and ``{prefix}_median`` of
    :func:`step_times` (nan where the run made one step only)."""
    import numpy as np

    startup, per_step = step_times(stats)
    mean = float(per_step.mean()) if per_step.size else float("nan")
    median = float(np.median(per_step)) if per_step.size else float("nan")
    return {"startup_s": startup, "steps": int(per_step.size + 1),
            f"{prefix}_mean": mean, f"{prefix}_median": median}


#: terminal control sequences (CSI, OSC) and carriage returns: Open MPI gives ranks a
#: pseudo-terminal, so a worker's line may read "\x1b[0mPARSPH ..." or end in "\r"
_TERMINAL = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]|\x1b\][^\x07\x1b]*(?:\x07|\x1b\\)|\x1b[@-_]|\r")


def worker_line(stdout: str, tag: str, what: str) -> str:
    """The text after ``tag`` on the last line of a worker's ``stdout`` that carries it,
    terminal codes removed; exits naming ``what`` and showing its output if none does."""
    for line in reversed(_TERMINAL.sub("", stdout).splitlines()):
        at = line.find(tag)
        if at >= 0:
            return line[at + len(tag):].strip()
    tail = stdout[-2000:] if stdout else "(nothing)"
    raise SystemExit(f"{what}: no line with {tag.strip()!r} in its output; it printed:\n{tail}")


def run_benchmark(comm, scene, overrides=(), petsc_args=()):
    """Collective: run a scene (built-in name or TOML text) in a scratch directory.

    Returns ``(summary, stats)``: the run's summary on every rank and its ``stats.csv``
    columns on rank 0 (None elsewhere); the scratch directory is removed.
    """
    import shutil
    import tempfile

    from decomposition.reduce import barrier, broadcast
    from parsph.io import read_stats
    from parsph.step.run import run
    from parsph.scene.loader import load_scene

    tmp = broadcast(comm, tempfile.mkdtemp(prefix="parsph-bench-") if comm.rank == 0 else None)
    if "\n" in scene:  # TOML text
        path = os.path.join(tmp, "scene.toml")
        if comm.rank == 0:
            with open(path, "w") as fh:
                fh.write(scene)
        barrier(comm)
        scene = path
    out = os.path.join(tmp, "out")
    summary = run(load_scene(scene, list(overrides)), out, comm=comm, petsc_args=petsc_args,
                  progress=False)
    stats = read_stats(os.path.join(out, "stats.csv")) if comm.rank == 0 else None
    barrier(comm)
    if comm.rank == 0:
        shutil.rmtree(tmp, ignore_errors=True)
    return summary, stats


def mpirun_parsph(ranks: int, scene: str, out: str, sets=()) -> dict:
    """Run ``parsph run SCENE --out OUT`` under ``mpirun -n RANKS`` (one ``--set`` per
    entry of ``sets``) and read its ``done:`` line robustly (ranks' output may carry
    terminal codes). Returns ``steps``, ``t_end`` (s), ``run_s`` (parsph's own timer:
    particle build and steps), ``process_s`` (the whole process, s) and ``peak_rss_mib``
    (each rank's whole process at its peak, MiB: ``parsph.step.run``); exits with the
    command and its output when the run fails or its line cannot be read. The caller
    must not have initialised MPI (h5py/mpi4py would) before it starts mpirun."""
    exe = os.path.join(os.path.dirname(sys.executable), "parsph")
    prog = [exe] if os.path.isfile(exe) else [sys.executable, "-m", "parsph"]
    cmd = ["mpirun", "-n", str(ranks), *prog, "run", scene, "--out", out, "--no-progress"]
    cmd += [x for s in sets for x in ("--set", s)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode:
        sys.exit(f"parsph failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stdout[-2000:]}\n"
                 f"{proc.stderr[-3000:]}")
    what = f"parsph run ({' '.join(cmd)}), its log"
    return dict(done_figures(proc.stderr, what), process_s=wall)


def done_figures(log: str, what: str) -> dict:
    """The figures of a parsph run's ``done:`` line in ``log`` (a rank's output, terminal
    codes and all): ``steps``, ``t_end`` (s), ``run_s`` (s) and ``peak_rss_mib`` (each
    rank's, MiB); exits naming ``what`` where the line is missing or reads otherwise."""
    line = worker_line(log, "done: ", what)
    done = re.match(r"(\d+) steps to t = (\S+) s in (\S+) s wall", line)
    rss = re.search(r"peak memory ([\d /]+) MiB per rank", line)
    if done is None or rss is None:
        sys.exit(f"{what}: its 'done:' line does not read 'N steps to t = T s in W s wall; "
                 f"peak memory M0 / M1 ... MiB per rank':\n{line}")
    return dict(steps=int(done.group(1)), t_end=float(done.group(2)),
                run_s=float(done.group(3)),
                peak_rss_mib=[float(m) for m in rss.group(1).split("/")])
