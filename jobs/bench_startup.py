"""Benchmark: numba cold and warm start — seconds from launch to the end of a short run.

Cold: an empty ``NUMBA_CACHE_DIR``, so every kernel the scene needs is compiled. Warm: the
same directory again, so every kernel is loaded from the cache (what a second run, or a
fresh CI clone with the cache outside the clone, sees). Figures in the long CSV format of
``jobs/benchlib.py``.

    .venv/bin/python jobs/bench_startup.py --scene dam_break --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import record  # noqa: E402

_MPI_ENV = ("OMPI_", "PMIX_", "OPAL_", "PRTE_", "HYDRA_", "PMI_")


def launch(scene: str, cache: str, out: str, steps: int) -> float:
    env = {k: v for k, v in os.environ.items() if not k.startswith(_MPI_ENV)}
    env["NUMBA_CACHE_DIR"] = cache
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "parsph", "run", scene, "--out", out, "--no-progress",
                    "--set", f"run.max_steps={steps}"], check=True, env=env,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", action="append", default=None,
                    help="scene(s) to start (default: dam_break and elastic_plate)")
    ap.add_argument("--steps", type=int, default=2)
    ap.add_argument("--csv", default=None)
    args = ap.parse_args()
    for scene in args.scene or ["dam_break", "elastic_plate"]:
        tmp = tempfile.mkdtemp(prefix="parsph-startup-")
        try:
            cache = os.path.join(tmp, "numba")
            cold = launch(scene, cache, os.path.join(tmp, "cold"), args.steps)
            warm = launch(scene, cache, os.path.join(tmp, "warm"), args.steps)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        record(args.csv, f"startup:{scene}", "parsph", 0, 0, 1,
               {"cold_start_s": cold, "warm_start_s": warm})


if __name__ == "__main__":
    main()
