"""One CSV for every benchmark: long format, one row per measured figure.

Columns: ``benchmark, code, dim, particles, ranks, metric, value`` — so benchmarks with
different figures (particle-steps/s, KSP iterations, bytes per particle, …) and peer codes
measured side by side land in the same file, which ``jobs/bench.sh`` writes.
"""
from __future__ import annotations

import csv
import os
import re
import sys

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
        new = not os.path.exists(path)
        with open(path, "a", newline="") as fh:
            w = csv.DictWriter(fh, COLUMNS)
            if new:
                w.writeheader()
            w.writerows(rows)


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
    from parsph.run import run
    from parsph.scene import load_scene

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
