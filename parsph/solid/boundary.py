r"""Solid boundary conditions (section 3.1, "as in Morikawa and Asai (2021)").

- Essential (Dirichlet) conditions: ``[[constraints]]`` with ``kind = "velocity"``
  prescribe chosen velocity components of the particles whose reference position lies in
  a box, every step, after the momentum update (so F, eq. (8), and x follow them).
- Initial velocity profiles (``kind = "initial"``), named, with parameters, no
  expressions: ``uniform``, ``cantilever_mode1`` (first bending mode of a clamped-free
  beam, Gray, Monaghan & Swift 2001), ``rigid_rotation`` (about the z axis).
- Wall contact: non-penetration plus Coulomb friction against wall particles (phase 2),
  enforced on the velocity after the momentum update (:func:`wall_contact`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.kernel import fac_grad

#: Root of cos(kL) cosh(kL) = -1, first mode of a clamped-free beam.
BETA1 = 1.8751040687119611


def _in_box(X, c):
    lo, hi = np.asarray(c.lo), np.asarray(c.hi)
    return np.all((X >= lo) & (X <= hi), axis=1)


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


def initial_velocity(constraints, X, v, solid) -> None:
    """Apply the ``kind = "initial"`` constraints to ``v`` (rows where ``solid``)."""
    dim = X.shape[1]
    for c in constraints:
        if c.kind != "initial":
            continue
        sel = _in_box(X, c) & solid
        if c.profile == "uniform":
            v[sel] = np.asarray(c.velocity)
        elif c.profile == "cantilever_mode1":
            v[sel, dim - 1] = c.tip_speed * cantilever_mode1(X[sel, 0], c.root, c.length)
        elif c.profile == "rigid_rotation":
            r = X[sel, :2] - np.asarray(c.centre)[:2]
            v[sel, 0] = -c.omega * r[:, 1]
            v[sel, 1] = c.omega * r[:, 0]


def velocity_masks(constraints, X, solid):
    """(mask (N, dim) of prescribed components, values (N, dim)) for ``kind = "velocity"``."""
    n, dim = X.shape
    mask = np.zeros((n, dim), dtype=bool)
    value = np.zeros((n, dim))
    for c in constraints:
        if c.kind != "velocity":
            continue
        sel = _in_box(X, c) & solid
        axes = np.asarray(c.axes if c.axes else (True,) * dim, dtype=bool)
        for a in range(dim):
            if axes[a]:
                mask[sel, a] = True
                value[sel, a] = c.velocity[a]
    return mask, value


@njit(cache=True)
def wall_contact(x, v, n_solid, rows, xw, indptr, indices, h, d, dim, mu):
    r"""Non-penetration and Coulomb friction against wall particles, in place on ``v``.

    For solid particle ``rows[k]`` (current position ``x[k]``, neighbours ``xw`` within
    2h from a CSR list over the concatenation [solid rows, wall rows]):

    - outward wall normal :math:`\mathbf n = -\sum_w \nabla W(\mathbf x_k - \mathbf x_w)`
      normalised (points from the wall into the body);
    - gap :math:`\delta = \min_w (\mathbf x_k - \mathbf x_w)\cdot\mathbf n`; a particle
      is in contact when :math:`\delta < d` (one particle spacing: a body resting on a
      wall has :math:`\delta = d`);
    - in contact and approaching (:math:`v_n < 0`) the normal velocity is removed,
      :math:`\Delta v_n = -v_n`, and the tangential velocity is reduced by at most
      :math:`\mu\,\Delta v_n` (Coulomb: the friction impulse is bounded by mu times the
      normal impulse; sticking when it would reverse the slip).

    Returns the number of particles in contact.
    """
    count = 0
    nv = np.zeros(3)
    for k in range(n_solid):
        i = rows[k]
        nv[:] = 0.0
        gap = 1e300
        found = False
        for p in range(indptr[k], indptr[k + 1]):
            w = indices[p] - n_solid
            if w < 0:
                continue
            found = True
            r2 = 0.0
            for a in range(dim):
                r2 += (x[k, a] - xw[w, a]) ** 2
            f = -fac_grad(math.sqrt(r2), h, dim)
            for a in range(dim):
                nv[a] += f * (x[k, a] - xw[w, a])
        if not found:
            continue
        norm = 0.0
        for a in range(dim):
            norm += nv[a] * nv[a]
        norm = math.sqrt(norm)
        if norm == 0.0:
            continue
        for a in range(dim):
            nv[a] /= norm
        for p in range(indptr[k], indptr[k + 1]):
            w = indices[p] - n_solid
            if w < 0:
                continue
            g = 0.0
            for a in range(dim):
                g += (x[k, a] - xw[w, a]) * nv[a]
            gap = min(gap, g)
        if gap >= d * (1.0 + 1e-6):
            continue
        vn = 0.0
        for a in range(dim):
            vn += v[i, a] * nv[a]
        if vn >= 0.0:
            continue
        count += 1
        vt2 = 0.0
        for a in range(dim):
            v[i, a] -= vn * nv[a]
            vt2 += v[i, a] * v[i, a]
        vt = math.sqrt(vt2)
        if vt > 0.0 and mu > 0.0:
            fac = max(0.0, 1.0 - mu * (-vn) / vt)
            for a in range(dim):
                v[i, a] *= fac
    return count
