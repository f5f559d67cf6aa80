"""The stats.csv row of a step: counts, kinetic energy, the energy balance (docs/energy.md),
front, speed, each stage's own columns and wall seconds."""
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
    # the sums of stats_row (the same in the same order: a restarted run's energy
    # balance goes on as the uninterrupted run's)
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
    # (with the work the stages did in the step, ctx.work: one collective for all)
    counts, (n_max, front, v2max), (n_min,) = global_reduce(
        comm, sums=sums[:6] + tuple(float(w) for w in ctx.work), mins=(n,),
        maxs=(n, sums[6], sums[7]))
    n_max, n_min = int(n_max), int(n_min)
    ke = float(counts[4])
    vmax = math.sqrt(v2max)
    row = {"step": ctx.step, "time": ctx.time, "dt": dt,
           "n_particles": int(counts[0]), "n_solid": int(counts[1]), "n_fluid": int(counts[2]),
           "n_wall": int(counts[3]), "n_owned_min": n_min, "n_owned_max": n_max,
           "kinetic_energy": ke, "max_speed": vmax, "front": front, "step_work": counts[6:9]}
    for s in stage_objs:
        row.update(s.stats())
    for name, seconds in ctx.timers.items():
        row[f"wall_s_{name}"] = seconds
    return row


def stats_columns(stages) -> list[str]:
    """stats.csv columns: counts, energy, each stage's own columns, wall seconds per stage,
    and the wall seconds since the run started (``elapsed_s``, at the end of the step)."""
    cols = ["step", "time", "dt", "n_particles", "n_solid", "n_fluid", "n_wall",
            "n_owned_min", "n_owned_max", "kinetic_energy", *EnergyBalance.COLUMNS,
            "max_speed", "front"]
    cols += [c for s in stages for c in getattr(s, "stats_columns", ())]
    cols += [f"wall_s_{name}" for name, _ in INFRASTRUCTURE]
    cols += [f"wall_s_{s.name}" for s in stages] + ["wall_s_output", "elapsed_s"]
    return cols


class EnergyBalance:
    r"""The run's mechanical energy balance (docs/energy.md): after step n,

    .. math:: E_n = K_n + \tfrac12 (S_{n-1} + S_n) - W_{b,n} - W_{c,n} - W_{hg,n},

    :math:`K_n` the kinetic energy of the moving particles, :math:`S` the stored energy
    (elastic, of the Hencky and Drucker-Prager rows, and the potential of
    ``solid.ambient_pressure``; Cam-Clay's pressure-dependent elasticity has no energy
    function and is left out), and the work since t = 0 of the body force (gravity and
    the earthquake, :meth:`Context.body_acceleration`), of the Dirichlet constraints and
    of the solid's hourglass control (:func:`parsph.core.energy.step_work`; the
    hourglass force has no energy function either: its store is booked as its work). The
    velocities of step n are those that moved the particles from :math:`\mathbf x_{n-1}`
    to :math:`\mathbf x_n` (symplectic Euler), so the stored energy is taken at the same
    time, the mean of its values at both ends of the step: for a linear elastic body
    this leaves an oscillation of :math:`O((\omega\Delta t)^2)` where the end value
    would leave one of :math:`O(\omega\Delta t)`. Nothing else supplies energy:
    plasticity, viscosity, contact, JST damping, the pressure projection and the phase
    change can only lower E, so a rise of E is energy the numerics made.

    Columns: ``work_body``, ``work_constraints``, ``work_hourglass`` (J, since t = 0),
    ``mechanical_energy`` (J), ``energy_rise`` (J, this step's), ``energy_rise_max`` (the
    largest rise of a step so far over the largest kinetic energy so far) and
    ``energy_gain_max`` (the largest rise of E over any stretch of steps so far,
    :math:`\max_n (E_n - \min_{k\le n} E_k)`, over the same). A restart takes the state
    from the checkpoint (:meth:`state`): the columns go on as in the uninterrupted run.
    """

    COLUMNS = ("work_body", "work_constraints", "work_hourglass", "mechanical_energy",
               "energy_rise", "energy_rise_max", "energy_gain_max")
    #: checkpoint attributes of :meth:`state`
    STATE = ("energy_work_body", "energy_work_constraints", "energy_work_hourglass",
             "energy_min", "energy_kinetic_peak", "energy_rise_peak", "energy_gain_peak")

    def __init__(self, ke: float, stored: float = 0.0, meta=None):
        """``ke``, ``stored``: the kinetic and the stored energy at the start (a fresh
        solid is unstrained: 0); ``meta``: a checkpoint's attributes (a restart) or None."""
        meta = meta or {}
        get = (lambda k, default: float(meta.get(k, default)))
        self.work = [get(k, 0.0) for k in self.STATE[:3]]
        self.stored = stored
        self.energy = self._total(ke, stored)
        self.low = get("energy_min", self.energy)
        self.ke_peak = max(get("energy_kinetic_peak", ke), ke)
        self.rise_peak = get("energy_rise_peak", 0.0)
        self.gain_peak = get("energy_gain_peak", 0.0)

    def _total(self, ke, stored):
        return ke + 0.5 * (self.stored + stored) - self.work[0] - self.work[1] - self.work[2]

    def _relative(self, value):
        if self.ke_peak > 0.0:
            return value / self.ke_peak
        return 0.0 if value <= 0.0 else math.inf

    def update(self, row: dict, stored: float) -> None:
        """Add this step's work (``row["step_work"]``, taken out) and write the columns
        into ``row``; ``stored``: the stored energy at the end of the step."""
        for k, w in enumerate(row.pop("step_work")):
            self.work[k] += w
        ke = row["kinetic_energy"]
        energy = self._total(ke, stored)
        rise = energy - self.energy
        self.energy, self.stored = energy, stored
        self.low = min(self.low, energy)
        self.ke_peak = max(self.ke_peak, ke)
        self.rise_peak = max(self.rise_peak, rise)
        self.gain_peak = max(self.gain_peak, energy - self.low)
        row.update(work_body=self.work[0], work_constraints=self.work[1],
                   work_hourglass=self.work[2], mechanical_energy=energy, energy_rise=rise,
                   energy_rise_max=self._relative(self.rise_peak),
                   energy_gain_max=self._relative(self.gain_peak))

    def summary(self) -> dict:
        """The run's figures: the largest rise of a step and over any stretch of steps,
        relative to the peak kinetic energy."""
        return {"energy_rise_max": self._relative(self.rise_peak),
                "energy_gain_max": self._relative(self.gain_peak)}

    def state(self) -> dict:
        """Checkpoint attributes (:data:`STATE`)."""
        return dict(zip(self.STATE, (*self.work, self.low, self.ke_peak, self.rise_peak,
                                     self.gain_peak)))
