r"""Numba kernels of the IISPH step: CSR blocks of the two implicit systems and the explicit sums.

Every kernel loops over the owned rows ``0 .. n_owned - 1`` of the CSR neighbour lists
(owned rows first, halo rows after) and writes *global* indices: ``row[j]`` is the
global PETSc point of row ``j`` (owned or halo). A boundary particle (``fluid[j] == 0``:
a wall ghost particle, or a solid particle seen by the fluid) is an unknown like a fluid
particle, with its own row (Adami et al. 2012 fixed wall ghost particles, treated as
extra unknowns rather than substituted, so that the distributed assembly never needs a
neighbour's neighbours).

Viscous predictor, eqs. (30) and (34), for a fluid row :math:`i` (vector unknowns,
block size ``dim``, component ``c`` of point ``P`` is scalar row ``P dim + c``):

.. math::

    \mathbf{v}^*_i - \Delta t \sum_j K_{ij} F_{ij}\, \mathbf{r}_{ij} \mathbf{r}_{ij}^T
    (\mathbf{v}^*_i - \mathbf{v}^*_j) = \mathbf{v}^\beta_i + \Delta t\, \mathbf{g},
    \qquad K_{ij} = m_j \frac{2 (D + 2) (\nu_i + \nu_j)}{(\rho_i + \rho_j)(r_{ij}^2 + \eta^2)},

with :math:`\nabla W_{ij} = F_{ij} \mathbf{r}_{ij}` and :math:`\eta^2 = 0.01 h^2`. The
paper's factor 8 of eq. (34) is :math:`2 (D + 2)` for :math:`D = 2` (Monaghan 2005); in 3D
the same expression gives 10. No-slip boundary rows carry the ghost velocity
:math:`\mathbf{v}_w = 2 \mathbf{v}_{wall} - \sum_f \mathbf{v}_f W_{wf} / \sum_f W_{wf}`
(Adami et al. 2012, eqs. (22)-(23)); free-slip boundary neighbours are left out of the
viscous sum.

Pressure Poisson equation, eqs. (32), (35), (36), for a fluid row :math:`i` that is not
on the free surface, multiplied by :math:`s_i = \rho_i d^2 / (2 \rho_{0i})` so that its
coefficients are of order one (:func:`ppe_row_scale`):

.. math::

    \frac{2}{\rho_i} \sum_j m_j F_{ij} (p_i - p_j)
    = \frac{\rho_0}{\Delta t} \langle \nabla\cdot\mathbf{v}^* \rangle_i
      + \alpha \frac{\rho_0 - \rho_i}{\Delta t^2},

free-surface rows :math:`p_i = 0`, and wall rows with fluid neighbours the pressure
extrapolation of Adami et al. (2012), eq. (27), for fixed walls,

.. math::

    p_w - \sum_f \frac{W_{wf}}{\sum_f W_{wf}} p_f
    = \sum_f \frac{W_{wf}}{\sum_f W_{wf}} \rho_f \mathbf{g}\cdot(\mathbf{x}_w - \mathbf{x}_f).

Wall rows without a fluid neighbour are identity rows (value 0). The rows of type-II
solid particles of a coupled scene (no penetration, the solid's inertia in the matrix)
are described in :mod:`parsph.coupling.pressure`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.kernel import constants, delta, fac_grad_k, w_and_fac_grad_k, w_k
from parsph.tensor import _eig6

__all__ = ["density_and_surface", "viscous_csr", "viscous_explicit", "ghost_velocity", "ppe_csr",
           "divergence", "pressure_gradient", "pressure_gradient_corrected", "ppe_row_scale",
           "has_fluid_neighbour", "rows_in_order"]

#: eta^2 / h^2 of the viscous term (avoids 1/r^2 blowing up for coincident particles).
ETA2 = 0.01

#: A boundary particle (wall or solid) comes into contact with the fluid when the
#: summation density of its support, fluid and boundary particles together, reaches this
#: times its rest density (a fluid layer resting a spacing d away fills it), and stays in
#: contact down to the free surface's beta (see density_and_surface).
CONTACT = 0.97


def ppe_row_scale(rho, rho0, d):
    r"""Scale :math:`s_i = \rho_i d^2 / (2 \rho_{0i})` (m^2) of the fluid PPE rows.

    The assembled fluid row is eq. (35) = source of eq. (32), both multiplied by
    :math:`-s_i`, so that its coefficients :math:`-d^2 m_j F_{ij} / \rho_{0i}` are of
    order one (like the wall and free-surface rows) and the diagonal is positive.
    """
    return rho * d * d / (2.0 * rho0)


@njit(cache=True)
def density_and_surface(x, m, fluid, rho0, indptr, indices, h, dim, beta, gamma, rho, free):
    r"""Summation density (33) of the owned fluid rows, the free-surface flag, and which
    boundary rows the fluid touches.

    A fluid row is on the free surface (``free[i] = 1``: p = 0) when its support is
    visibly incomplete: :math:`\rho_i < \beta \rho_{0i}` (Koshizuka & Oka 1996) **or**
    (:math:`\rho_i < \rho_{0i}` and :math:`h |\sum_j V_j \nabla W_{ij}| > \gamma`) (the
    kernel-gradient sum, zero for a full support; Marrone et al. 2010 use its normalised
    form for surface detection; a compressed particle is never free, or two surface
    particles could collapse onto each other at p = 0), with :math:`V_j = m_j /
    \rho_{0j}`. Boundary particles count in both sums (they fill the support beyond a
    wall), so a particle by a wall is not flagged, while one at a wall corner above the
    water is, through the second test, even if the wall particles above the water raise
    its density.

    ``rho[i]`` of boundary rows is left as given (their rest density). A boundary row
    (wall or solid) is *free* too (p = 0, its no-penetration row inactive) unless the
    fluid is in contact with it: its support, fluid and boundary particles together, is
    full, :math:`\sum_j m_j W_{ij} \ge` :data:`CONTACT` :math:`\rho_{0i}` to come into
    contact, :math:`\ge \beta \rho_{0i}` to stay (``free`` holds the last step's flag on
    entry). As an equality on every boundary particle with a fluid neighbour, no
    penetration stopped a fluid particle wherever it entered a support (2h away): a
    Bingham front hovered a quarter spacing above the floor and ran out 0.5 m further
    with 0.9 both ways; with 0.97 both ways the side walls of a tank at rest flickered in
    and out of contact and its water rocked at 6 % of sqrt(g H) after 16 s
    (docs/iisph.md).
    """
    n = indptr.shape[0] - 1
    k = constants(h, dim)
    w0 = k[1]
    for i in range(n):
        acc = m[i] * w0
        if not fluid[i]:
            touched = False
            for q in range(indptr[i], indptr[i + 1]):
                j = indices[q]
                r2 = delta(x, i, j, dim)[3]
                touched = touched or fluid[j]
                acc += m[j] * w_k(math.sqrt(r2), k)
            level = beta if free[i] == 0 else CONTACT
            free[i] = 0 if touched and acc >= level * rho0[i] else 1
            continue
        g0 = g1 = g2 = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            d0, d1, d2, r2 = delta(x, i, j, dim)
            wij, fij = w_and_fac_grad_k(math.sqrt(r2), k)
            acc += m[j] * wij
            f = m[j] / rho0[j] * fij
            g0 += f * d0
            g1 += f * d1
            g2 += f * d2
        rho[i] = acc
        gnorm = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        free[i] = 1 if (acc < beta * rho0[i] or (acc < rho0[i] and h * gnorm > gamma)) else 0


@njit(cache=True, inline="always")
def fluid_weight_sum(x, fluid, indptr, indices, i, h, dim):
    """sum_f W(r_if, h) over the fluid neighbours f of a wall particle i (Adami et al. 2012:
    the normalisation of the wall extrapolations of velocity and pressure)."""
    k = constants(h, dim)
    wsum = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        j = indices[p]
        if fluid[j]:
            wsum += w_k(math.sqrt(delta(x, i, j, dim)[3]), k)
    return wsum


@njit(cache=True)
def _slot(cols, vals, base, span, bw, dim, t, last, P):
    """Slot of partner point ``P`` in the ``dim`` scalar rows of one point.

    The rows are written side by side, row ``a`` from ``base + a span``; slot ``s`` of
    row ``a`` is the ``bw`` entries from ``base + a span + s bw``, columns ``P dim + b``
    (``bw == dim``: a full block) or ``P dim + a`` (``bw == 1``: the diagonal of the
    block). Partners arrive in non-decreasing ``P`` (neighbour lists sorted by global
    row), so a repeated ``P`` (a periodic image, or the diagonal) merges into the last
    slot. Returns ``(slot, t, last)`` with ``t`` slots used and ``last`` partner.
    """
    if t > 0 and last == P:
        return t - 1, t, last
    for a in range(dim):
        for b in range(bw):
            q = base + a * span + t * bw + b
            cols[q] = P * dim + (b if bw == dim else a)
            vals[q] = 0.0
    return t, t + 1, P


@njit(cache=True)
def _close_rows(cols, vals, out_ptr, base, span, bw, dim, t, local):
    """Pack the ``dim`` rows of a point (row ``a`` moved from ``base + a span`` to
    ``base + a t bw``) and set their row pointers; returns the next free position."""
    length = t * bw
    for a in range(1, dim):
        src = base + a * span
        dst = base + a * length
        for q in range(length):
            cols[dst + q] = cols[src + q]
            vals[dst + q] = vals[src + q]
    for a in range(dim):
        out_ptr[local * dim + a + 1] = base + (a + 1) * length
    return base + dim * length


@njit(cache=True, inline="always")
def _viscous_pair(m, rho, nu, fluid, i, j, r2, k, dim, dt, eta2, morris):
    """Coefficient ``c`` (<= 0) of the pair (i, j) at distance squared ``r2`` in the
    viscous term of row ``i``, times dt: eq. (34) is ``c r r^T (v_i - v_j)``, Morris et
    al. (1997) ``c (v_i - v_j)``, ``r = x_i - x_j``. A boundary j takes row i's
    viscosity; a boundary row i its fluid partner's (coupling). ``k``: the kernel's
    :func:`parsph.kernel.constants`."""
    nui = nu[i] if fluid[i] else nu[j]
    nuj = nu[j] if fluid[j] else nui
    f = fac_grad_k(math.sqrt(r2), k)
    if morris:
        return dt * m[j] * (rho[i] * nui + rho[j] * nuj) / (rho[i] * rho[j]) * f \
            * r2 / (r2 + eta2)
    return dt * m[j] * 2.0 * (dim + 2) * (nui + nuj) / ((rho[i] + rho[j]) * (r2 + eta2)) * f


@njit(cache=True)
def rows_in_order(row, n, first):
    """The owned particles of the system in the order of their rows: ``order[r]`` is the
    particle of global row ``first + r``. The stage numbers the owned rows
    ``first, first + 1, ...`` in whatever order it likes (wall rows after the fluid's,
    see ``IISPH._row_order``); the CSR kernels write them in that order."""
    count = 0
    for i in range(n):
        if row[i] >= 0:
            count += 1
    order = np.empty(count, np.int64)
    for i in range(n):
        if row[i] >= 0:
            order[row[i] - first] = i
    return order


@njit(cache=True)
def csr_capacity(fluid, solid, row, indptr, dim, full):
    """Entries the CSR kernels may write for the owned rows in the system (``row >= 0``):
    ``dim`` scalar rows of ``(neighbours + 1) bw`` slots each, ``bw = dim`` for a fluid or
    type-II row when ``full`` (the blocks of eq. (34)), else 1 (:func:`viscous_csr`; with
    ``dim = 1`` and ``full = False`` the scalar PPE of :func:`ppe_csr`). Rows outside the
    system (type-I solids) take nothing: sizing by every owned row held a 3D coupled
    scene's viscous buffers at 5.5 KB per particle."""
    total = 0
    for i in range(indptr.shape[0] - 1):
        if row[i] < 0:
            continue
        bw = dim if full and (fluid[i] or solid[i] > 0.0) else 1
        total += dim * bw * (indptr[i + 1] - indptr[i] + 1)
    return total


@njit(cache=True)
def viscous_csr(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim, dt,
                g, morris, first, out_ptr, out_cols, out_vals):
    """CSR block and right-hand side of the implicit viscous predictor (30)/(34).

    Writes the owned scalar rows (block size ``dim``: component ``a`` of global point
    ``P`` is row ``P dim + a``) straight into ``out_ptr`` (``n_local + 1``), ``out_cols``
    and ``out_vals`` (capacity :func:`csr_capacity`): columns sorted and distinct
    in each row, no triplets and no sort (the neighbour lists must be sorted by
    ``row``, :func:`solvers.csr.sort_neighbours_by_row`). ``first`` is the first global
    point of this rank. Returns ``(nnz, rhs)`` with ``rhs`` of shape (n_owned, dim). See
    the module docstring for the rows. With ``morris`` the operator is Morris et al.
    (1997) instead of eq. (34):
    ``sum_j m_j (rho_i nu_i + rho_j nu_j) / (rho_i rho_j) F_ij r^2 / (r^2 + eta^2) v_ij``
    (component-wise; accurate in shear on a lattice with h = 1.2 d, see docs/iisph.md).

    Coupling (section 5, eq. (47)): a row with ``solid[i] > 0`` is a TLSPH particle
    with fluid neighbours (type II); its unknown is its own velocity, its right-hand
    side ``v[i]`` is the solid predictor of eq. (7) (the caller passes it), and it
    couples to its fluid neighbours only, with the pair coefficient the fluid row sees
    (pair viscosity ``2 nu_f``) times ``solid[i]`` = (mass the fluid sees) / (true mass),
    so the viscous forces between the phases are equal and opposite. Fluid rows see
    solid neighbours as no-slip walls whose velocity is the solid's own unknown
    (eq. (43)). Rows with ``row[i] < 0`` (type I solids, walls without fluid neighbours)
    are not in the system. A fluid or solid row under eq. (34) stores full ``dim x dim``
    blocks (zeros included); the other rows the diagonal of each block.
    """
    n = indptr.shape[0] - 1
    rhs = np.zeros((n, dim))
    eta2 = ETA2 * h * h
    kc = constants(h, dim)
    out_ptr[0] = 0
    k = 0
    order = rows_in_order(row, n, first)
    for q in range(order.shape[0]):
        i = order[q]
        ri = row[i]
        moving = fluid[i] or solid[i] > 0.0
        wsum = 0.0
        if not moving and not slip[i]:
            wsum = fluid_weight_sum(x, fluid, indptr, indices, i, h, dim)
        ghost = wsum > 0.0
        bw = dim if moving and not morris else 1
        span = (indptr[i + 1] - indptr[i] + 1) * bw
        base = k
        t = 0
        last = -1
        dslot = -1
        # the diagonal block, symmetric: D = I - sum_j c r r^T (or I - sum_j c I)
        e00 = e11 = e22 = 1.0
        e01 = e02 = e12 = 0.0
        if moving:
            for a in range(dim):
                rhs[i, a] = v[i, a] + dt * g[a] if fluid[i] else v[i, a]
        elif ghost:
            for a in range(dim):  # no-slip ghost velocity: v_w + sum_f w_wf v_f = 2 v_wall
                rhs[i, a] = 2.0 * v[i, a]
        else:
            for a in range(dim):
                rhs[i, a] = v[i, a]
        if moving or ghost:
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                rj = row[j]
                if rj < 0:
                    continue
                if moving:
                    if not fluid[j] and (slip[j] or solid[i] > 0.0):
                        continue
                elif not fluid[j]:
                    continue
                if dslot < 0 and rj >= ri:
                    dslot, t, last = _slot(out_cols, out_vals, base, span, bw, dim, t, last, ri)
                s, t, last = _slot(out_cols, out_vals, base, span, bw, dim, t, last, rj)
                d0, d1, d2, r2 = delta(x, i, j, dim)
                if ghost:
                    wij = w_k(math.sqrt(r2), kc) / wsum
                    for a in range(dim):
                        out_vals[base + a * span + s] += wij
                    continue
                c = _viscous_pair(m, rho, nu, fluid, i, j, r2, kc, dim, dt, eta2, morris) \
                    * (1.0 if fluid[i] else solid[i])
                if morris:
                    e00 -= c
                    for a in range(dim):
                        out_vals[base + a * span + s] += c
                    continue
                c00, c01, c02 = c * d0 * d0, c * d0 * d1, c * d0 * d2
                c11, c12, c22 = c * d1 * d1, c * d1 * d2, c * d2 * d2
                e00 -= c00
                e01 -= c01
                e02 -= c02
                e11 -= c11
                e12 -= c12
                e22 -= c22
                _add_block(out_vals, base + s * dim, span, dim, c00, c01, c02, c11, c12, c22)
        if dslot < 0:
            dslot, t, last = _slot(out_cols, out_vals, base, span, bw, dim, t, last, ri)
        if bw == dim:
            _add_block(out_vals, base + dslot * dim, span, dim, e00, e01, e02, e11, e12, e22)
        else:  # a diagonal block: (1 - sum c) I (Morris), or the identity
            for a in range(dim):
                out_vals[base + a * span + dslot] += e00
        k = _close_rows(out_cols, out_vals, out_ptr, base, span, bw, dim, t, ri - first)
    return k, rhs


@njit(cache=True, inline="always")
def _add_block(vals, at, span, dim, c00, c01, c02, c11, c12, c22):
    """Add the symmetric block ``c`` to the ``dim`` rows written side by side: row ``a``
    from ``at + a span``, columns in order."""
    vals[at] += c00
    vals[at + 1] += c01
    vals[at + span] += c01
    vals[at + span + 1] += c11
    if dim == 3:
        vals[at + 2] += c02
        vals[at + span + 2] += c12
        vals[at + 2 * span] += c02
        vals[at + 2 * span + 1] += c12
        vals[at + 2 * span + 2] += c22


@njit(cache=True)
def ghost_velocity(x, v, fluid, slip, indptr, indices, h, dim, out):
    """No-slip ghost velocity of the owned wall rows from the fluid's present velocity,
    ``out[w] = 2 v_w - sum_f W_wf v_f / sum_f W_wf`` (Adami et al. 2012, eqs. (22)-(23)):
    the wall rows of :func:`viscous_csr` solved on their own. Wall rows without fluid
    neighbours get ``v_w``; fluid and free-slip rows are left as they are."""
    n = indptr.shape[0] - 1
    k = constants(h, dim)
    for i in range(n):
        if fluid[i] or slip[i]:
            continue
        wsum = 0.0  # one pass: sum_f W_wf and sum_f W_wf v_f together
        a0 = a1 = a2 = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if fluid[j]:
                wij = w_k(math.sqrt(delta(x, i, j, dim)[3]), k)
                wsum += wij
                u0, u1, u2 = _vec(v, j, dim)
                a0 += wij * u0
                a1 += wij * u1
                a2 += wij * u2
        if wsum > 0.0:
            _store(out, i, dim, 2.0 * v[i, 0] - a0 / wsum, 2.0 * v[i, 1] - a1 / wsum,
                   2.0 * v[i, 2] - a2 / wsum if dim == 3 else 0.0)
        else:
            for a in range(dim):
                out[i, a] = v[i, a]


@njit(cache=True)
def viscous_explicit(x, v, v_ghost, m, rho, nu, fluid, slip, indptr, indices, h, dim, dt, g,
                     morris):
    r"""Explicit viscous predictor of the owned fluid rows: eq. (30) with the viscous term
    (34) (or Morris et al. 1997) evaluated at :math:`\mathbf{v}^\beta`,

    .. math:: \mathbf{v}^*_i = \mathbf{v}_i + \Delta t\,\mathbf{g}
              + \sum_j c_{ij} \mathbf{r}_{ij} \mathbf{r}_{ij}^T (\mathbf{v}_i - \mathbf{v}_j),

    with the coefficients of :func:`viscous_csr` (no-slip walls at their ``v_ghost``,
    free-slip walls left out). It is one step of forward instead of backward Euler on the
    same operator; the two differ by O(zeta^2) for a viscous number
    :math:`\zeta = \nu \Delta t / h^2`, and forward Euler is stable below about 0.1
    (Morris et al. 1997). Other rows: ``v``. Shape (n_owned, dim)."""
    n = indptr.shape[0] - 1
    out = np.empty((n, dim))
    eta2 = ETA2 * h * h
    k = constants(h, dim)
    for i in range(n):
        if not fluid[i]:
            for a in range(dim):
                out[i, a] = v[i, a]
            continue
        vi0, vi1, vi2 = _vec(v, i, dim)
        o0 = vi0 + dt * g[0]
        o1 = vi1 + dt * g[1]
        o2 = vi2 + dt * g[2] if dim == 3 else 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            fj = fluid[j]
            if not fj and slip[j]:
                continue
            d0, d1, d2, r2 = delta(x, i, j, dim)
            u0, u1, u2 = _vec(v if fj else v_ghost, j, dim)
            e0, e1, e2 = vi0 - u0, vi1 - u1, vi2 - u2
            c = _viscous_pair(m, rho, nu, fluid, i, j, r2, k, dim, dt, eta2, morris)
            if morris:
                o0 += c * e0
                o1 += c * e1
                o2 += c * e2
            else:
                dr = e0 * d0 + e1 * d1 + e2 * d2
                o0 += c * d0 * dr
                o1 += c * d1 * dr
                o2 += c * d2 * dr
        _store(out, i, dim, o0, o1, o2)
    return out


@njit(cache=True, inline="always")
def _vec(v, i, dim):
    """Row ``i`` of an (N, dim) array as three scalars (the third 0 in 2D)."""
    return v[i, 0], v[i, 1], v[i, 2] if dim == 3 else 0.0


@njit(cache=True, inline="always")
def _store(out, i, dim, a0, a1, a2):
    """Write three scalars to row ``i`` of an (N, dim) array (the third only in 3D)."""
    out[i, 0] = a0
    out[i, 1] = a1
    if dim == 3:
        out[i, 2] = a2


@njit(cache=True)
def ppe_csr(x, vs, m, rho, rho0, fluid, free, row, indptr, indices, h, dim, dt, alpha, d,
            corrected, expansion, first, out_ptr, out_cols, out_vals):
    r"""CSR block and right-hand side of the stabilised PPE (32) with (35), (36) and the
    no-penetration rows of the boundary (walls, type-II solids).

    Writes the owned rows straight into ``out_ptr`` (``n_local + 1``), ``out_cols`` and
    ``out_vals`` (capacity ``pairs + n_owned``), columns sorted and distinct in each row
    (neighbour lists sorted by ``row``); ``first`` is the first global row of this rank.
    Returns ``(nnz, rhs)``, ``rhs`` of shape (n_owned,). Rows with ``row[i] < 0`` are not
    in the system.

    ``vs`` is the predicted velocity v* of all rows: the fluid's after the viscous
    predictor, a wall's its own (zero), a type-II solid's its predictor (eq. (7)).

    - Interior fluid row: -s_i x eq. (35) = -s_i x the source of eq. (32), with
      :math:`s_i` of :func:`ppe_row_scale`. A pair with a boundary neighbour carries half
      the fluid pair's coefficient: only the fluid end of the pair responds to the
      pressure through the fluid's inertia (a wall does not move; a solid's response is
      the solid-response term of :mod:`parsph.coupling.pressure`).
    - Free-surface row: p = 0.
    - Boundary row with fluid neighbours: no penetration,
      :math:`\langle\nabla\cdot\mathbf v^{\beta+1}\rangle_b = 0` over its fluid
      neighbours, the fluid's response taken along each pair
      (:math:`\nabla p_f\cdot(\mathbf x_b - \mathbf x_f) \approx p_b - p_f`, exact for a
      linear pressure): :math:`-\frac{d^2}{2}\frac{1}{\rho_b}\sum_f m_f F_{bf}(p_b - p_f)
      = -\frac{d^2}{2}\frac{\rho_{0b}}{\rho_b\Delta t}\sum_f m_f (\mathbf v^*_f -
      \mathbf v^*_b)\cdot\nabla W_{bf}`. Its pressure is the multiplier of that
      constraint; gravity enters through the fluid's v* (docs/iisph.md).
    - Boundary row not in contact with the fluid (``free``, see
      :func:`density_and_surface`): p = 0.

    With ``corrected`` the Laplacian (35) of a fluid row gets the first-order correction
    :math:`- 2\,\mathbf{e}_i\cdot\mathbf{L}_i \sum_j V_j (p_j - p_i) \nabla W_{ij}`,
    :math:`\mathbf{e}_i = \sum_j (m_j/\rho_i) \nabla W_{ij}` (zero for a full support),
    :math:`\mathbf{L}_i` as in :func:`pressure_gradient_corrected`: a linear pressure
    is then harmonic even where the support is truncated (the layers under the free
    surface; cf. Schwaiger 2008, Fatehi & Manzari 2011), which (35) alone is not; each
    corrected pair coefficient is kept >= 0, and a row whose diagonal the correction
    would halve keeps eq. (35) as printed.
    """
    n = indptr.shape[0] - 1
    rhs = np.zeros(n)
    kc = constants(h, dim)
    ok, e0, e1, e2 = False, 0.0, 0.0, 0.0
    L = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    out_ptr[0] = 0
    k = 0
    order = rows_in_order(row, n, first)
    for q in range(order.shape[0]):
        i = order[q]
        ri = row[i]
        base = k
        t = 0
        last = -1
        dslot = -1
        diag = 1.0
        interior = fluid[i] and not free[i]
        boundary = not fluid[i] and not free[i]  # in contact with the fluid
        s = 0.0
        div = 0.0
        plain = 0.0
        use_corr = False
        if interior or boundary:
            s = rho[i] * d * d / (2.0 * rho0[i])
            diag = 0.0
            if corrected and interior:
                ok, e0, e1, e2, L = _truncation(x, m, rho, indptr, indices, i, kc, dim)
                use_corr = ok
            v0, v1, v2 = _vec(vs, i, dim)
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                if boundary and not fluid[j]:
                    continue
                rj = row[j]
                if dslot < 0 and rj >= ri:
                    dslot, t, last = _scalar_slot(out_cols, out_vals, base, t, last, ri)
                slot, t, last = _scalar_slot(out_cols, out_vals, base, t, last, rj)
                d0, d1, d2, r2 = delta(x, i, j, dim)
                u0, u1, u2 = _vec(vs, j, dim)
                dvr = (u0 - v0) * d0 + (u1 - v1) * d1 + (u2 - v2) * d2
                f = fac_grad_k(math.sqrt(r2), kc)
                div += m[j] * dvr * f
                # >= 0: the pair's response; 1 where one end is a boundary (see above)
                c = -s * (2.0 if fluid[i] and fluid[j] else 1.0) / rho[i] * m[j] * f
                plain += c
                if use_corr:
                    c = _corrected(c, m, rho, j, f, s, e0, e1, e2, L, d0, d1, d2)
                diag += c
                out_vals[base + slot] -= c
            if use_corr and diag < 0.5 * plain:
                # a row whose support is truncated yet not flagged free (a compressed
                # surface particle, a droplet) loses its diagonal to the correction: its
                # pressure reached MPa and GMRES broke down (elastic_gate, docs/iisph.md);
                # it keeps eq. (35) as printed
                diag = plain
                for p in range(indptr[i], indptr[i + 1]):
                    j = indices[p]
                    d0, d1, d2, r2 = delta(x, i, j, dim)
                    f = fac_grad_k(math.sqrt(r2), kc)
                    c = -s * (2.0 if fluid[j] else 1.0) / rho[i] * m[j] * f
                    u = _column_slot(out_cols, base, t, row[j])
                    out_vals[base + u] += _corrected(c, m, rho, j, f, s, e0, e1, e2, L,
                                                     d0, d1, d2) - c
            if interior:
                div /= rho[i]
                # density-error term of eq. (32) for compression only: under-density near
                # the free surface is kernel truncation, not expansion (docs/iisph.md)
                drho = rho0[i] - rho[i] if expansion else min(rho0[i] - rho[i], 0.0)
                source = rho0[i] * div / dt + alpha * drho / (dt * dt)
                # eq. (35) as sum a_ij (p_i - p_j) with a_ij = -(2/rho_i) m_j F_ij = -source
                rhs[i] = -s * source
            else:  # no penetration: no density term (a boundary's own volume)
                rhs[i] = -s * rho0[i] * div / (rho[i] * dt)
        if dslot < 0:
            dslot, t, last = _scalar_slot(out_cols, out_vals, base, t, last, ri)
        out_vals[base + dslot] += diag
        k = base + t
        out_ptr[ri - first + 1] = k
    return k, rhs


@njit(cache=True, inline="always")
def _scalar_slot(cols, vals, base, t, last, col):
    """:func:`_slot` of a scalar system (one row, block size 1)."""
    if t > 0 and last == col:
        return t - 1, t, last
    cols[base + t] = col
    vals[base + t] = 0.0
    return t, t + 1, col


@njit(cache=True, inline="always")
def _corrected(c, m, rho, j, f, s, e0, e1, e2, L, d0, d1, d2):
    """The pair coefficient ``c`` of a fluid row with the first-order correction of the
    ``corrected`` Laplacian, + 2 s e_i . L_i V_j grad W_ij, kept >= 0 (an M-matrix row).
    ``(d0, d1, d2) = x_i - x_j``; ``L`` the six entries of the symmetric L_i
    (:func:`_truncation`)."""
    l00, l01, l02, l11, l12, l22 = L
    eb = e0 * (l00 * d0 + l01 * d1 + l02 * d2) + e1 * (l01 * d0 + l11 * d1 + l12 * d2) \
        + e2 * (l02 * d0 + l12 * d1 + l22 * d2)
    return max(c - 2.0 * s * m[j] / rho[j] * f * eb, 0.0)


@njit(cache=True, inline="always")
def _column_slot(cols, base, t, col):
    """Slot of column ``col`` among the sorted ``cols[base:base + t]``."""
    lo, hi = 0, t - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cols[base + mid] < col:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline="always")
def _truncation(x, m, rho, indptr, indices, i, k, dim):
    """``(ok, e0, e1, e2, L)`` of row ``i``: ``e`` = sum_j (m_j / rho_i) grad W_ij and ``L``
    the six entries ``(l00, l01, l02, l11, l12, l22)`` of the inverse of the symmetric
    moment matrix sum_j V_j grad W_ij (x) (x_j - x_i); ``ok`` False where that matrix is
    near singular (no correction then)."""
    e0 = e1 = e2 = 0.0
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        j = indices[p]
        d0, d1, d2, r2 = delta(x, i, j, dim)
        f = fac_grad_k(math.sqrt(r2), k)
        a = m[j] / rho[i] * f
        e0 += a * d0
        e1 += a * d1
        e2 += a * d2
        b = -m[j] / rho[j] * f
        m00 += b * d0 * d0
        m01 += b * d0 * d1
        m02 += b * d0 * d2
        m11 += b * d1 * d1
        m12 += b * d1 * d2
        m22 += b * d2 * d2
    ok, L = _invert_sym(m00, m01, m02, m11, m12, m22, dim)
    return ok, e0, e1, e2, L


@njit(cache=True, inline="always")
def _invert_sym(m00, m01, m02, m11, m12, m22, dim):
    """``(ok, (l00, l01, l02, l11, l12, l22))``: the inverse of the symmetric 2x2 (``dim`` 2,
    the ``*2`` entries ignored) or 3x3 matrix; ``ok`` False (zeros) where it is near
    singular: trace <= 0 or det <= 1e-3 (trace / dim)^dim."""
    zero = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if dim == 2:
        tr = m00 + m11
        det = m00 * m11 - m01 * m01
        if tr <= 0.0 or det <= 1e-3 * (tr / 2) ** 2:
            return False, zero
        return True, (m11 / det, -m01 / det, 0.0, m00 / det, 0.0, 0.0)
    tr = m00 + m11 + m22
    c00 = m11 * m22 - m12 * m12
    c01 = m12 * m02 - m01 * m22
    c02 = m01 * m12 - m11 * m02
    det = m00 * c00 + m01 * c01 + m02 * c02
    if tr <= 0.0 or det <= 1e-3 * (tr / 3) ** 3:
        return False, zero
    return True, (c00 / det, c01 / det, c02 / det, (m00 * m22 - m02 * m02) / det,
                  (m02 * m01 - m00 * m12) / det, (m00 * m11 - m01 * m01) / det)


@njit(cache=True)
def divergence(x, vs, m, rho, fluid, indptr, indices, h, dim):
    """Velocity divergence (36) of the owned fluid rows (1/s); 0 elsewhere."""
    n = indptr.shape[0] - 1
    out = np.zeros(n)
    k = constants(h, dim)
    for i in range(n):
        if not fluid[i]:
            continue
        v0, v1, v2 = _vec(vs, i, dim)
        acc = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            d0, d1, d2, r2 = delta(x, i, j, dim)
            u0, u1, u2 = _vec(vs, j, dim)
            dvr = (u0 - v0) * d0 + (u1 - v1) * d1 + (u2 - v2) * d2
            acc += m[j] * dvr * fac_grad_k(math.sqrt(r2), k)
        out[i] = acc / rho[i]
    return out


@njit(cache=True)
def pressure_gradient(x, p, m, rho, fluid, indptr, indices, h, dim):
    r"""Symmetric pressure gradient (37) of the owned fluid rows (Pa/m); 0 elsewhere.

    :math:`\langle\nabla p\rangle_i = \rho_i \sum_j m_j (p_i/\rho_i^2 + p_j/\rho_j^2)
    \nabla W_{ij}`, over fluid and boundary neighbours.
    """
    n = indptr.shape[0] - 1
    out = np.zeros((n, dim))
    k = constants(h, dim)
    for i in range(n):
        if not fluid[i]:
            continue
        pi = p[i] / (rho[i] * rho[i])
        g0 = g1 = g2 = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            d0, d1, d2, r2 = delta(x, i, j, dim)
            c = rho[i] * m[j] * (pi + p[j] / (rho[j] * rho[j])) * fac_grad_k(math.sqrt(r2), k)
            g0 += c * d0
            g1 += c * d1
            g2 += c * d2
        _store(out, i, dim, g0, g1, g2)
    return out


@njit(cache=True)
def has_fluid_neighbour(fluid, indptr, indices):
    """1 for the owned rows with at least one fluid neighbour (uint8)."""
    n = indptr.shape[0] - 1
    out = np.zeros(n, dtype=np.uint8)
    for i in range(n):
        for q in range(indptr[i], indptr[i + 1]):
            if fluid[indices[q]]:
                out[i] = 1
                break
    return out


@njit(cache=True)
def pressure_gradient_corrected(x, p, m, rho, fluid, indptr, indices, h, dim, wet=None):
    r"""Corrected pressure gradient of the owned fluid rows (Pa/m); 0 elsewhere.

    :math:`\langle\nabla p\rangle_i = \mathbf{L}_i \sum_j V_j (p_j - p_i) \nabla W_{ij}`,
    :math:`\mathbf{L}_i = \big(\sum_j V_j \nabla W_{ij} \otimes (\mathbf{x}_j - \mathbf{x}_i)
    \big)^{-1}`, :math:`V_j = m_j / \rho_j` (Bonet & Lok 1999, cited in section 2): exact
    for a linear pressure even where the support is truncated (free surface), so the
    outermost layer, at p = 0, feels the full hydrostatic gradient.

    The moment matrix :math:`\mathbf{M}_i = \mathbf{L}_i^{-1}` is symmetric (the kernel
    gradient is radial) and equals the identity for a full support, I/2 for a half space
    and about :math:`2^{-d}` I for an orthant (a convex corner). Its eigenvalues are taken
    as at least :math:`2^{-d}`: in a direction the neighbourhood covers less than a
    corner's support does (a film one particle thick, a lone pair) it cannot tell the
    gradient, and the inverse would multiply the pressure of a neighbour by an unbounded
    factor, a force its reaction on the neighbour (the symmetric pair, eq. (37)) does not
    balance: the thin front of slope_failure on 2 ranks gained 1.5x the energy gravity can
    supply that way (docs/coupling.md). Exact wherever the support is at least a corner's.
    """
    n = indptr.shape[0] - 1
    out = np.zeros((n, dim))
    floor = 0.5 ** dim
    k = constants(h, dim)
    for i in range(n):
        if not fluid[i]:
            continue
        s0 = s1 = s2 = 0.0
        m00 = m01 = m02 = m11 = m12 = m22 = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            if wet is not None and not wet[j]:
                continue
            d0, d1, d2, r2 = delta(x, i, j, dim)
            vf = m[j] / rho[j] * fac_grad_k(math.sqrt(r2), k)
            dp = p[j] - p[i]
            s0 += dp * vf * d0
            s1 += dp * vf * d1
            s2 += dp * vf * d2
            m00 -= vf * d0 * d0
            m01 -= vf * d0 * d1
            m02 -= vf * d0 * d2
            m11 -= vf * d1 * d1
            m12 -= vf * d1 * d2
            m22 -= vf * d2 * d2
        g0, g1, g2 = _solve_floored(m00, m01, m02, m11, m12, m22, s0, s1, s2, floor, dim)
        _store(out, i, dim, g0, g1, g2)
    return out


@njit(cache=True, inline="always")
def _solve_floored(m00, m01, m02, m11, m12, m22, s0, s1, s2, floor, dim):
    """``M^-1 s`` of a symmetric 2x2 or 3x3 ``M`` with its eigenvalues taken as at least
    ``floor`` (closed-form eigen-decomposition, no LAPACK call, no allocation)."""
    if dim == 2:
        l0, l1, c, sn = _eig2(m00, m01, m11)
        t0 = (c * s0 + sn * s1) / max(l0, floor)
        t1 = (-sn * s0 + c * s1) / max(l1, floor)
        return c * t0 - sn * t1, sn * t0 + c * t1, 0.0
    e = _eig6(m00, m11, m22, m01, m02, m12)  # (l0, l1, l2, v0, v1, v2), ascending
    out0 = out1 = out2 = 0.0
    for q in range(3):
        x0, x1, x2 = e[3 + 3 * q], e[4 + 3 * q], e[5 + 3 * q]
        t = (x0 * s0 + x1 * s1 + x2 * s2) / max(e[q], floor)
        out0 += x0 * t
        out1 += x1 * t
        out2 += x2 * t
    return out0, out1, out2


@njit(cache=True, inline="always")
def _eig2(a, b, c):
    """Eigenvalues ``(l0, l1)`` of the symmetric ``[[a, b], [b, c]]`` and the rotation
    ``(cos, sin)`` whose columns ``(cos, sin)``, ``(-sin, cos)`` are their eigenvectors."""
    if b == 0.0:
        return a, c, 1.0, 0.0
    theta = 0.5 * math.atan2(2.0 * b, a - c)
    cs, sn = math.cos(theta), math.sin(theta)
    l0 = a * cs * cs + 2.0 * b * cs * sn + c * sn * sn
    l1 = a * sn * sn - 2.0 * b * cs * sn + c * cs * cs
    return l0, l1, cs, sn

