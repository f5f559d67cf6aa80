"""The table of docs/aso.md from runs of the ``aso`` scene: one row per run directory.

For each run (its first and last frames and ``stats.csv``): where the slope failed (the
x range, up the path, that the fluidised particles started from), how much (their count
and volume d^3 each, per metre of the periodic 96 m width and for a source 140 m wide),
how far the debris went (the lowest x a fluid particle reached, and the run-out from the
crown at x = 860 m), the speeds (the largest at the frame nearest 30 s, and over the
run), the kinetic energy at the end against its peak (the run is at rest when it stays
below 1e-3 of it), and how the soil moved: the mean displacement of soil 2's region
(between the ground and aso_soil2_base.asc) and the largest of the soil below x = 480 m
(the lower slope, the gorge and the far bank: outside the source area)::

    .venv/bin/python jobs/aso_table.py out/aso out/aso_no_quake out/aso_undisturbed ...
"""
from __future__ import annotations

import argparse
import os
import sys

import h5py
import numpy as np

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
CROWN_X = 860.0     # m: the crown, the upper end of soil 2 (jobs/make_aso_terrain.py)
WIDTH = 96.0        # m: the scene's periodic width
SOURCE_WIDTH = 140.0  # m: the source's average width (PASCO, docs/aso.md)
SLID = 5.0          # m: a permanent displacement counted as sliding (the shaking's
                    # elastic and small plastic part moved the lower slope < 3 m at d = 8, 16 m)


def row(run_dir: str) -> dict:
    """The figures of one run directory."""
    sys.path.insert(0, ROOT)
    from parsph.io import read_frame, read_frames, read_stats
    from parsph.scene.heightmap import read_grid, surface

    h5 = os.path.join(run_dir, "particles.h5")
    frames = read_frames(h5)
    first, last = read_frame(h5, frames[0][0]), read_frame(h5, "last")
    o0, o1 = np.argsort(first["id"]), np.argsort(last["id"])
    x0, x1 = first["x"][o0], last["x"][o1]
    phase0 = first["phase"][o0]
    soil = phase0 != 2
    with h5py.File(h5, "r") as f:  # the run's d (the settled lattice is not exact)
        d = float(f.attrs["particle_size"])
    data = os.path.join(ROOT, "parsph", "scenes", "data")
    ground = read_grid(os.path.join(data, "aso_surface.asc"))
    base = read_grid(os.path.join(data, "aso_soil2_base.asc"))
    soil2 = soil & (x0[:, 2] > surface(base, x0[:, 0], x0[:, 1])) & \
        (x0[:, 2] <= surface(ground, x0[:, 0], x0[:, 1]))
    moved = np.linalg.norm(x1 - x0, axis=1)
    slid = soil & (moved > SLID)
    fl = last["fluidised"][o1].astype(bool)
    fluid = last["phase"][o1] == 1
    stats = read_stats(os.path.join(run_dir, "stats.csv"))
    t, ke, vmax = stats["time"], stats["kinetic_energy"], stats["max_speed"]
    at30 = int(np.argmin(np.abs(t - 30.0)))
    volume = fl.sum() * d ** 3
    return {
        "run": os.path.basename(os.path.normpath(run_dir)), "d_m": d, "t_end_s": float(t[-1]),
        "n_fluidised": int(fl.sum()), "soil2_fluidised": int((fl & soil2).sum()),
        "first_fluidised_s": float(t[stats["n_fluidised"] > 0][0]) if fl.any() else None,
        "volume_per_m_m3": volume / WIDTH, "volume_140m_m3": volume / WIDTH * SOURCE_WIDTH,
        "from_x_m": (float(x0[fl, 0].min()), float(x0[fl, 0].max())) if fl.any() else None,
        "fluid_lowest_x_m": float(x1[fluid, 0].min()) if fluid.any() else None,
        "runout_from_crown_m": float(CROWN_X - x1[fluid, 0].min()) if fluid.any() else None,
        "max_speed_30s_ms": float(vmax[at30]) if abs(t[at30] - 30.0) < 1.0 else None,
        "max_speed_ms": float(vmax.max()), "ke_end_over_peak": float(ke[-1] / ke.max()),
        "soil2_mean_disp_m": float(moved[soil2].mean()),
        "moved_max_m": float(moved[soil].max()),
        # where it slid: the soil that moved more than SLID metres, by where it started
        "slid_x_m": (float(x0[slid, 0].min()), float(x0[slid, 0].max())) if slid.any()
        else None,
        "slid_volume_per_m_m3": float(slid.sum() * d ** 3 / WIDTH),
        # the last time the kinetic energy was above 1e-3 of its peak: at rest after it
        "rest_from_s": float(t[np.flatnonzero(ke > 1e-3 * ke.max())[-1]])
        if ke.max() > 0.0 else 0.0,
        "lower_max_disp_m": float(moved[soil & (x0[:, 0] < 480.0)].max()),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run directories of the aso scene")
    args = parser.parse_args(argv)
    for run_dir in args.runs:
        r = row(run_dir)
        print(" ".join(f"{k}={(round(v, 3) if isinstance(v, float) else v)}"
                       for k, v in r.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
