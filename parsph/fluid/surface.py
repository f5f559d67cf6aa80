"""The free-surface fluid rows' contact with walls and the soil (``fluid.surface_wall_contact``).

A free-surface row (p = 0, or a pocket's soil pressure) is held off a wall or the soil
only by their extrapolated pressure, too weak for a lone particle: it would sink in until
its density flags it interior and the PPE throws it out. :func:`parsph.core.contact.
wall_contact` holds it off instead, with Coulomb friction from the Bingham yield's
p tan(phi'), p from the normal impulses of the boundary's pressure and of the contact
(docs/iisph.md).

Against the soil the contact is an impulse between two bodies of comparable mass: the
fluid particle takes its share of it and the solid rows near it the rest (``react``,
summed on their owners, halo rows included), so that momentum is kept and the kinetic
energy can only fall. The solid rows move with the velocity the PPE gave them this step
(their owners' values, refreshed on the halo rows).
"""
from __future__ import annotations

import math

import numpy as np

from parsph.core.contact import INSTANT, NO_MASS, wall_contact


def surface_contact(ctx, vnew, own_fluid, free, fluid, solid, strong, m, push_grad, rho0,
                    dt, table, indptr, indices) -> tuple[int, np.ndarray | None]:
    """Collective: the contact of the owned free-surface fluid rows, in place on ``vnew``
    (their velocities after the pressure step, shape (n_owned, dim)).

    ``strong`` (the same on every rank): some rank has a solid row in the fluid's reach
    (a type-II row). Then the solid rows' velocities ``v`` on the halo are refreshed
    first, and each owned solid row's ``v`` takes the reactions of the contacts near it
    (the halo rows' summed on their owners). Returns ``(contacts, reaction)``: the
    number of rows in contact and the momentum the owned rows received (kg m/s per
    row, shape (n_owned, dim); None without ``strong``).
    """
    p, n, dim = ctx.particles, ctx.n_owned, ctx.dim
    masses = NO_MASS
    if strong:
        ctx.update_halo(["v"])  # the solid rows' velocities after the PPE
        react = np.zeros((len(fluid), dim))
        masses = (np.ascontiguousarray(p["inv_mass"]), np.ascontiguousarray(m), react)
    surface = np.flatnonzero(own_fluid & (free[:n] == 1))
    contacts = 0
    if len(surface):
        mu = table["tan_phi"][p["material"][surface]]
        push = -dt * push_grad[surface] / rho0[surface, None]  # the pressure impulse
        # partners move with their present v (walls: still): the same on owned and halo
        # rows, whatever the partition
        moving = np.where((solid > 0)[:, None], p["v"], 0.0)
        contacts = wall_contact(p["x"], vnew, surface, surface, 1 - fluid, moving, indptr,
                                indices, ctx.h, ctx.d, dim, mu, push,
                                np.full(len(fluid), -1.0), math.inf, *masses, *INSTANT)
    if not strong:
        return contacts, None
    reaction = react[:n].copy()
    halo = ctx.halo
    if halo.n_send or halo.n_halo:  # (a rank that exchanges nothing posts nothing)
        reaction += halo.reverse_add({"r": react[n:]})["r"]
    p["v"][:n] += p["inv_mass"][:n] * reaction
    return contacts, reaction
