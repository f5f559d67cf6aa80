"""Kinematic stage: particles move with their velocity and feel no force.

Used by ``run.mode = "kinematic"`` (previews, benchmarks of the distributed machinery,
tests of migration and halos on a moving set). Walls stay fixed.
"""
from __future__ import annotations

import numpy as np

from decomposition.reduce import global_max
from parsph.core.particles import max_speed
from parsph.scene.materials import PHASE_WALL


class Kinematics:
    name = "kinematics"

    def __init__(self, ctx):
        self.cfl = ctx.scene.run.cfl

    def max_dt(self, ctx) -> float:
        """CFL limit of eq. (49), fluid part: C d / |v|_max."""
        p = ctx.particles
        vmax = global_max(ctx.comm, max_speed(p["v"], p.n_owned))
        return self.cfl * ctx.d / vmax if vmax > 0 else np.inf

    def step(self, ctx, dt: float) -> None:
        p = ctx.particles
        n = p.n_owned
        moving = p["phase"][:n] != PHASE_WALL
        p["x"][:n][moving] += dt * p["v"][:n][moving]

    def stats(self) -> dict:
        return {}
