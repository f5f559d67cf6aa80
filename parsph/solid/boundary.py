r"""Solid boundary conditions (section 3.1, "as in Morikawa and Asai (2021)").

- Essential (Dirichlet) conditions: ``[[constraints]]`` with ``kind = "velocity"``
  prescribe chosen velocity components of the particles whose reference position lies in
  a box, every step, after the momentum update (so F, eq. (8), and x follow them).
- Initial velocity profiles (``kind = "initial"``), named, with parameters, no
  expressions: ``uniform``, ``cantilever_mode1`` (first bending mode of a clamped-free
  beam, Gray, Monaghan & Swift 2001), ``rigid_rotation`` (about the z axis).
- Wall contact: non-penetration plus Coulomb friction against wall particles (phase 2),
  enforced on the velocity after the momentum update (:func:`parsph.core.contact.wall_contact`).
"""
from __future__ import annotations

import math

import numpy as np


#: Root of cos(kL) cosh(kL) = -1, first mode of a clamped-free beam.
BETA1 = 1.8751040687119611


def _selected(X, c, body=None, names=()):
    """The rows a constraint selects: reference position in its box (if it has one) and
    body among its ``bodies`` (if it names any; ``body`` the rows' body indices into
    ``names``, the scene's body names in order)."""
    sel = np.ones(len(X), dtype=bool)
    if c.lo:
        lo, hi = np.asarray(c.lo), np.asarray(c.hi)
        sel &= np.all((X >= lo) & (X <= hi), axis=1)
    if c.bodies:
        wanted = [k for k, name in enumerate(names) if name in c.bodies]
        sel &= np.isin(body, wanted)
    return sel


def cantilever_mode1(x, root, length):
    r"""Shape of the first clamped-free bending mode, 1 at the tip.

    :math:`f(s) = \cosh ks - \cos ks - \frac{\cosh kL + \cos kL}{\sinh kL + \sin kL}
    (\sinh ks - \sin ks)`, :math:`s = x - x_{root}` (0 for s < 0), :math:`kL = 1.8751`.
    """
    k = BETA1 / length
    s = np.clip(np.asarray(x, dtype=float) - root, 0.0, None)
    kl = BETA1
    a = (math.cosh(kl) + math.cos(kl)) / (math.sinh(kl) + math.sin(kl))

    def f(t):
        return np.cosh(k * t) - np.cos(k * t) - a * (np.sinh(k * t) - np.sin(k * t))

    return f(s) / f(length)


def initial_velocity(constraints, X, v, solid, body=None, names=()) -> None:
    """Apply the ``kind = "initial"`` constraints to ``v`` (rows where ``solid``; ``body``
    and ``names`` as for :func:`_selected`)."""
    dim = X.shape[1]
    for c in constraints:
        if c.kind != "initial":
            continue
        sel = _selected(X, c, body, names) & solid
        if c.profile == "uniform":
            v[sel] = np.asarray(c.velocity)
        elif c.profile == "cantilever_mode1":
            v[sel, dim - 1] = c.tip_speed * cantilever_mode1(X[sel, 0], c.root, c.length)
        elif c.profile == "rigid_rotation":
            r = X[sel, :2] - np.asarray(c.centre)[:2]
            v[sel, 0] = -c.omega * r[:, 1]
            v[sel, 1] = c.omega * r[:, 0]


def velocity_masks(constraints, X, solid, body=None, names=()):
    """(mask (N, dim) of prescribed components, values (N, dim)) for ``kind = "velocity"``
    (``body`` and ``names`` as for :func:`_selected`)."""
    n, dim = X.shape
    mask = np.zeros((n, dim), dtype=bool)
    value = np.zeros((n, dim))
    for c in constraints:
        if c.kind != "velocity":
            continue
        sel = _selected(X, c, body, names) & solid
        axes = np.asarray(c.axes if c.axes else (True,) * dim, dtype=bool)
        for a in range(dim):
            if axes[a]:
                mask[sel, a] = True
                value[sel, a] = c.velocity[a]
    return mask, value
