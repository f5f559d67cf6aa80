"""Benchmark: what the internal length costs per step (docs/regularisation.md).

Runs a scene with the internal length (the default) and with the paper's local rule
(``materials.NAME.regularisation = "local"`` for every soil), at each particle size and
rank count, each under ``mpirun`` as a user would, and prints the seconds per step by
the step loop's clock (stats.csv's ``elapsed_s``: the mean over all steps, set-up,
migrations, checks and output included; the median beside it) split by stage (the
``wall_s_*`` columns: the solid, the fluid, the phase change and the non-local solve),
and the whole run's wall time. Issue goal: the cost of the length, reported, on
``slope_failure`` and the 3D slab at two sizes, 1 and 2 ranks.

    .venv/bin/python jobs/bench_regularisation.py --scene slope_failure --sizes 0.05 0.025
    .venv/bin/python jobs/bench_regularisation.py --scene slope_failure_3d \\
        --sizes 0.0625 0.05 --end 1.0 --ranks 2 --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from benchlib import bytes_per_particle, mpirun_parsph, record  # noqa: E402

#: stats.csv columns of a stage's wall time, in the order printed.
STAGES = ("wall_s_solid", "wall_s_nonlocal", "wall_s_fluid", "wall_s_phase_change",
          "wall_s_tlsph", "wall_s_coupled", "wall_s_migrate", "wall_s_halo",
          "wall_s_neighbours", "wall_s_output")


def soils(scene_name) -> list[str]:
    """The names of the scene's materials that take ``regularisation``."""
    from parsph.scene.loader import load_scene

    return [k for k, m in load_scene(scene_name).materials.items()
            if hasattr(m, "regularisation")]


def measure(out: str) -> dict:
    """Mean (and median) seconds per step and the mean of every stage column."""
    import numpy as np

    from parsph.io import read_stats

    stats = read_stats(os.path.join(out, "stats.csv"))
    elapsed = np.asarray(stats["elapsed_s"])
    per_step = np.diff(np.concatenate([[0.0], elapsed]))
    row = {"steps": len(elapsed), "s_per_step": float(elapsed[-1] / len(elapsed)),
           "median_s_per_step": float(np.median(per_step))}
    for k in STAGES:
        if k in stats:
            row[k] = float(np.mean(stats[k]))
    row["n_solid"] = int(stats["n_solid"][0])
    row["n_particles"] = int(stats["n_particles"][0])
    row["n_fluidised"] = int(stats["n_fluidised"][-1]) if "n_fluidised" in stats else 0
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="slope_failure")
    parser.add_argument("--sizes", type=float, nargs="+", default=[0.05, 0.025])
    parser.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--end", type=float, default=1.0,
                        help="simulated time (s): the slide is under way by 1 s")
    parser.add_argument("--csv", default=None, help="append the figures (long format)")
    args = parser.parse_args(argv)
    names = soils(args.scene)
    print(f"{'rule':8s} {'d':>7s} {'ranks':>5s} {'steps':>6s} {'s/step':>8s} {'median':>8s} "
          + " ".join(f"{k[7:]:>11s}" for k in STAGES) + "  fluidised", flush=True)
    for d in args.sizes:
        for ranks in args.ranks:
            for rule in ("nonlocal", "local"):
                sets = [f"domain.particle_size={d!r}", f"run.end_time={args.end!r}",
                        f"output.every={args.end!r}"]
                sets += [f"materials.{k}.regularisation=\"{rule}\"" for k in names]
                with tempfile.TemporaryDirectory(prefix="parsph-bench-") as tmp:
                    run = mpirun_parsph(ranks, args.scene, tmp, sets)
                    row = measure(tmp)
                print(f"{rule:8s} {d:7.4f} {ranks:5d} {row['steps']:6d} "
                      f"{row['s_per_step'] * 1e3:8.2f} {row['median_s_per_step'] * 1e3:8.2f} "
                      + " ".join(f"{row.get(k, float('nan')) * 1e3:11.2f}" for k in STAGES)
                      + f"  {row['n_fluidised']}", flush=True)
                record(args.csv, f"regularisation_{args.scene}", rule,
                       2 if args.scene != "slope_failure_3d" else 3, row["n_solid"], ranks,
                       {"s_per_step": row["s_per_step"], "wall_s": run["process_s"],
                        "peak_rss_mib_max": max(run["peak_rss_mib"]),
                        "bytes_per_particle_peak_rss":
                            bytes_per_particle(run["peak_rss_mib"], row["n_particles"]),
                        **{k: v for k, v in row.items() if k.startswith("wall_s_")}})
    print("(ms per step; the stage columns are means over all steps)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
