"""The localisation benchmark: the built-in ``biaxial`` scene with the internal length and
with the paper's local rule, at several particle sizes, side by side.

Runs every size twice (``materials.*.regularisation = "nonlocal"``, the default, and
``"local"``) on the ranks it is started on, prints a table (peak and post-peak stress,
band width, wall time) and draws ``--png``: the stress-strain curves of both rules, and
the plastic strain of the finest runs (docs/regularisation.md).

    mpirun -n 2 .venv/bin/python jobs/localisation.py --png docs/img/localisation.png
    mpirun -n 2 .venv/bin/python jobs/localisation.py --sizes 0.05 0.025 --out out/loc
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+",
                        default=[0.05, 1.0 / 30.0, 0.025, 1.0 / 60.0],
                        help="particle sizes d (m), coarse to fine (default l/d = 2, 3, 4, 6)")
    parser.add_argument("--out", default="out/localisation", help="run directories")
    parser.add_argument("--png", default=None, help="figure to write (rank 0)")
    parser.add_argument("--json", default=None, help="the table as JSON (rank 0)")
    args = parser.parse_args(argv)

    from decomposition import world
    from parsph.scene.loader import load_scene
    from parsph.step.run import run
    from parsph.verify.solid import biaxial_quantities

    comm = world()
    rows = []
    for mode in ("nonlocal", "local"):
        for d in args.sizes:
            sets = [f"domain.particle_size={d!r}", "output.progress=false"]
            sets += [f"materials.{m}.regularisation=\"{mode}\"" for m in ("soil", "seed")]
            scene = load_scene("biaxial", sets)
            out = os.path.join(args.out, f"{mode}_{d:.5f}")
            t0 = time.perf_counter()
            summary = run(scene, out, comm=comm, progress=False)
            wall = time.perf_counter() - t0
            if comm.rank == 0:
                q = biaxial_quantities(scene, out)
                rows.append(dict(mode=mode, d=d, ell_over_d=0.1 / d, out=out,
                                 steps=summary["steps"], wall_s=wall, **q))
                print(f"{mode:8s} d = {d:.4f} m (l/d = {0.1 / d:.1f}): peak {q['peak_kpa']:.1f} "
                      f"kPa, at 1.5 % strain {q['post_peak_kpa']:.1f} kPa, band "
                      f"{q['band_width_m']:.3f} m, {summary['steps']} steps, {wall:.0f} s",
                      flush=True)
    if comm.rank == 0:
        record_figures(rows, comm.size, " ".join(sys.argv[1:]))
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(rows, fh, indent=1)
        if args.png:
            figure(rows, args.png)
            print(f"wrote {args.png}")
    return 0


def record_figures(rows, ranks, args="") -> None:
    """The table as the figure record ``biaxial_localisation`` (docs/figures.md): per rule,
    lists over the sizes, coarse to fine."""
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from jobs.figures import record

    fig = {}
    for mode in ("nonlocal", "local"):
        mine = sorted((r for r in rows if r["mode"] == mode), key=lambda r: -r["d"])
        fig[f"{mode}_d_m"] = [r["d"] for r in mine]
        for key in ("peak_kpa", "post_peak_kpa", "band_width_m", "wall_s"):
            fig[f"{mode}_{key}"] = [r[key] for r in mine]
    record("biaxial_localisation", fig, ranks=ranks, source="jobs/localisation.py",
           command=f"mpirun -n {ranks} .venv/bin/python jobs/localisation.py {args}".strip())


def figure(rows, path) -> None:
    """Stress-strain curves of both rules, and the plastic strain of the finest runs."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from parsph.io import read_frame
    from parsph.verify.solid import biaxial_curve

    fig = Figure(figsize=(12, 7.5))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 4)
    finest = {}
    for col, mode in enumerate(("nonlocal", "local")):
        ax = fig.add_subplot(grid[0, 2 * col:2 * col + 2])
        for k, r in enumerate(r for r in rows if r["mode"] == mode):
            strain, sigma = biaxial_curve(r["out"])
            ax.plot(100 * strain, sigma / 1e3, color=f"C{k}",
                    label=f"d = {r['d']:.4f} m (l/d = {r['ell_over_d']:.1f})")
            finest[mode] = r
        ax.set_title("internal length l = 0.1 m" if mode == "nonlocal" else
                     "the paper's local rule")
        ax.set_xlabel("axial strain (%)")
        ax.set_ylabel("mean axial stress (kPa)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    for col, mode in enumerate(("nonlocal", "local")):
        for j, r in enumerate(r for r in rows if r["mode"] == mode
                              and r["d"] in (max(x["d"] for x in rows),
                                             min(x["d"] for x in rows))):
            ax = fig.add_subplot(grid[1, 2 * col + j])
            f = read_frame(os.path.join(r["out"], "particles.h5"), "last")
            s = (72.0 * r["d"] / 2.4) ** 2 * 2.0
            im = ax.scatter(f["x"][:, 0], f["x"][:, 1], c=f["eps_p"], s=s, marker="s",
                            lw=0, cmap="viridis", vmin=0.0,
                            vmax=np.percentile(f["eps_p"], 99.5))
            ax.set_aspect("equal")
            ax.set_title(f"{'l = 0.1 m' if mode == 'nonlocal' else 'local'}, d = {r['d']:.4f}: "
                         f"band {r['band_width_m']:.3f} m", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
            fig.colorbar(im, ax=ax, shrink=0.8, label="plastic strain")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
