"""Benchmark: the real coupled step of a landslide, against its solid and fluid parts alone.

The scene is ``jobs/scenes/landslide_slab.toml`` (the section 6.2 slope as a 3D slab,
periodic across the slope; 108,400 particles at d = 0.025 m, 70,480 of them soil). The
job

1. runs it once to ``--prep-time`` (0.6 s: the band has yielded and fluidised, fluid runs
   on the soil and the floor) and keeps that run's checkpoint in ``--prep`` (reused by the
   next invocation at any rank count: a restart at another rank count re-partitions);
2. derives two checkpoints from it: *solid alone* (the fluid rows dropped: the TLSPH step
   of the same soil) and *fluid alone* (the soil rows dropped: the IISPH step of the same
   fluid and the walls it wets);
3. branches each of the three for ``--steps`` steps and times them as a user waits for
   them: the step loop's clock (``stats.csv`` ``elapsed_s``), so every step's set-ups
   (AMG), migrations, halo, neighbour lists, checks, statistics and output are in.

It prints, in the long CSV format of ``jobs/benchlib.py``, for each of ``coupled``,
``solid_alone`` and ``fluid_alone``: the mean seconds per step over every step after the
first (the first row holds the branch's set-up, printed apart as ``startup_s``) with the
median beside, simulated seconds per wall second, the stages' seconds per step (mean),
moving particles (soil + fluid; walls apart) x steps per second per core, PPE and viscous
iterations, and the whole process's peak RSS of every rank during that run (the peak is
reset before each run; bytes per particle of all particles, walls included). Then the
coupled step against the sum of its parts: per step, ``coupled / (k solid + fluid)``
with ``k`` the coupled step's mean solid sub-steps (the solid alone steps at its own
limit, eq. (49)), and per simulated second, ``coupled / (solid + fluid)``.

    mpirun -n 2 .venv/bin/python jobs/bench_landslide.py --prep out/landslide_prep
    .venv/bin/python jobs/bench_landslide.py --prep out/landslide_prep --csv out/bench/bench.csv
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

import numpy as np

from decomposition import world
from decomposition.reduce import allgather, barrier, broadcast

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import (  # noqa: E402
    bytes_per_particle, peak_rss_mib, record, reset_peak_rss, step_figures, step_times)

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "scenes", "landslide_slab.toml")
STAGES = ("solid", "nonlocal", "fluid_assembly", "visc_solve", "ppe_solve", "fluid_halo",
          "phase_change", "migrate", "halo", "neighbours", "output")


def derive(src: str, dst: str, keep_phase: int) -> int:
    """Rank 0, serial: a copy of the checkpoint ``src`` with only the rows of phase
    ``keep_phase`` and the walls, each rank's rows kept in its segment (``/counts``
    recounted, the partitions kept: a restart at the writing rank count reads its own rows
    under them, at another it re-partitions). Returns the rows kept."""
    import h5py

    from parsph.scene.materials import PHASE_WALL

    with h5py.File(src, "r") as f, h5py.File(dst + ".tmp", "w") as g:
        for k, v in f.attrs.items():
            g.attrs[k] = v
        phase = f["fields/phase"][...]
        keep = (phase == keep_phase) | (phase == PHASE_WALL)
        bounds = np.concatenate([[0], np.cumsum(f["counts"][...])])
        g.create_dataset("counts", data=np.array(
            [keep[a:b].sum() for a, b in zip(bounds[:-1], bounds[1:])], dtype=np.int64))
        fields = g.create_group("fields")
        for name, dset in f["fields"].items():
            fields.create_dataset(name, data=dset[...][keep])
        for name in f:
            if name not in ("counts", "fields"):
                f.copy(f[name], g, name)
    os.replace(dst + ".tmp", dst)
    return int(keep.sum())


def branch(comm, scene_path, restart, out, steps, sets, petsc_args, profile=0) -> dict:
    """Collective: branch ``restart`` into ``out`` for ``steps`` steps; returns the figures
    of its ``stats.csv`` (rank 0; None elsewhere) and the peak RSS of every rank; with
    ``profile`` > 0, rank 0 prints that many functions of its profile (by own time)."""
    import h5py

    from parsph.io import read_stats
    from parsph.scene.loader import load_scene
    from parsph.step.run import run

    step0 = None
    if comm.rank == 0:
        with h5py.File(restart, "r") as f:
            step0 = int(f.attrs["step"])
    step0 = broadcast(comm, step0)
    scene = load_scene(scene_path, ["run.end_time=1e9", f"run.max_steps={step0 + steps}",
                                    "output.progress=false", *sets])
    exact = reset_peak_rss()
    barrier(comm)
    if profile and comm.rank == 0:  # by function (numba kernels appear by their Python name)
        import cProfile
        import pstats

        prof = cProfile.Profile()
        summary = prof.runcall(run, scene, out, comm=comm, petsc_args=petsc_args,
                               progress=False, restart=restart)
        stats = pstats.Stats(prof, stream=sys.stdout)
        print(f"== profile of rank 0 over {steps} steps, by own time", flush=True)
        stats.sort_stats("tottime").print_stats(profile)
    else:
        summary = run(scene, out, comm=comm, petsc_args=petsc_args, progress=False,
                      restart=restart)
    rss = allgather(comm, peak_rss_mib())
    exact = all(allgather(comm, exact))
    if comm.rank != 0:
        return None
    s = read_stats(os.path.join(out, "stats.csv"))
    _, step_s = step_times(s)  # the steps after the first (its row holds the set-up)
    later = slice(1, None)
    solid, fluid = (np.asarray(s[k], float)[later] for k in ("n_solid", "n_fluid"))
    dt = np.asarray(s["dt"], float)[later]
    wall = step_s.sum()
    fig = step_figures(s)
    fig.update({"simulated_s_per_wall_s": float(dt.sum() / wall),
                "dt_mean_s": float(dt.mean()),
                "moving_particles": float((solid + fluid).mean()),
                "solid_particles": float(solid.mean()),
                "fluid_particles": float(fluid.mean()),
                "moving_particle_steps_per_s_per_core": float(
                    (solid + fluid).sum() / wall / comm.size),
                "particle_steps_per_s_per_core": float(
                    summary["particles"] * len(step_s) / wall / comm.size)})
    for k in STAGES:
        if f"wall_s_{k}" in s:
            fig[f"s_per_step_{k}"] = float(np.asarray(s[f"wall_s_{k}"], float)[later].mean())
    for k in ("solid_substeps", "ppe_iterations", "visc_iterations"):
        if k in s:
            fig[f"{k}_mean"] = float(np.nanmean(np.asarray(s[k], float)[later]))
    fig.update({f"peak_rss_mib_rank{r}": float(m) for r, m in enumerate(rss)})
    fig["peak_rss_since_start"] = int(not exact)
    fig["bytes_per_particle"] = bytes_per_particle(rss, summary["particles"])
    fig["particles"] = int(summary["particles"])
    return fig


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=SCENE, help="the slab scene (TOML)")
    ap.add_argument("--d", type=float, default=None, help="particle size (m); default the "
                    "scene's (0.025)")
    ap.add_argument("--prep", default="out/landslide_prep",
                    help="directory of the run to --prep-time (made if missing, else reused)")
    ap.add_argument("--prep-time", type=float, default=0.6, help="simulated seconds")
    ap.add_argument("--steps", type=int, default=40, help="steps timed per branch")
    ap.add_argument("--parts", default="coupled,solid_alone,fluid_alone")
    ap.add_argument("--set", action="append", default=[], help="extra scene overrides")
    ap.add_argument("--csv", default=None, help="append the rows to this CSV file")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="print rank 0's N costliest functions of each branch (cProfile; "
                    "the figures of a profiled run are slower: profile apart)")
    args, petsc_args = ap.parse_known_args()
    petsc_args = [a for a in petsc_args if a != "--"]

    from parsph.scene.loader import load_scene
    from parsph.scene.materials import PHASE_FLUID, PHASE_SOLID
    from parsph.step.run import run

    comm = world()
    sets = ([f"domain.particle_size={args.d}"] if args.d else []) + list(args.set)
    prep = args.prep + (f"_d{args.d:g}" if args.d else "")
    ck = os.path.join(prep, "checkpoint.h5")
    if not os.path.isfile(ck):
        t0 = time.perf_counter()
        scene = load_scene(args.scene, [f"run.end_time={args.prep_time}",
                                        "output.progress=false", *sets])
        run(scene, prep, comm=comm, petsc_args=petsc_args, progress=False)
        if comm.rank == 0:
            print(f"prep: {prep} to t = {args.prep_time} s in {time.perf_counter() - t0:.0f} s",
                  flush=True)
    tmp = broadcast(comm, tempfile.mkdtemp(prefix="parsph-landslide-")
                    if comm.rank == 0 else None)
    cks = {"coupled": ck, "solid_alone": os.path.join(tmp, "solid.h5"),
           "fluid_alone": os.path.join(tmp, "fluid.h5")}
    if comm.rank == 0:
        derive(ck, cks["solid_alone"], PHASE_SOLID)
        derive(ck, cks["fluid_alone"], PHASE_FLUID)
    barrier(comm)
    figs = {}
    for part in args.parts.split(","):
        figs[part] = branch(comm, args.scene, cks[part], os.path.join(tmp, part), args.steps,
                            sets, petsc_args, args.profile)
    if comm.rank == 0:
        d = args.d or load_scene(args.scene, []).domain.particle_size
        for part, fig in figs.items():
            record(args.csv, f"landslide_d{d:g}_{part}", "parsph", 3, fig["particles"],
                   comm.size, fig)
        if {"coupled", "solid_alone", "fluid_alone"} <= set(figs):
            c, s, f = figs["coupled"], figs["solid_alone"], figs["fluid_alone"]
            k = c.get("solid_substeps_mean", 1.0)
            per_step = c["s_per_step_mean"] / (k * s["s_per_step_mean"] + f["s_per_step_mean"])
            # wall seconds per simulated second of each
            wc, ws, wf = (1.0 / x["simulated_s_per_wall_s"] for x in (c, s, f))
            record(args.csv, f"landslide_d{d:g}_against_parts", "parsph", 3, c["particles"],
                   comm.size, {"coupled_over_parts_per_step": per_step,
                               "coupled_over_parts_per_simulated_s": wc / (ws + wf),
                               "solid_substeps_mean": k})
            write_record(comm.size, figs, per_step, wc / (ws + wf))
        shutil.rmtree(tmp, ignore_errors=True)


def write_record(ranks, figs, over_parts, over_parts_simulated) -> None:
    """Rank 0: the figures record ``bench_landslide`` (``jobs/figures.py``; written where
    ``$PARSPH_FIGURES`` says): this rank count's figures as ``r{ranks}_*``, merged with
    the other rank count's of the record there, and ``speedup_1_to_2`` when both are in
    it from the same day."""
    import datetime
    import json

    from figures import record

    c = figs["coupled"]
    mine = {"s_per_step": c["s_per_step_mean"], "s_per_step_median": c["s_per_step_median"],
            "moving_psps_per_core": c["moving_particle_steps_per_s_per_core"],
            "over_parts": over_parts, "over_parts_simulated": over_parts_simulated,
            "bytes_per_particle": c["bytes_per_particle"],
            "solid_alone_s_per_step": figs["solid_alone"]["s_per_step_mean"],
            "fluid_alone_s_per_step": figs["fluid_alone"]["s_per_step_mean"],
            "date": datetime.date.today().isoformat()}
    mine.update({f"s_per_step_{k}": c[f"s_per_step_{k}"] for k in STAGES
                 if f"s_per_step_{k}" in c})
    mine.update({k: v for k, v in c.items() if k.startswith("peak_rss_mib_rank")})
    folder = os.environ.get("PARSPH_FIGURES")
    old, old_ranks = {}, 0
    path = os.path.join(folder, "bench_landslide.json") if folder else ""
    if path and os.path.isfile(path):
        with open(path, encoding="utf-8") as fh:
            rec = json.load(fh)
        old, old_ranks = rec["figures"], rec["ranks"]
    fig = {k: v for k, v in old.items() if not k.startswith(f"r{ranks}_")}
    fig.update({f"r{ranks}_{k}": v for k, v in mine.items()})
    fig.update(particles=c["particles"], moving=int(round(c["moving_particles"])),
               fluid=int(round(c["fluid_particles"])))
    if fig.get("r1_date") == fig.get("r2_date") and "r1_s_per_step" in fig \
            and "r2_s_per_step" in fig:
        fig["speedup_1_to_2"] = fig["r1_s_per_step"] / fig["r2_s_per_step"]
    else:
        fig.pop("speedup_1_to_2", None)
    record("bench_landslide", fig, ranks=max(ranks, old_ranks), source="jobs/bench_landslide.py",
           command="mpirun -n 2 python jobs/bench_landslide.py --steps 40; "
                   "python jobs/bench_landslide.py --steps 40")


if __name__ == "__main__":
    main()
