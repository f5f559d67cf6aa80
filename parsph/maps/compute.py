"""``parsph maps``: the collective pass over a run's frames, the rasters and summary.json.

Each frame is read in shares (:class:`parsph.io.frames.FrameReader`); every rank sends
each particle of its share to the rank(s) that own the rows its footprint overlaps
(:func:`decomposition.exchange.migrate`; a particle near a block's edge goes to both),
and each rank bins what it receives into its own rows (:func:`.binning.bin_frame`). So
no rank holds more of the grid than its rows, nor more particles than the chunk it reads
and those that fall on its rows. The rasters are written from every rank's rows into
one file each (:func:`parsph.io.geotiff.write_blocks`); the pictures are drawn on rank 0
from the files, read at a stride (:mod:`.render`). Definitions: docs/maps.md.
"""
from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass

import numpy as np

from decomposition.comm import collective, on_root
from decomposition.exchange import migrate
from decomposition.reduce import broadcast, global_sum
from parsph.errors import ParsphError
from parsph.maps.binning import QQ, bin_frame, row_span
from parsph.maps.grid import MapGrid, grid_for
from parsph.maps.summary import peak, summarise

log = logging.getLogger("parsph")

#: The rasters: file stem -> (title, unit) for the pictures.
RASTERS = {
    "deposit_thickness": ("deposit thickness", "m"),
    "erosion_depth": ("erosion depth", "m"),
    "max_flow_depth": ("maximum flow depth", "m"),
    "max_speed": ("maximum speed", "m/s"),
    "arrival_time": ("arrival time", "s"),
    "surface_initial": ("surface, first frame", "m"),
    "surface_final": ("surface, last frame", "m"),
}
#: Default speed above which material counts as flowing (m/s).
SPEED_THRESHOLD = 0.1
#: Default thickness from which a cell counts as eroded or deposited, in particle sizes.
MIN_THICKNESS_D = 0.25
#: Which material can be flowing (faster than the threshold): any, or only the fluid.
FLOWING = ("any", "fluid")
_WALL, _FLUID = 2, 1


@dataclass(frozen=True)
class Plan:
    """What rank 0 checked and every rank works from."""

    run_dir: str
    out: str
    d: float
    frames: tuple[tuple[int, float], ...]
    grid: MapGrid
    v_min: float
    h_min: float
    fluidised: bool
    scene: str
    fluid_only: bool


def _plan(run_dir, cell, scene_path, out, speed_threshold, min_thickness, flowing, ranks,
          ranks_on_node, node_memory) -> Plan:
    """Rank 0: every check before any work (ParsphError naming what to change)."""
    from parsph.io.hdf5 import _index, open_run
    from parsph.scene.loader import load_scene

    if not os.path.isdir(run_dir):
        raise ParsphError(f"{run_dir}: no such directory; give the output directory of a "
                          "run (`parsph run SCENE --out DIR`)")
    with open_run(run_dir) as f:
        frames = tuple((fr.step, fr.time) for fr in _index(f))
        attrs = dict(f.attrs)
        last = f"frames/{frames[-1][0]:06d}" if frames else None
        fluidised = last is not None and "fluidised" in f[last]
        missing = [k for k in ("x", "v", "phase") if last is not None and k not in f[last]]
    if not frames:
        raise ParsphError(f"{run_dir}: particles.h5 holds no frame yet; wait for the run's "
                          "first output (output.every) or check that the run started")
    if missing:
        raise ParsphError(f"{run_dir}: the frames lack {missing}; they were not written by "
                          "parsph run")
    dim = int(attrs.get("dim", 0))
    if dim != 3:
        raise ParsphError(f"{run_dir} holds a {dim}D run; maps are rasters over x, y of a 3D "
                          "run (z up). For a 2D run use `parsph plot` or [[probes]] lines of "
                          "deposit depth (docs/probes.md)")
    d = float(attrs.get("particle_size", 0.0))
    if not d > 0:
        raise ParsphError(f"{run_dir}: particles.h5 has no particle_size attribute; it was "
                          "not written by parsph run")
    path = scene_path or str(attrs.get("scene_source", ""))
    if not path or not os.path.isfile(path):
        raise ParsphError(f"{run_dir} was written from the scene file '{path}', which is not "
                          "there now; give it with --scene FILE (its height map gives the grid)")
    scene = load_scene(path)
    if scene.name != attrs.get("scene", scene.name):
        raise ParsphError(f"{path} is scene '{scene.name}', but {run_dir} was written by scene "
                          f"'{attrs.get('scene')}'; give that scene's file with --scene")
    grid = grid_for(scene, cell, ranks, ranks_on_node, node_memory)
    v_min = SPEED_THRESHOLD if speed_threshold is None else float(speed_threshold)
    h_min = MIN_THICKNESS_D * d if min_thickness is None else float(min_thickness)
    for name, value in (("--speed-threshold", v_min), ("--min-thickness", h_min)):
        if not (math.isfinite(value) and value >= 0):
            raise ParsphError(f"{name} {value!r}: give a number >= 0")
    if flowing not in FLOWING:
        raise ParsphError(f"--flowing {flowing!r}: give one of {', '.join(FLOWING)}")
    out = out or os.path.join(run_dir, "maps")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise ParsphError(f"cannot create the maps directory {out}: {exc.strerror}; give a "
                          "writable --out") from None
    return Plan(run_dir=run_dir, out=out, d=d, frames=frames, grid=grid, v_min=v_min,
                h_min=h_min, fluidised=fluidised, scene=scene.name,
                fluid_only=flowing == "fluid")


def _images(x, speed, kind, grid: MapGrid, half: float):
    """The particles and, on a periodic axis, their images shifted by the period whose
    footprints reach the cells past the other face (so that a cell cut by a periodic face
    is filled from both sides; one period at most)."""
    for axis, period in ((0, grid.period_x), (1, grid.period_y)):
        if period is None:
            continue
        lo, hi = period
        length = hi - lo
        start, end = (grid.west, grid.east) if axis == 0 else (grid.south, grid.north)
        near_lo = x[:, axis] - lo < (end - hi) + half  # its image at + length is on the grid
        near_hi = hi - x[:, axis] < (lo - start) + half
        if not (near_lo.any() or near_hi.any()):
            continue
        shift_lo, shift_hi = x[near_lo].copy(), x[near_hi].copy()
        shift_lo[:, axis] += length
        shift_hi[:, axis] -= length
        x = np.concatenate([x, shift_lo, shift_hi])
        speed = np.concatenate([speed, speed[near_lo], speed[near_hi]])
        kind = np.concatenate([kind, kind[near_lo], kind[near_hi]])
    return x, speed, kind


def _route(comm, x, speed, kind, grid: MapGrid, half: float):
    """Collective: every particle to the rank(s) owning the rows its footprint overlaps."""
    x, speed, kind = _images(x, speed, kind, grid, half)
    jlo, jhi = row_span(x[:, 1], half, grid.south, grid.cell, grid.ny)
    keep = (jlo <= jhi) & (x[:, 0] + half > grid.west) & (x[:, 0] - half < grid.east)
    idx = np.flatnonzero(keep)
    first = grid.owner(jlo[idx], comm.size)
    count = grid.owner(jhi[idx], comm.size) - first + 1
    rep = np.repeat(np.arange(idx.size), count)
    starts = np.repeat(np.cumsum(count) - count, count)
    dest = first[rep] + (np.arange(rep.size) - starts)
    rows = idx[rep]
    return migrate(comm, {"x": np.ascontiguousarray(x[rows]), "s": speed[rows],
                          "k": kind[rows]}, dest)


def _pass(comm, plan: Plan, j0: int, nrows: int):
    """Collective: the running fields of this rank's rows over every frame."""
    from parsph.io.frames import FrameReader

    grid, half, nx = plan.grid, 0.5 * plan.d, plan.grid.nx
    shape = (nrows, nx)
    w0, wflow_max = np.zeros(shape, np.int64), np.zeros(shape, np.int64)
    top0 = np.full(shape, -np.inf)
    vmax_run, arrival = np.zeros(shape), np.full(shape, np.nan)
    w_all, w_flow = np.zeros(shape, np.int64), np.zeros(shape, np.int64)
    vmax, top, top_wall = np.zeros(shape), np.full(shape, -np.inf), np.full(shape, -np.inf)
    best = (0.0, 0.0)
    counts = np.zeros(3)  # last frame: material, fluid, fluidised particles
    last_k = len(plan.frames) - 1
    with FrameReader(plan.run_dir, comm) as reader:
        for k, (step, time) in enumerate(plan.frames):
            w_all[:] = 0
            w_flow[:] = 0
            vmax[:] = 0.0
            top[:] = -np.inf
            top_wall[:] = -np.inf
            names = ["x", "v", "phase"] + (["fluidised"] if k == last_k and plan.fluidised else [])
            for chunk in reader.chunks(step, names):
                x = np.ascontiguousarray(chunk["x"], dtype=np.float64)
                speed = np.sqrt((np.asarray(chunk["v"], dtype=np.float64) ** 2).sum(axis=1))
                phase = chunk["phase"]
                kind = np.where(phase == _WALL, 0, np.where(phase == _FLUID, 2, 1)).astype(np.uint8)
                material = kind != 0
                if material.any():
                    s = float(speed[material].max())
                    if s > best[0]:
                        best = (s, time)
                if k == last_k:
                    counts += [material.sum(), (kind == 2).sum(),
                               (chunk["fluidised"] == 1).sum() if plan.fluidised else 0]
                got = _route(comm, x, speed, kind, grid, half)
                bin_frame(got["x"], got["s"], got["k"], half, grid.west, grid.south,
                          grid.cell, nx, j0, nrows, plan.v_min, plan.fluid_only, w_all,
                          w_flow, vmax, top, top_wall)
            # the surface: the material's top, the walls' (the terrain) where none
            np.copyto(top, top_wall, where=np.isinf(top))
            if k == 0:
                w0[:], top0[:] = w_all, top
            np.maximum(wflow_max, w_flow, out=wflow_max)
            np.maximum(vmax_run, vmax, out=vmax_run)
            arrival[(w_flow > 0) & np.isnan(arrival)] = time
            log.debug("maps: frame %d of %d (step %d, t = %.6g s)", k + 1, len(plan.frames),
                      step, time)
    del w_flow, vmax, top_wall
    for surface in (top0, top):
        surface[np.isinf(surface)] = np.nan  # no particle over the cell
    return dict(w0=w0, wend=w_all, wflow_max=wflow_max, top0=top0, topend=top,
                vmax=vmax_run, arrival=arrival), best, counts


def make_maps(comm, run_dir, cell=None, scene=None, out=None, speed_threshold=None,
              min_thickness=None, flowing="any", pictures=True) -> dict:
    """Collective: the rasters, pictures and ``summary.json`` of a run (docs/maps.md).

    Parameters
    ----------
    comm : mpi4py communicator
        Every rank calls; each computes and writes its own rows of the grid.
    run_dir : str
        The run's output directory (``particles.h5``).
    cell : float, optional
        Cell size (m); default the DEM's (required without a height map).
    scene : str, optional
        The scene file, if not where the run read it (``scene_source`` in particles.h5).
    out : str, optional
        Directory of the outputs (default ``run_dir/maps``).
    speed_threshold : float, optional
        Speed above which material is flowing (m/s; default :data:`SPEED_THRESHOLD`).
    min_thickness : float, optional
        Erosion or deposit from which a cell counts for the areas, the crown, the toe and
        the centroids (m; default ``d / 4``).
    flowing : {"any", "fluid"}
        Which material, when faster than ``speed_threshold``, is flowing: any solid or
        fluid, or only the fluid (the debris of the phase change: in a scene shaken by an
        earthquake the whole slope moves).
    pictures : bool
        Also draw the PNG pictures.

    Returns
    -------
    dict
        The summary (also in ``out/summary.json``), with ``files``: the paths written.

    Raises
    ------
    ParsphError
        On every rank, before any work, for a missing run or scene, a 2D run, a bad
        cell size or a grid too large for the memory.
    """
    from parsph.io.geotiff import geotags, write_blocks
    from parsph.scene.budget import node_memory_bytes, ranks_on_this_node

    on_node = ranks_on_this_node(comm)
    plan = on_root(comm, _plan, os.fspath(run_dir), cell, scene, out, speed_threshold,
                   min_thickness, flowing, comm.size, on_node, node_memory_bytes())
    grid = plan.grid
    log.info("maps of '%s': %d frames, grid %d x %d cells of %g m (%s)", plan.scene,
             len(plan.frames), grid.nx, grid.ny, grid.cell, grid.source)
    j0, j1 = grid.rows(comm.rank, comm.size)
    f, (speed, when), counts = _pass(comm, plan, j0, j1 - j0)
    counts = global_sum(comm, counts)
    speed, when = peak(comm, speed, when)

    scale = plan.d ** 3 / (QQ * grid.cell ** 2)  # m of thickness per share unit

    def raster(name):  # one at a time: a rank holds its running fields and one raster
        if name == "deposit_thickness":
            return np.maximum(f["wend"] - f["w0"], 0) * scale
        if name == "erosion_depth":
            return np.maximum(f["w0"] - f["wend"], 0) * scale
        if name == "max_flow_depth":
            return f["wflow_max"] * scale
        return f[{"max_speed": "vmax", "arrival_time": "arrival", "surface_initial": "top0",
                  "surface_final": "topend"}[name]]

    summary = {"scene": plan.scene, "frames": len(plan.frames),
               "time_first_s": plan.frames[0][1], "time_last_s": plan.frames[-1][1],
               "particle_size_m": plan.d, "particle_volume_m3": plan.d ** 3,
               "volume_fluidised_m3": float(counts[2]) * plan.d ** 3,
               "volume_fluid_m3": float(counts[1]) * plan.d ** 3,
               "volume_material_m3": float(counts[0]) * plan.d ** 3,
               "peak_speed_ms": speed, "peak_speed_time_s": when}
    summary.update(summarise(comm, grid, j0, raster("erosion_depth"),
                             raster("deposit_thickness"), f["wend"] * scale, f["top0"],
                             f["topend"], plan.h_min))
    summary["volume_outside_grid_m3"] = summary["volume_material_m3"] - \
        summary["volume_in_grid_end_m3"]
    summary.update(speed_threshold_ms=plan.v_min, flowing="fluid" if plan.fluid_only else "any",
                   min_thickness_m=plan.h_min, grid=grid.describe())

    files = []
    tags = geotags(grid.georef, grid.west, grid.north, grid.cell, grid.same_as_dem)
    for name in RASTERS:
        path = os.path.join(plan.out, f"{name}.tif")
        write_blocks(comm, path, grid.ny, grid.nx, j0, raster(name).astype(np.float32), tags)
        files.append(path)
    del f
    with collective(comm):
        if comm.rank == 0:
            if pictures:
                from parsph.maps.render import draw_all

                files += draw_all(plan.out, grid, RASTERS)
            path = os.path.join(plan.out, "summary.json")
            with open(path, "w") as fh:
                json.dump(summary, fh, indent=2)
                fh.write("\n")
            files.append(path)
    summary["files"] = broadcast(comm, files)
    return summary
