"""The stats.csv row of a step: counts, kinetic energy and its bound (the energy
budget), front, speed, each stage's own columns and wall seconds."""
from __future__ import annotations

import math

import numpy as np

from decomposition.reduce import global_reduce
from parsph.core.particles import PHASE_FLUID, PHASE_SOLID, PHASE_WALL
from parsph.step.pipeline import INFRASTRUCTURE


def kinetic_energy(ctx) -> tuple[float, float]:
    """Collective: ``(kinetic energy, mass)`` of the moving (non-wall) particles (J, kg;
    per metre in 2D)."""
    p, n = ctx.particles, ctx.particles.n_owned
    moving = p["phase"][:n] != PHASE_WALL
    v = p["v"][:n][moving]
    m = p["m"][:n][moving]
    # the reduction of stats_row (the same sum in the same order: a restarted run's
    # first energy budget is that of the uninterrupted run)
    ke = 0.5 * float((m * (v * v).sum(axis=1)).sum())
    (ke, mass), _, _ = global_reduce(ctx.comm, sums=(ke, float(m.sum())))
    return ke, mass


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


def stats_row(ctx, dt, stage_objs) -> dict:
    p, comm = ctx.particles, ctx.comm
    n = p.n_owned
    phase = p["phase"][:n]
    counts = np.array([n, (phase == PHASE_SOLID).sum(), (phase == PHASE_FLUID).sum(),
                       (phase == PHASE_WALL).sum(), 0.0, 0.0], dtype=np.float64)
    v = p["v"][:n]
    moving = phase != PHASE_WALL
    speed2 = (v * v).sum(axis=1)[moving]
    counts[4] = 0.5 * float((p["m"][:n][moving] * speed2).sum())
    counts[5] = float(p["m"][:n][moving].sum())
    e = np.asarray(ctx.scene.output.front_direction or (1.0,) + (0.0,) * (ctx.dim - 1), float)
    along = p["x"][:n][moving] @ (e / np.linalg.norm(e))
    counts, (n_max, front, v2max), (n_min,) = global_reduce(
        comm, sums=counts, mins=(n,),
        maxs=(n, float(along.max()) if len(along) else -math.inf,
              float(speed2.max()) if len(speed2) else 0.0))
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
