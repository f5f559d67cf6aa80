"""The scatter of the slope's deposit at one particle size: runs far below the physics apart.

A landslide amplifies small differences: the deposit of ``slope_failure`` moves by a few
per cent between runs that differ only in the time step. A convergence study of such a
scene can ask no more of its sizes than that they agree to within this scatter
(docs/slope.md). This job measures it: at each size ``--d`` it runs the scene as it is
and with one setting perturbed at a time (``--perturb KEY=V1,V2,...``; by default
``solid.cfl`` = 0.45, 0.475, 0.525, 0.55 about its 0.5, the time step by up to +-10 %,
and ``solid.friction_time`` = 0.009, 0.011 about its 0.01), measures the scene's
quantities of every run (:func:`parsph.verify.coupling.landslide`: the run-out that 99 %
of the mass stays behind, the fluidised area, the time to rest) and prints, per size and
quantity, the mean and the largest deviation from it, relative, and the figures record
``slope_failure_scatter`` (per size, in the order of ``--d``: ``runout_m_mean``,
``runout_m_deviation_pc``, the runs' values ``runout_m_values_0``, ...; over the sizes,
``runout_m_scatter_pc``; the same for ``fluidised`` and ``time_to_rest_s``), written to
``$PARSPH_FIGURES`` when set (``python jobs/figures.py --take DIR`` takes it into
docs/figures). The study's slow test asks of its resolved sizes that they lie within
twice the largest of these deviations.

A run whose directory already holds a finished run (its stats.csv reaches the end time)
is measured, not run again: an interrupted job resumes.

    PARSPH_FIGURES=out/scatter/figures mpirun -n 2 .venv/bin/python jobs/slope_scatter.py
    mpirun -n 2 .venv/bin/python jobs/slope_scatter.py --d 0.05 --perturb solid.cfl=0.45,0.55
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from decomposition import world  # noqa: E402
from decomposition.reduce import broadcast  # noqa: E402

PERTURB = ("solid.cfl=0.45,0.475,0.525,0.55", "solid.friction_time=0.009,0.011")
QUANTITIES = ("runout_m", "fluidised", "time_to_rest_s")


def _perturbations(items) -> list[tuple[str, float]]:
    out = []
    for item in items:
        key, _, values = item.partition("=")
        try:
            vals = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            vals = []
        if not key or not vals:
            raise SystemExit(f"slope_scatter: --perturb {item!r}: expected KEY=V1,V2,... "
                             f"e.g. solid.cfl=0.45,0.55")
        out += [(key.strip(), v) for v in vals]
    return out


def _finished(out: str, end_time: float) -> bool:
    from parsph.io import read_stats

    path = os.path.join(out, "stats.csv")
    if not os.path.exists(path):
        return False
    t = read_stats(path).get("time", [])
    return len(t) > 0 and float(t[-1]) >= end_time * (1.0 - 1e-9)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="slope_failure")
    ap.add_argument("--d", default="0.025,0.02", help="particle sizes (m), comma-separated")
    ap.add_argument("--perturb", action="append", default=None,
                    help="KEY=V1,V2,...: one run per value, the rest of the scene as it is "
                         f"(default: {' and '.join(PERTURB)})")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene key for every run, e.g. run.end_time=1.0")
    ap.add_argument("--out", default="out/scatter")
    args = ap.parse_args(argv)
    comm = world()
    from parsph.scene.loader import load_scene
    from parsph.step.run import run
    from parsph.verify.coupling import landslide

    sizes = [float(v) for v in args.d.split(",") if v.strip()]
    runs = [("base", None)] + _perturbations(args.perturb or PERTURB)
    names = ["base" if key == "base" else f"{key}={value:g}" for key, value in runs]
    figures = {"d_m": sizes, "runs": names}
    worst = {q: 0.0 for q in QUANTITIES}
    for q in QUANTITIES:  # per size, in the order of --d (a figure's key holds no dot)
        figures[f"{q}_mean"], figures[f"{q}_deviation_pc"] = [], []
    for i, d in enumerate(sizes):
        values = {q: [] for q in QUANTITIES}
        for (key, value), name in zip(runs, names):
            sets = [f"domain.particle_size={d!r}", "output.progress=false", *args.set]
            if key != "base":
                sets.append(f"{key}={value!r}")
            scene = load_scene(args.scene, sets)
            out = os.path.join(args.out, f"d{d:.4g}", name)
            if not broadcast(comm, _finished(out, scene.run.end_time) if comm.rank == 0
                             else None):
                run(scene, out, comm=comm, progress=False)
            if comm.rank == 0:
                q = landslide(scene, out)
                for k in QUANTITIES:
                    values[k].append(float(q[k]))
                print(f"d = {d:.4g} m, {name}: run-out {q['runout_m']:.4f} m, fluidised "
                      f"{q['fluidised']:.5f}, at rest from {q['time_to_rest_s']:.2f} s",
                      flush=True)
        if comm.rank == 0:
            for k in QUANTITIES:
                v = np.array(values[k])
                mean = float(v.mean())
                spread = float(np.abs(v - mean).max())
                dev = spread / abs(mean) if mean else (0.0 if spread == 0.0 else np.inf)
                worst[k] = max(worst[k], dev)
                figures[f"{k}_values_{i}"] = [float(x) for x in v]
                figures[f"{k}_mean"].append(mean)
                figures[f"{k}_deviation_pc"].append(100 * dev)
                print(f"d = {d:.4g} m: {k} mean {mean:.4f}, largest deviation "
                      f"{100 * dev:.2f} % over {len(v)} runs", flush=True)
    if comm.rank != 0:
        return 0
    for k in QUANTITIES:
        figures[f"{k}_scatter_pc"] = 100 * worst[k]
        print(f"scatter of {k}: {100 * worst[k]:.2f} % (the largest deviation from the mean "
              f"at one size)")
    from jobs.figures import record

    record("slope_failure_scatter", figures, ranks=comm.size, source="jobs/slope_scatter.py",
           command="mpirun -n %d .venv/bin/python jobs/slope_scatter.py %s"
                   % (comm.size, " ".join(argv if argv is not None else sys.argv[1:])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
