"""Diagnostic stages: fields computed for output after each refresh of the halo."""
from __future__ import annotations

from parsph.core.density import density_summation


class DensityStage:
    """SPH density summation, eq. (33): ``rho_i = sum_j m_j W(r_ij, h)`` (self included)."""

    name = "density"

    def __init__(self, ctx):
        ctx.particles.add_field("rho")

    def max_dt(self, ctx) -> float:
        return float("inf")

    def after_refresh(self, ctx) -> None:
        p = ctx.particles
        rho = density_summation(p["x"], p["m"], ctx.indptr, ctx.indices, ctx.h, ctx.dim)
        p["rho"][: p.n_owned] = rho

    def stats(self) -> dict:
        return {}
