"""One CSV for every benchmark: long format, one row per measured figure.

Columns: ``benchmark, code, dim, particles, ranks, metric, value`` — so benchmarks with
different figures (particle-steps/s, KSP iterations, bytes per particle, …) and peer codes
measured side by side land in the same file, which ``jobs/bench.sh`` writes.
"""
from __future__ import annotations

import csv
import os
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
