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

from parsph.kernel import fac_grad, normalisation, w

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
    w0 = normalisation(h, dim)
    gs = np.zeros(dim)
    for i in range(n):
        if not fluid[i]:
            acc = m[i] * w0
            touched = False
            for q in range(indptr[i], indptr[i + 1]):
                j = indices[q]
                r2 = 0.0
                for a in range(dim):
                    e = x[i, a] - x[j, a]
                    r2 += e * e
                touched = touched or fluid[j]
                acc += m[j] * w(math.sqrt(r2), h, dim)
            level = beta if free[i] == 0 else CONTACT
            free[i] = 0 if touched and acc >= level * rho0[i] else 1
            continue
        acc = m[i] * w0
        gs[:] = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            r2 = 0.0
            for a in range(dim):
                e = x[i, a] - x[j, a]
                r2 += e * e
            r = math.sqrt(r2)
            acc += m[j] * w(r, h, dim)
            f = m[j] / rho0[j] * fac_grad(r, h, dim)
            for a in range(dim):
                gs[a] += f * (x[i, a] - x[j, a])
        rho[i] = acc
        g2 = 0.0
        for a in range(dim):
            g2 += gs[a] * gs[a]
        free[i] = 1 if (acc < beta * rho0[i] or
                        (acc < rho0[i] and h * math.sqrt(g2) > gamma)) else 0


@njit(cache=True, inline="always")
def fluid_weight_sum(x, fluid, indptr, indices, i, h, dim):
    """sum_f W(r_if, h) over the fluid neighbours f of a wall particle i (Adami et al. 2012:
    the normalisation of the wall extrapolations of velocity and pressure)."""
    wsum = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        j = indices[p]
        if fluid[j]:
            r2 = 0.0
            for a in range(dim):
                e = x[i, a] - x[j, a]
                r2 += e * e
            wsum += w(math.sqrt(r2), h, dim)
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


@njit(cache=True)
def _viscous_pair(m, rho, nu, fluid, i, j, r2, h, dim, dt, eta2, morris):
    """Coefficient ``c`` (<= 0) of the pair (i, j) at distance squared ``r2`` in the
    viscous term of row ``i``, times dt: eq. (34) is ``c r r^T (v_i - v_j)``, Morris et
    al. (1997) ``c (v_i - v_j)``, ``r = x_i - x_j``. A boundary j takes row i's
    viscosity; a boundary row i its fluid partner's (coupling)."""
    nui = nu[i] if fluid[i] else nu[j]
    nuj = nu[j] if fluid[j] else nui
    f = fac_grad(math.sqrt(r2), h, dim)
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
def viscous_csr(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim, dt,
                g, morris, first, out_ptr, out_cols, out_vals):
    """CSR block and right-hand side of the implicit viscous predictor (30)/(34).

    Writes the owned scalar rows (block size ``dim``: component ``a`` of global point
    ``P`` is row ``P dim + a``) straight into ``out_ptr`` (``n_local + 1``), ``out_cols``
    and ``out_vals`` (capacity ``dim^2 (pairs + n_owned)``): columns sorted and distinct
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
    diag = np.empty((dim, dim))
    r = np.empty(dim)
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
        diag[:, :] = 0.0
        for a in range(dim):
            diag[a, a] = 1.0
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
                if ghost:
                    r2 = 0.0
                    for a in range(dim):
                        e = x[i, a] - x[j, a]
                        r2 += e * e
                    wij = w(math.sqrt(r2), h, dim) / wsum
                    for a in range(dim):
                        out_vals[base + a * span + s] += wij
                    continue
                r2 = 0.0
                for a in range(dim):
                    r[a] = x[i, a] - x[j, a]
                    r2 += r[a] * r[a]
                c = _viscous_pair(m, rho, nu, fluid, i, j, r2, h, dim, dt, eta2, morris) \
                    * (1.0 if fluid[i] else solid[i])
                if morris:
                    for a in range(dim):
                        diag[a, a] -= c
                        out_vals[base + a * span + s] += c
                    continue
                for a in range(dim):
                    for b in range(dim):
                        e = c * r[a] * r[b]
                        diag[a, b] -= e
                        out_vals[base + a * span + s * dim + b] += e
        if dslot < 0:
            dslot, t, last = _slot(out_cols, out_vals, base, span, bw, dim, t, last, ri)
        for a in range(dim):
            if bw == dim:
                for b in range(dim):
                    out_vals[base + a * span + dslot * dim + b] += diag[a, b]
            else:
                out_vals[base + a * span + dslot] += diag[a, a]
        k = _close_rows(out_cols, out_vals, out_ptr, base, span, bw, dim, t, ri - first)
    return k, rhs


@njit(cache=True)
def ghost_velocity(x, v, fluid, slip, indptr, indices, h, dim, out):
    """No-slip ghost velocity of the owned wall rows from the fluid's present velocity,
    ``out[w] = 2 v_w - sum_f W_wf v_f / sum_f W_wf`` (Adami et al. 2012, eqs. (22)-(23)):
    the wall rows of :func:`viscous_csr` solved on their own. Wall rows without fluid
    neighbours get ``v_w``; fluid and free-slip rows are left as they are."""
    n = indptr.shape[0] - 1
    acc = np.empty(dim)
    for i in range(n):
        if fluid[i] or slip[i]:
            continue
        wsum = 0.0  # one pass: sum_f W_wf and sum_f W_wf v_f together
        acc[:] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if fluid[j]:
                r2 = 0.0
                for a in range(dim):
                    e = x[i, a] - x[j, a]
                    r2 += e * e
                wij = w(math.sqrt(r2), h, dim)
                wsum += wij
                for a in range(dim):
                    acc[a] += wij * v[j, a]
        for a in range(dim):
            out[i, a] = 2.0 * v[i, a] - acc[a] / wsum if wsum > 0.0 else v[i, a]


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
    for i in range(n):
        for a in range(dim):
            out[i, a] = v[i, a] + dt * g[a] if fluid[i] else v[i, a]
        if not fluid[i]:
            continue
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            fj = fluid[j]
            if not fj and slip[j]:
                continue
            r2 = 0.0
            dr = 0.0
            for a in range(dim):
                e = x[i, a] - x[j, a]
                r2 += e * e
                dr += (v[i, a] - (v[j, a] if fj else v_ghost[j, a])) * e
            c = _viscous_pair(m, rho, nu, fluid, i, j, r2, h, dim, dt, eta2, morris)
            for a in range(dim):
                if morris:
                    out[i, a] += c * (v[i, a] - (v[j, a] if fj else v_ghost[j, a]))
                else:
                    out[i, a] += c * (x[i, a] - x[j, a]) * dr
    return out


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
    ev = np.zeros(dim)
    L = np.zeros((dim, dim))
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
                use_corr = _truncation_vector(x, m, rho, indptr, indices, i, h, dim, ev, L)
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                if boundary and not fluid[j]:
                    continue
                rj = row[j]
                if dslot < 0 and rj >= ri:
                    dslot, t, last = _slot(out_cols, out_vals, base, 0, 1, 1, t, last, ri)
                slot, t, last = _slot(out_cols, out_vals, base, 0, 1, 1, t, last, rj)
                r2 = 0.0
                dvr = 0.0
                for a in range(dim):
                    e = x[i, a] - x[j, a]
                    r2 += e * e
                    dvr += (vs[j, a] - vs[i, a]) * e
                f = fac_grad(math.sqrt(r2), h, dim)
                div += m[j] * dvr * f
                # >= 0: the pair's response; 1 where one end is a boundary (see above)
                c = -s * (2.0 if fluid[i] and fluid[j] else 1.0) / rho[i] * m[j] * f
                plain += c
                if use_corr:
                    c = _corrected(c, x, m, rho, i, j, f, s, ev, L, dim)
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
                    r2 = 0.0
                    for a in range(dim):
                        e = x[i, a] - x[j, a]
                        r2 += e * e
                    f = fac_grad(math.sqrt(r2), h, dim)
                    c = -s * (2.0 if fluid[j] else 1.0) / rho[i] * m[j] * f
                    u = _column_slot(out_cols, base, t, row[j])
                    out_vals[base + u] += _corrected(c, x, m, rho, i, j, f, s, ev, L, dim) - c
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
            dslot, t, last = _slot(out_cols, out_vals, base, 0, 1, 1, t, last, ri)
        out_vals[base + dslot] += diag
        k = base + t
        out_ptr[ri - first + 1] = k
    return k, rhs


@njit(cache=True, inline="always")
def _corrected(c, x, m, rho, i, j, f, s, ev, L, dim):
    """The pair coefficient ``c`` of a fluid row with the first-order correction of the
    ``corrected`` Laplacian, + 2 s e_i . L_i V_j grad W_ij, kept >= 0 (an M-matrix row)."""
    eb = 0.0
    for a in range(dim):
        la = 0.0
        for b in range(dim):
            la += L[a, b] * (x[i, b] - x[j, b])
        eb += ev[a] * la
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


@njit(cache=True)
def _truncation_vector(x, m, rho, indptr, indices, i, h, dim, ev, L):
    """``ev`` = sum_j (m_j / rho_i) grad W_ij and ``L`` = the inverse of
    sum_j V_j grad W_ij (x) (x_j - x_i) of row ``i``; False where that matrix is near
    singular (no correction then)."""
    ev[:] = 0.0
    M = L  # accumulated in place, inverted below
    M[:, :] = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        j = indices[p]
        r2 = 0.0
        for a in range(dim):
            e = x[i, a] - x[j, a]
            r2 += e * e
        f = fac_grad(math.sqrt(r2), h, dim)
        for a in range(dim):
            ga = f * (x[i, a] - x[j, a])
            ev[a] += m[j] / rho[i] * ga
            for b in range(dim):
                M[a, b] += m[j] / rho[j] * ga * (x[j, b] - x[i, b])
    return _invert_small(M, dim)


@njit(cache=True)
def _invert_small(M, dim):
    """Invert the 2x2 or 3x3 matrix ``M`` in place (no LAPACK call, no allocation);
    False (``M`` unchanged) where it is near singular: trace <= 0 or
    det <= 1e-3 (trace / dim)^dim."""
    tr = 0.0
    for a in range(dim):
        tr += M[a, a]
    if tr <= 0.0:
        return False
    if dim == 2:
        det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        if det <= 1e-3 * (tr / 2) ** 2:
            return False
        a00, a01, a10, a11 = M[0, 0], M[0, 1], M[1, 0], M[1, 1]
        M[0, 0], M[0, 1], M[1, 0], M[1, 1] = a11 / det, -a01 / det, -a10 / det, a00 / det
        return True
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    if det <= 1e-3 * (tr / 3) ** 3:
        return False
    inv = np.empty((3, 3))
    inv[0, 0] = c00
    inv[1, 0] = c01
    inv[2, 0] = c02
    inv[0, 1] = M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]
    inv[1, 1] = M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]
    inv[2, 1] = M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]
    inv[0, 2] = M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]
    inv[1, 2] = M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]
    inv[2, 2] = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    for a in range(3):
        for b in range(3):
            M[a, b] = inv[a, b] / det
    return True


@njit(cache=True)
def divergence(x, vs, m, rho, fluid, indptr, indices, h, dim):
    """Velocity divergence (36) of the owned fluid rows (1/s); 0 elsewhere."""
    n = indptr.shape[0] - 1
    out = np.zeros(n)
    for i in range(n):
        if not fluid[i]:
            continue
        acc = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            r2 = 0.0
            dvr = 0.0
            for a in range(dim):
                e = x[i, a] - x[j, a]
                r2 += e * e
                dvr += (vs[j, a] - vs[i, a]) * e
            acc += m[j] * dvr * fac_grad(math.sqrt(r2), h, dim)
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
    for i in range(n):
        if not fluid[i]:
            continue
        pi = p[i] / (rho[i] * rho[i])
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            r2 = 0.0
            for a in range(dim):
                e = x[i, a] - x[j, a]
                r2 += e * e
            c = rho[i] * m[j] * (pi + p[j] / (rho[j] * rho[j])) * fac_grad(math.sqrt(r2), h, dim)
            for a in range(dim):
                out[i, a] += c * (x[i, a] - x[j, a])
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
    M = np.zeros((dim, dim))
    s = np.zeros(dim)
    floor = 0.5 ** dim
    for i in range(n):
        if not fluid[i]:
            continue
        M[:, :] = 0.0
        s[:] = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            if wet is not None and not wet[j]:
                continue
            r2 = 0.0
            for a in range(dim):
                e = x[i, a] - x[j, a]
                r2 += e * e
            vf = m[j] / rho[j] * fac_grad(math.sqrt(r2), h, dim)
            for a in range(dim):
                ga = vf * (x[i, a] - x[j, a])
                s[a] += (p[j] - p[i]) * ga
                for b in range(dim):
                    M[a, b] += ga * (x[j, b] - x[i, b])
        lam, Q = np.linalg.eigh(M)
        for a in range(dim):
            acc = 0.0
            for k in range(dim):
                c = 0.0
                for b in range(dim):
                    c += Q[b, k] * s[b]
                acc += Q[a, k] * c / max(lam[k], floor)
            out[i, a] = acc
    return out

