r"""The strongly coupled pressure step: the PPE sees the soil's inertia (docs/coupling.md).

Paper section 5.3: "the coupling force must be calculated concurrently for both phases",
and type-II solid particles (solid particles with fluid neighbours, Fig. 2) are unknowns
of the PPE. Here the velocity the fluid's divergence (36) sees at a type-II particle
:math:`s` is its velocity *after* the pressure has acted on it,

.. math::

    \mathbf v_s^{\beta+1} = \mathbf v_s^* + \Delta t\,\mathbf a_s(p), \qquad
    \mathbf a_s(p) = W_s \sum_b \mathbf G_{sb}\, p_b ,

with :math:`\mathbf a_s` the reaction of eqs. (45)/(48) on the solid's true mass
(:math:`W_s = 1/m_s^{true}` per component, 0 on a component a ``[[constraints]]`` box
holds) and the pair pressure force of eq. (37),

.. math::

    \mathbf G_{ss} = -\frac{m_s}{\rho_s^2} \sum_f m_f c_f \nabla W_{sf}, \qquad
    \mathbf G_{sf} = -\frac{m_s m_f c_f}{\rho_f^2} \nabla W_{sf}, \qquad
    c_f = \rho_f / \rho_{0f},

(:math:`m_s`, :math:`\rho_s`: the mass and density the fluid sees a solid particle with).
A fluid row :math:`i` of the PPE (scaled by :math:`-s_i`, see
:func:`parsph.fluid.ppe.ppe_row_scale`) then reads

.. math::

    -s_i \langle\nabla^2 p\rangle_i + \frac{d^2}{2} \sum_{s} \mathbf D_{si}\cdot\mathbf a_s(p)
    = -s_i \Big(\frac{\rho_0}{\Delta t}\langle\nabla\cdot\mathbf v^*\rangle_i
    + \alpha\frac{\rho_0 - \rho_i}{\Delta t^2}\Big),
    \qquad \mathbf D_{si} = m_s \nabla W_{is},

and the row of a type-II solid particle is the non-penetration of its fluid neighbours,
:math:`\langle\nabla\cdot\mathbf v^{\beta+1}\rangle_s = 0` over its fluid neighbours only
(the adjoint of its pressure's force), with the fluid's response to the pressure taken
along each pair (:math:`\nabla p_f\cdot(\mathbf x_s - \mathbf x_f) \approx p_s - p_f`,
exact for a linear pressure),

.. math::

    -\frac{d^2}{2}\frac{1}{\rho_s}\sum_f m_f F_{sf}(p_s - p_f)
    + \frac{d^2}{2}\mathbf D_{ss}\cdot\mathbf a_s(p)
    = -\frac{d^2}{2}\frac{\rho_{0}}{\rho_s \Delta t}\sum_f m_f(\mathbf v^*_f - \mathbf v^*_s)
      \cdot\nabla W_{sf}, \qquad \mathbf D_{ss} = -\sum_f m_f \nabla W_{sf}.

The solid-response term :math:`\frac{d^2}{2}\mathbf D^T W \mathbf G` couples two fluid
rows through a shared solid neighbour (up to 4h apart). It is applied as the product of
two sparse blocks with one row per owned type-II particle and component
(:func:`response_blocks`, ``D`` and :math:`\frac{d^2}{2}W\mathbf G`), so the operator is
exact on any rank count; the preconditioner's matrix gets the part of it between rows
that are neighbours (:func:`add_near_response`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.fluid.ppe import _column_slot
from parsph.core.kernel import constants, delta, fac_grad_k

__all__ = ["self_response", "response_blocks", "add_near_response", "solid_pressure_force"]


@njit(cache=True, error_model="numpy", inline="always")
def _grad(x, i, j, k, dim):
    """grad W_ij = F(r_ij) (x_i - x_j) as three scalars (the third 0 in 2D); ``k`` the
    kernel's :func:`parsph.core.kernel.constants`."""
    d0, d1, d2, r2 = delta(x, i, j, dim)
    f = fac_grad_k(math.sqrt(r2), k)
    return f * d0, f * d1, f * d2


@njit(cache=True, error_model="numpy", inline="always")
def _dot(u0, u1, u2, v, i, dim):
    """(u0, u1, u2) . row ``i`` of an (N, dim) array."""
    acc = u0 * v[i, 0] + u1 * v[i, 1]
    return acc + u2 * v[i, 2] if dim == 3 else acc


@njit(cache=True, error_model="numpy")
def self_response(x, m, rho, rho0, fluid, solid, inv_mass, indptr, indices, h, dim):
    r""":math:`W_s \mathbf G_{ss}` (m s^-2 Pa^-1) of the owned rows with ``solid[s] > 0``:
    the acceleration of a solid particle per unit of its own pressure, over all its fluid
    neighbours; zero for the other rows. Shape (n, dim)."""
    n = indptr.shape[0] - 1
    out = np.zeros((n, dim))
    k = constants(h, dim)
    for s in range(n):
        if solid[s] <= 0.0:
            continue
        a0 = a1 = a2 = 0.0
        for q in range(indptr[s], indptr[s + 1]):
            f = indices[q]
            if not fluid[f]:
                continue
            g0, g1, g2 = _grad(x, s, f, k, dim)
            c = -m[s] * m[f] * (rho[f] / rho0[f]) / (rho[s] * rho[s])
            a0 += c * g0
            a1 += c * g1
            a2 += c * g2
        out[s, 0] = a0 * inv_mass[s, 0]
        out[s, 1] = a1 * inv_mass[s, 1]
        if dim == 3:
            out[s, 2] = a2 * inv_mass[s, 2]
    return out


@njit(cache=True, error_model="numpy", inline="always")  # a call per pair otherwise: 2x slower
def _unknown(fluid, free, solid, row, j):
    """Whether row ``j`` is a pressure unknown the response couples to: an interior fluid
    row or a type-II solid row in contact with the fluid (free rows are p = 0)."""
    if row[j] < 0 or free[j]:
        return False
    return fluid[j] or solid[j] > 0.0


@njit(cache=True, error_model="numpy")
def response_blocks(x, m, rho, rho0, fluid, free, solid, row, inv_mass, indptr, indices, h,
                    dim, d):
    r"""The two sparse blocks ``D`` and :math:`\frac{d^2}{2} W \mathbf G` of the
    solid-response term, one row per owned type-II solid particle (``solid[s] > 0`` and
    ``row[s] >= 0``) and component (row ``k dim + a`` for the ``k``-th such particle),
    columns the global PPE rows of the particle and of its interior fluid neighbours,
    sorted (neighbour lists sorted by ``row``; a repeated column, a periodic image, is
    merged).

    Returns ``(indptr, cols, left, right)``: ``left`` holds ``D``, ``right`` the
    :math:`\frac{d^2}{2} W \mathbf G` values on the same pattern; the response term of
    the PPE is ``left^T right`` (see the module docstring).
    """
    n = indptr.shape[0] - 1
    count = 0
    cap = 0
    for s in range(n):
        if solid[s] > 0.0 and row[s] >= 0:
            count += 1
            cap += indptr[s + 1] - indptr[s] + 1
    ptr = np.zeros(count * dim + 1, np.int64)
    cols = np.empty(cap * dim, np.int64)
    left = np.zeros(cap * dim)
    right = np.zeros(cap * dim)
    kc = constants(h, dim)
    g = np.empty(3)
    dss = np.empty(3)
    gss = np.empty(3)
    half = 0.5 * d * d
    k = 0
    r = 0
    for s in range(n):
        if not (solid[s] > 0.0 and row[s] >= 0):
            continue
        # the columns: the particle itself and its interior fluid neighbours, in global
        # row order (the particle inserted where it belongs)
        base = k
        t = 0
        own = False
        for q in range(indptr[s], indptr[s + 1] + 1):
            f = indices[q] if q < indptr[s + 1] else -1
            if not own and (f < 0 or row[f] >= row[s]):
                own = True
                if not free[s]:  # a solid not in contact with the fluid has p = 0
                    cols[base + t] = row[s]
                    t += 1
            if f < 0 or not fluid[f] or free[f] or row[f] < 0:
                continue
            if t == 0 or cols[base + t - 1] != row[f]:
                cols[base + t] = row[f]
                t += 1
        for a in range(1, dim):
            for u in range(t):
                cols[base + a * t + u] = cols[base + u]
        for u in range(dim * t):
            left[base + u] = 0.0
            right[base + u] = 0.0
        dss[:] = 0.0
        gss[:] = 0.0
        for q in range(indptr[s], indptr[s + 1]):
            f = indices[q]
            if not fluid[f]:
                continue
            g[0], g[1], g[2] = _grad(x, s, f, kc, dim)  # grad W_sf
            c = m[f] * rho[f] / rho0[f]
            for a in range(dim):
                dss[a] -= m[f] * g[a]
                gss[a] -= m[s] * c / (rho[s] * rho[s]) * g[a]
            if free[f] or row[f] < 0:
                continue
            u = _column_slot(cols, base, t, row[f])
            c = -m[s] * c / (rho[f] * rho[f])
            for a in range(dim):
                left[base + a * t + u] -= m[s] * g[a]
                right[base + a * t + u] += half * inv_mass[s, a] * c * g[a]
        if not free[s]:
            u = _column_slot(cols, base, t, row[s])
            for a in range(dim):
                left[base + a * t + u] += dss[a]
                right[base + a * t + u] += half * inv_mass[s, a] * gss[a]
        for a in range(dim):
            r += 1
            ptr[r] = base + (a + 1) * t
        k = base + dim * t
    return ptr, cols[:k], left[:k], right[:k]


@njit(cache=True, error_model="numpy")
def near_capacity(fluid, free, solid, row, indptr, indices, first, ptr):
    """Entries :func:`add_near_response` writes to its ``near_*`` block: the whole PPE
    row (``ptr``: rows in global order from ``first``) of each row it touches, i.e. an
    interior fluid row with a type-II solid neighbour that has a row, or a type-II row.
    The block is sized by this count, not by the PPE's: most rows touch no solid (in a
    tank whose soil is not yet wet, none)."""
    n = indptr.shape[0] - 1
    total = 0
    for i in range(n):
        if row[i] < 0 or free[i]:
            continue
        touched = (not fluid[i]) and solid[i] > 0.0
        if fluid[i]:
            for q in range(indptr[i], indptr[i + 1]):
                s = indices[q]
                if not fluid[s] and solid[s] > 0.0 and row[s] >= 0:
                    touched = True
                    break
        if touched:
            rr = row[i] - first
            total += ptr[rr + 1] - ptr[rr]
    return total


@njit(cache=True, error_model="numpy")
def add_near_response(x, m, rho, rho0, fluid, free, solid, row, inv_mass, a_self, indptr,
                      indices, h, dim, d, first, ptr, cols, vals, near_ptr, near_cols,
                      near_vals):
    r"""Add the solid-response term between rows that are neighbours to the PPE's CSR
    block (``ptr``, ``cols``, ``vals``: rows in global order from ``first``, columns
    sorted), and write that part alone to ``near_*`` (same row layout; capacity of
    ``cols``). Returns the entries of ``near``.

    Row of an interior fluid particle :math:`i`, column :math:`b` (itself or a
    neighbour): :math:`\frac{d^2}{2}\sum_s \mathbf D_{si}\cdot W_s\mathbf G_{sb}` over its
    type-II solid neighbours :math:`s` (``a_self`` = :math:`W_s \mathbf G_{ss}` of every
    row, owned and halo, for :math:`b = s`; :math:`\mathbf G_{sb}` vanishes beyond the
    support of :math:`s`). Row of a type-II particle: the whole term (its columns are
    its own and its fluid neighbours'). The pairs of fluid rows that share a solid
    neighbour but are not neighbours (up to 4h apart) are left to the operator's
    product (:func:`response_blocks`).
    """
    n = indptr.shape[0] - 1
    nrows = ptr.shape[0] - 1
    half = 0.5 * d * d
    kc = constants(h, dim)
    k = 0
    near_ptr[0] = 0
    order = np.empty(nrows, np.int64)
    longest = 0
    for i in range(n):
        if row[i] >= 0:
            order[row[i] - first] = i
        longest = max(longest, indptr[i + 1] - indptr[i])
    # an interior row's columns b (its fluid unknowns and itself, in list order) and their
    # slots, found once per row, not once per solid neighbour (the term's cost had been
    # a slot search and a kernel gradient per solid neighbour and list entry: 41 ms of a
    # 3D slab's coupled step of 235 ms)
    cand = np.empty(longest + 1, np.int64)
    slot = np.empty(longest + 1, np.int64)
    for rr in range(nrows):
        i = order[rr]
        start, stop = ptr[rr], ptr[rr + 1]
        touched = False
        interior = fluid[i] and not free[i]
        typeii = (not fluid[i]) and solid[i] > 0.0 and not free[i]
        if interior:
            nc = -1  # (the columns b: found at the first solid neighbour)
            for q in range(indptr[i], indptr[i + 1]):
                s = indices[q]
                if fluid[s] or solid[s] <= 0.0 or row[s] < 0:
                    continue
                if nc < 0:
                    nc = 0
                    for qq in range(indptr[i], indptr[i + 1] + 1):
                        b = indices[qq] if qq < indptr[i + 1] else i
                        if _unknown(fluid, free, solid, row, b) and fluid[b]:
                            cand[nc] = b
                            slot[nc] = _column_slot(cols, start, stop - start, row[b])
                            nc += 1
                if not touched:
                    for u in range(start, stop):
                        near_cols[k + u - start] = cols[u]
                        near_vals[k + u - start] = 0.0
                    touched = True
                g0, g1, g2 = _grad(x, i, s, kc, dim)  # grad W_is
                e0, e1, e2 = m[s] * g0, m[s] * g1, m[s] * g2
                if not free[s]:  # b = s: the particle's own pressure
                    u = _column_slot(cols, start, stop - start, row[s])
                    val = _dot(e0, e1, e2, a_self, s, dim)
                    vals[start + u] += half * val
                    near_vals[k + u] += half * val
                # b = i itself and its other neighbours within the support of s
                for t in range(nc):
                    b = cand[t]
                    d0, d1, d2, r2 = delta(x, s, b, dim)
                    f = fac_grad_k(math.sqrt(r2), kc)
                    if f == 0.0:  # beyond the support of s: no term
                        continue
                    g0, g1, g2 = f * d0, f * d1, f * d2  # grad W_sb
                    c = -m[s] * m[b] * rho[b] / rho0[b] / (rho[b] * rho[b])
                    val = e0 * inv_mass[s, 0] * c * g0 + e1 * inv_mass[s, 1] * c * g1
                    if dim == 3:
                        val += e2 * inv_mass[s, 2] * c * g2
                    if val == 0.0:
                        continue
                    u = slot[t]
                    vals[start + u] += half * val
                    near_vals[k + u] += half * val
        elif typeii:
            e0 = e1 = e2 = 0.0
            for q in range(indptr[i], indptr[i + 1]):
                f = indices[q]
                if fluid[f]:
                    g0, g1, g2 = _grad(x, i, f, kc, dim)
                    e0 -= m[f] * g0
                    e1 -= m[f] * g1
                    e2 -= m[f] * g2
            for u in range(start, stop):
                near_cols[k + u - start] = cols[u]
                near_vals[k + u - start] = 0.0
            touched = True
            u = _column_slot(cols, start, stop - start, row[i])
            val = _dot(e0, e1, e2, a_self, i, dim)
            vals[start + u] += half * val
            near_vals[k + u] += half * val
            for q in range(indptr[i], indptr[i + 1]):
                f = indices[q]
                if not fluid[f] or free[f] or row[f] < 0:
                    continue
                g0, g1, g2 = _grad(x, i, f, kc, dim)
                c = -m[i] * m[f] * rho[f] / rho0[f] / (rho[f] * rho[f])
                val = e0 * inv_mass[i, 0] * c * g0 + e1 * inv_mass[i, 1] * c * g1
                if dim == 3:
                    val += e2 * inv_mass[i, 2] * c * g2
                u = _column_slot(cols, start, stop - start, row[f])
                vals[start + u] += half * val
                near_vals[k + u] += half * val
        if touched:
            k += stop - start
        near_ptr[rr + 1] = k
    return k


@njit(cache=True, error_model="numpy")
def solid_pressure_force(x, p, m, rho, rho0, fluid, solid, indptr, indices, h, dim):
    r""":math:`\sum_b \mathbf G_{sb} p_b` (N, N/m in 2D) of the owned rows with
    ``solid[s] > 0``: the fluid's pressure force on a solid particle (eq. (45)), the exact
    reaction of what its fluid neighbours get from it through eqs. (37) and (31); zero
    for the other rows. Times the inverse true mass (zero on held components) it is the
    acceleration :math:`\mathbf a_s(p)` of eq. (48). Shape (n, dim)."""
    n = indptr.shape[0] - 1
    out = np.zeros((n, dim))
    k = constants(h, dim)
    for s in range(n):
        if solid[s] <= 0.0:
            continue
        ps = p[s] / (rho[s] * rho[s])
        a0 = a1 = a2 = 0.0
        for q in range(indptr[s], indptr[s + 1]):
            f = indices[q]
            if not fluid[f]:
                continue
            g0, g1, g2 = _grad(x, s, f, k, dim)
            c = -m[s] * m[f] * rho[f] / rho0[f] * (ps + p[f] / (rho[f] * rho[f]))
            a0 += c * g0
            a1 += c * g1
            a2 += c * g2
        out[s, 0] = a0
        out[s, 1] = a1
        if dim == 3:
            out[s, 2] = a2
    return out
