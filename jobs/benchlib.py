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
