"""The stats.csv row of a step: counts, kinetic energy and its bound (the energy
budget), front, speed, each stage's own columns and wall seconds."""
from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from decomposition.reduce import global_reduce
from parsph.core.particles import PHASE_FLUID, PHASE_SOLID, PHASE_WALL
from parsph.step.pipeline import INFRASTRUCTURE


def kinetic_energy(ctx) -> tuple[float, float]:
    """Collective: ``(kinetic energy, mass)`` of the moving (non-wall) particles (J, kg;
    per metre in 2D)."""
    p, n = ctx.particles, ctx.particles.n_owned
    # the sums of stats_row (the same in the same order: a restarted run's first energy
    # budget is that of the uninterrupted run)
    sums = _row_sums(p["phase"], p["v"], p["m"], p["x"], n, np.zeros(ctx.dim))
    (ke, mass), _, _ = global_reduce(ctx.comm, sums=(sums[4], sums[5]))
    return ke, mass


@njit(cache=True, error_model="numpy")
def _row_sums(phase, v, m, x, n, e):
    """One pass over the first ``n`` rows: ``(n, n_solid, n_fluid, n_wall, kinetic energy,
    mass, front, max speed^2)``, the last four over the moving (non-wall) rows, the front
    the largest ``x . e`` (-inf if none moves). The numpy form had cost about 60 us of a
    2D coupled step of 1,100 particles (jobs/bench_overhead.py)."""
    counts = np.zeros(3)
    ke = mass = 0.0
    front = -np.inf
    v2max = 0.0
    for i in range(n):
        ph = phase[i]
        if ph == PHASE_SOLID or ph == PHASE_FLUID or ph == PHASE_WALL:
            counts[ph] += 1.0
        if ph == PHASE_WALL:
            continue
        s = 0.0
        a = 0.0
        for k in range(v.shape[1]):
            s += v[i, k] * v[i, k]
            a += x[i, k] * e[k]
        ke += m[i] * s
        mass += m[i]
        front = max(front, a)
        v2max = max(v2max, s)
    return (float(n), counts[PHASE_SOLID], counts[PHASE_FLUID], counts[PHASE_WALL],
            0.5 * ke, mass, front, v2max)


def energy_budget(ke0, ke1, ee0, ee1, mass, g, dt, work=0.0) -> tuple[float, float]:
    r"""``(bound, ratio)`` of one step: what gravity, the stored elastic energy and the
    density term of the PPE can supply to the kinetic energy over ``dt``,
    :math:`|g|\sqrt{2 M \max(K_0, K_1)}\,\Delta t + \max(0, E_0 - E_1) + W_\alpha` (J; the
    first term bounds :math:`\int \sum m\,\mathbf g\cdot\mathbf v\,dt` by
    Cauchy-Schwarz; :math:`W_\alpha` = ``work``, the work of the pressure on the expansion
    the density term of eq. (32) asks of compressed particles), and the kinetic energy's
    rise over it, :math:`(K_1 - K_0) / \text{bound}`: a step that makes energy has a ratio
    above 1 (docs/coupling.md)."""
    bound = g * math.sqrt(2.0 * mass * max(ke0, ke1, 0.0)) * dt + max(ee0 - ee1, 0.0) \
        + max(work, 0.0)
    rise = ke1 - ke0
    if bound <= 0.0:
        return 0.0, (0.0 if rise <= 0.0 else math.inf)
    return bound, rise / bound


@functools.lru_cache(maxsize=8)
def _unit(direction: tuple, dim: int) -> np.ndarray:
    """The unit vector along ``output.front_direction`` (default +x); shared, not to be
    written to (a read-only array would be another type for numba)."""
    e = np.asarray(direction or (1.0,) + (0.0,) * (dim - 1), float)
    return e / np.linalg.norm(e)


def stats_row(ctx, dt, stage_objs) -> dict:
    p, comm = ctx.particles, ctx.comm
    n = p.n_owned
    sums = _row_sums(p["phase"], p["v"], p["m"], p["x"], n,
                     _unit(tuple(ctx.scene.output.front_direction), ctx.dim))
    counts, (n_max, front, v2max), (n_min,) = global_reduce(
        comm, sums=sums[:6], mins=(n,), maxs=(n, sums[6], sums[7]))
    n_max, n_min = int(n_max), int(n_min)
    ke = float(counts[4])
    vmax = math.sqrt(v2max)
    row = {"step": ctx.step, "time": ctx.time, "dt": dt,
           "n_particles": int(counts[0]), "n_solid": int(counts[1]), "n_fluid": int(counts[2]),
           "n_wall": int(counts[3]), "n_owned_min": n_min, "n_owned_max": n_max,
           "kinetic_energy": ke, "max_speed": vmax, "front": front, "mass": float(counts[5])}
    for s in stage_objs:
        row.update(s.stats())
    for name, seconds in ctx.timers.items():
        row[f"wall_s_{name}"] = seconds
    return row


def stats_columns(stages) -> list[str]:
    """stats.csv columns: counts, energy, each stage's own columns, wall seconds per stage,
    and the wall seconds since the run started (``elapsed_s``, at the end of the step)."""
    cols = ["step", "time", "dt", "n_particles", "n_solid", "n_fluid", "n_wall",
            "n_owned_min", "n_owned_max", "kinetic_energy", "energy_bound", "energy_ratio",
            "max_speed", "front"]
    cols += [c for s in stages for c in getattr(s, "stats_columns", ())]
    cols += [f"wall_s_{name}" for name, _ in INFRASTRUCTURE]
    cols += [f"wall_s_{s.name}" for s in stages] + ["wall_s_output", "elapsed_s"]
    return cols
