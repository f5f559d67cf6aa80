r"""Numba kernels of the IISPH step outside its two systems' blocks, and their row order.

Summation density and free surface, the order and CSR capacity of the systems' rows,
divergence and pressure gradients.

Every kernel loops over the owned rows ``0 .. n_owned - 1`` of the CSR neighbour lists
(owned rows first, halo rows after) and writes *global* indices: ``row[j]`` is the
global PETSc point of row ``j`` (owned or halo). A boundary particle (``fluid[j] == 0``:
a wall ghost particle, or a solid particle seen by the fluid) is an unknown like a fluid
particle, with its own row (Adami et al. 2012 fixed wall ghost particles, treated as
extra unknowns rather than substituted, so that the distributed assembly never needs a
neighbour's neighbours).

The two systems' blocks: :mod:`parsph.fluid.ppe` (pressure) and
:mod:`parsph.fluid.viscous` (viscous predictor).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.core.kernel import constants, delta, fac_grad_k, w_and_fac_grad_k, w_k
from parsph.core.tensor import _eig6

__all__ = ["WorkArrays", "density_and_surface", "fluid_weight_sum", "rows_in_order", "csr_capacity",
           "pressure_gradient", "pressure_gradient_corrected"]

#: A boundary particle (wall or solid) comes into contact with the fluid when the
#: summation density of its support, fluid and boundary particles together, reaches this
#: times its rest density (a fluid layer resting a spacing d away fills it), and stays in
#: contact down to the free surface's beta (see density_and_surface).
CONTACT = 0.97



class WorkArrays:
    """Work arrays kept from step to step: fresh arrays of a step's size would be
    allocated and page-faulted anew every step. Each set grows when too small (by a
    quarter, or to a tenth more than asked), never shrinks, and is named by a key."""

    def __init__(self):
        self._sets = {}

    def csr(self, system, capacity, key=None):
        """``(indptr, cols, values)`` for a CSR block of ``system``'s owned rows with room
        for ``capacity`` entries; ``cols`` has PETSc's index type. The PPE and the viscous
        preconditioner share the default set (``key`` None), as their matrices' storage."""
        key = key or "csr"
        ptr, cols, vals = self._sets.get(key, (None, None, None))
        if ptr is None or ptr.size != system.n_local + 1:
            ptr = np.zeros(system.n_local + 1, dtype=system.index_dtype)
        if cols is None or cols.size < capacity:
            size = max(int(capacity), int(1.25 * cols.size) if cols is not None else 0)
            cols, vals = np.empty(size, dtype=system.index_dtype), np.empty(size)
        self._sets[key] = ptr, cols, vals
        return ptr, cols, vals

    def floats(self, key, size):
        """``size`` float64 values (the first of the set ``key``)."""
        a = self._sets.get(key)
        if a is None or a.size < size:
            a = self._sets[key] = np.empty(int(1.1 * size) + 1)
        return a[:size]

    def idle(self, size):
        """``size`` float64 values of memory that holds nothing between two steps: the
        values of the default CSR set (the PPE's and the viscous preconditioner's storage,
        written afresh by every step before its solves), or None when it is smaller. A
        stage that runs between the fluid's steps (the TLSPH predictor of a coupled step)
        borrows it for its scratch instead of raising the peak by as much
        (:meth:`parsph.solid.stage.TLSPH.predict`)."""
        vals = self._sets.get("csr", (None, None, None))[2]
        return vals[:size] if vals is not None and vals.size >= size else None

    def drop(self, key) -> None:
        """Free the set ``key`` (if any)."""
        self._sets.pop(key, None)

@njit(cache=True, error_model="numpy")
def density_and_surface(x, v, m, fluid, rho0, indptr, indices, h, dim, beta, gamma, rho, free):
    r"""Summation density (33) of the owned fluid rows, the free-surface flag, and which
    boundary rows the fluid touches; returns the largest :math:`|\nabla\cdot\mathbf v|`
    (36) of the interior fluid rows (1/s, 0 if none), the ``max_divergence`` statistic.

    The divergence is that of ``v``, the velocity the step starts from (the last step's
    result), over the same pairs as the density, divided by the new density: one pass,
    where a pass of its own at the end of the step had cost 16 ms of a 0.49 s 3D step.

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
    max_div = 0.0
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
        div = 0.0
        v0, v1, v2 = _vec(v, i, dim)
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            d0, d1, d2, r2 = delta(x, i, j, dim)
            wij, fij = w_and_fac_grad_k(math.sqrt(r2), k)
            acc += m[j] * wij
            f = m[j] / rho0[j] * fij
            g0 += f * d0
            g1 += f * d1
            g2 += f * d2
            u0, u1, u2 = _vec(v, j, dim)
            div += m[j] * fij * ((u0 - v0) * d0 + (u1 - v1) * d1 + (u2 - v2) * d2)
        rho[i] = acc
        gnorm = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        free[i] = 1 if (acc < beta * rho0[i] or (acc < rho0[i] and h * gnorm > gamma)) else 0
        if free[i] == 0:
            max_div = max(max_div, abs(div / acc))
    return max_div


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy")
def rows_in_order(row, n, first):
    """The owned particles of the system in the order of their rows: ``order[r]`` is the
    particle of global row ``first + r``. The stage numbers the owned rows
    ``first, first + 1, ...`` in whatever order it likes (wall rows after the fluid's,
    see ``walls.row_order``); the CSR kernels write them in that order."""
    count = 0
    for i in range(n):
        if row[i] >= 0:
            count += 1
    order = np.empty(count, np.int64)
    for i in range(n):
        if row[i] >= 0:
            order[row[i] - first] = i
    return order


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", inline="always")
def _vec(v, i, dim):
    """Row ``i`` of an (N, dim) array as three scalars (the third 0 in 2D)."""
    return v[i, 0], v[i, 1], v[i, 2] if dim == 3 else 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _store(out, i, dim, a0, a1, a2):
    """Write three scalars to row ``i`` of an (N, dim) array (the third only in 3D)."""
    out[i, 0] = a0
    out[i, 1] = a1
    if dim == 3:
        out[i, 2] = a2


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
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
