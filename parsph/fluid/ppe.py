r"""The pressure Poisson equation of the IISPH step (eqs. (32), (35), (36)) as a CSR block.

Its rows and right-hand side, their scale, and the corrected Laplacian.

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
are described in :mod:`parsph.fluid.response`.

Rows and global numbering as in :mod:`parsph.fluid.assembly`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from decomposition.reduce import global_reduce
from parsph.core.kernel import constants, delta, fac_grad_k
from parsph.fluid.assembly import _vec, rows_in_order

__all__ = ["density_error_factor", "ppe_csr", "ppe_row_scale"]


def ppe_row_scale(rho, rho0, d):
    r"""Scale :math:`s_i = \rho_i d^2 / (2 \rho_{0i})` (m^2) of the fluid PPE rows.

    The assembled fluid row is eq. (35) = source of eq. (32), both multiplied by
    :math:`-s_i`, so that its coefficients :math:`-d^2 m_j F_{ij} / \rho_{0i}` are of
    order one (like the wall and free-surface rows) and the diagonal is positive.
    """
    return rho * d * d / (2.0 * rho0)


def density_error_factor(comm, scale, rho, interior, n_fluid, dt, d) -> float:
    r"""Collective: the factor :math:`c` for which :math:`c\,\|\tilde r\|_2` bounds the
    RMS relative density error that the pressure leaves over the fluid rows, where
    :math:`\tilde r` is the residual of the solved system (0 if there is no interior fluid
    row anywhere).

    The unscaled residual :math:`R_i` of eq. (32) is a density rate per unit time
    (kg m^-3 s^-2, like :math:`\alpha(\rho_0 - \rho_i)/\Delta t^2`): the density change
    the step's pressure leaves unbalanced is :math:`\delta\rho_i = \Delta t^2 R_i`, the
    quantity whose mean IISPH's iteration bounds (Ihmsen et al. 2014). The solved row is
    eq. (32) times :math:`s_i` (:func:`ppe_row_scale`) times ``scale_i`` (to a unit
    diagonal: ``1 / D_i``), so

    .. math::

        \frac{\delta\rho_i}{\rho_{0i}} = \frac{2 \Delta t^2}{d^2}
        \frac{D_i}{\rho_i} \tilde r_i, \qquad
        \sqrt{\frac{1}{N}\sum_{i \in \text{fluid}}
        \Big(\frac{\delta\rho_i}{\rho_{0i}}\Big)^2}
        \le \frac{2 \Delta t^2}{d^2} \max_i \frac{D_i}{\rho_i}
        \frac{\|\tilde r\|_2}{\sqrt N}

    with the maximum over the interior fluid rows (``interior``, in row order like
    ``scale`` and ``rho``) and :math:`N` the fluid rows of all ranks (``n_fluid`` here;
    a free-surface row's density is not constrained, its error counts as 0, as in the
    mean over all fluid particles of SPlisHSPlasH). Every other row's residual (wall,
    solid, free-surface rows) is in :math:`\|\tilde r\|_2` too: a bound, never an
    underestimate.
    """
    w = float(np.max(1.0 / (scale[interior] * rho[interior]))) if interior.any() else 0.0
    (n,), (w,), _ = global_reduce(comm, sums=(n_fluid,), maxs=(w,))
    return 2.0 * dt * dt * w / (d * d * math.sqrt(n)) if n > 0 and w > 0 else 0.0


@njit(cache=True, error_model="numpy")
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
      the solid-response term of :mod:`parsph.fluid.response`).
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
    ok, le0, le1, le2 = False, 0.0, 0.0, 0.0
    out_ptr[0] = 0
    k = 0
    order = rows_in_order(row, n, first)
    longest = 0
    for q in range(order.shape[0]):
        longest = max(longest, indptr[order[q] + 1] - indptr[order[q]])
    # (x_i - x_j, F_ij, V_j F_ij, (2 or 1) m_j)
    scratch = np.empty((longest if corrected else 0, 6))
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
        s = sr = 0.0
        div = 0.0
        plain = 0.0
        use_corr = False
        if interior or boundary:
            s = rho[i] * d * d / (2.0 * rho0[i])
            diag = 0.0
            v0, v1, v2 = _vec(vs, i, dim)
            if corrected and interior:
                # one pass over the neighbours (positions, kernel, v*) into a per-row
                # scratch, then the row from the scratch: the truncation needs the whole
                # row before any corrected coefficient (two passes over the neighbours
                # had cost 58 ms of a 3D step at 1.1e5 particles, the printed
                # Laplacian's one pass 29 ms)
                start = indptr[i]
                ok, le0, le1, le2, div = _truncation_and_divergence(
                    x, vs, m, rho, fluid, indptr, indices, i, kc, dim, v0, v1, v2, scratch)
                use_corr = ok
                sr = s / rho[i]
                for p in range(start, indptr[i + 1]):
                    rj = row[indices[p]]
                    if dslot < 0 and rj >= ri:
                        dslot, t, last = _scalar_slot(out_cols, out_vals, base, t, last, ri)
                    o = p - start
                    # >= 0: the pair's response; 1 where one end is a boundary (see above);
                    # (2 or 1) m_j from the scratch: -((2 or 1) sr) m_j F_ij, bit for bit
                    c = -(sr * scratch[o, 5]) * scratch[o, 3]
                    plain += c
                    if use_corr:
                        c = _corrected(c, s, le0, le1, le2, scratch, o)
                    diag += c
                    # a new column written at once, a repeated one (an image) added to
                    # (the slot's zero and its update in one: 24.4 -> 23.3 ms with the
                    # scratch's m_j, the 3D dam break's block)
                    if t > 0 and last == rj:
                        out_vals[base + t - 1] -= c
                    else:
                        out_cols[base + t] = rj
                        out_vals[base + t] = 0.0 - c
                        last = rj
                        t += 1
            else:
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
                    c = -s * (2.0 if fluid[i] and fluid[j] else 1.0) / rho[i] * m[j] * f
                    plain += c
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
                    o = p - indptr[i]
                    c = -(sr * scratch[o, 5]) * scratch[o, 3]
                    u = _column_slot(out_cols, base, t, row[j])
                    out_vals[base + u] += _corrected(c, s, le0, le1, le2, scratch, o) - c
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


@njit(cache=True, error_model="numpy", inline="always")
def _scalar_slot(cols, vals, base, t, last, col):
    """:func:`_slot` of a scalar system (one row, block size 1)."""
    if t > 0 and last == col:
        return t - 1, t, last
    cols[base + t] = col
    vals[base + t] = 0.0
    return t, t + 1, col


@njit(cache=True, error_model="numpy", inline="always")
def _corrected(c, s, le0, le1, le2, scratch, o):
    """The pair coefficient ``c`` of a fluid row with the first-order correction of the
    ``corrected`` Laplacian, + 2 s e_i . L_i V_j grad W_ij, kept >= 0 (an M-matrix row).
    ``(le0, le1, le2) = L_i e_i`` (:func:`_truncation_and_divergence`; L_i symmetric, so
    e_i . L_i r = (L_i e_i) . r); row ``o`` of ``scratch`` the pair's ``(x_i - x_j, F_ij,
    V_j F_ij, ...)``. The row's products taken once, not per pair: the PPE's block of the 3D
    tank of ``jobs/bench_memory.py`` 42.5 -> 40 ms (its second pass over a row's pairs
    is 26 ms of the 42.5, mostly loads and slot writes, not this product)."""
    eb = le0 * scratch[o, 0] + le1 * scratch[o, 1] + le2 * scratch[o, 2]
    return max(c - 2.0 * s * scratch[o, 4] * eb, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def _truncation_and_divergence(x, vs, m, rho, fluid, indptr, indices, i, k, dim, v0, v1,
                               v2, scratch):
    """``(ok, L e)`` of row ``i`` (``e`` = sum_j (m_j / rho_i) grad W_ij, ``L`` the
    inverse of the symmetric moment matrix sum_j V_j grad W_ij (x) (x_j - x_i), V_j =
    m_j / rho_j; ``ok`` False where it is near singular: no correction then) and, in the
    same pass, the sum ``sum_j m_j (v*_j - v*_i) . (x_i - x_j) F_ij`` of its divergence;
    each pair's ``(x_i - x_j, F_ij, V_j F_ij, (2 or 1) m_j)`` (2: a fluid j) goes to row
    ``p - indptr[i]`` of ``scratch``. Returns ``(ok, le0, le1, le2, div)``."""
    e0 = e1 = e2 = 0.0
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    div = 0.0
    start = indptr[i]
    for p in range(start, indptr[i + 1]):
        j = indices[p]
        d0, d1, d2, r2 = delta(x, i, j, dim)
        f = fac_grad_k(math.sqrt(r2), k)
        q = p - start
        scratch[q, 0] = d0
        scratch[q, 1] = d1
        scratch[q, 2] = d2
        scratch[q, 3] = f
        vf = m[j] / rho[j] * f
        scratch[q, 4] = vf
        scratch[q, 5] = (2.0 if fluid[j] else 1.0) * m[j]
        u0, u1, u2 = _vec(vs, j, dim)
        dvr = (u0 - v0) * d0 + (u1 - v1) * d1 + (u2 - v2) * d2
        div += m[j] * dvr * f
        a = m[j] / rho[i] * f
        e0 += a * d0
        e1 += a * d1
        e2 += a * d2
        b = -vf
        m00 += b * d0 * d0
        m01 += b * d0 * d1
        m02 += b * d0 * d2
        m11 += b * d1 * d1
        m12 += b * d1 * d2
        m22 += b * d2 * d2
    ok, (l00, l01, l02, l11, l12, l22) = _invert_sym(m00, m01, m02, m11, m12, m22, dim)
    return (ok, l00 * e0 + l01 * e1 + l02 * e2, l01 * e0 + l11 * e1 + l12 * e2,
            l02 * e0 + l12 * e1 + l22 * e2, div)


@njit(cache=True, error_model="numpy", inline="always")
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
