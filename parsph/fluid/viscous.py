r"""The viscous predictor of the IISPH step (eqs. (30), (34)), implicit or explicit.

Its CSR block (the implicit system), the no-slip ghost velocity, and the same operator
applied explicitly.

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

Rows and global numbering as in :mod:`parsph.fluid.assembly`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.core.kernel import constants, delta, fac_grad_k, w_k
from parsph.fluid.assembly import _store, _vec, fluid_weight_sum, rows_in_order

__all__ = ["viscous_csr", "viscous_pairs", "pair_offsets", "viscous_apply", "viscous_explicit",
           "ghost_velocity"]

#: eta^2 / h^2 of the viscous term (avoids 1/r^2 blowing up for coincident particles).
ETA2 = 0.01


@njit(cache=True, error_model="numpy", inline="always")  # a call per pair otherwise: 2x slower
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy", inline="always")
def _viscous_pair(m, rho, nu, fluid, i, j, r2, k, dim, dt, eta2, morris):
    """Coefficient ``c`` (<= 0) of the pair (i, j) at distance squared ``r2`` in the
    viscous term of row ``i``, times dt: eq. (34) is ``c r r^T (v_i - v_j)``, Morris et
    al. (1997) ``c (v_i - v_j)``, ``r = x_i - x_j``. A boundary j takes row i's
    viscosity; a boundary row i its fluid partner's (coupling). ``k``: the kernel's
    :func:`parsph.core.kernel.constants`."""
    nui = nu[i] if fluid[i] else nu[j]
    nuj = nu[j] if fluid[j] else nui
    f = fac_grad_k(math.sqrt(r2), k)
    if morris:
        return dt * m[j] * (rho[i] * nui + rho[j] * nuj) / (rho[i] * rho[j]) * f \
            * r2 / (r2 + eta2)
    return dt * m[j] * 2.0 * (dim + 2) * (nui + nuj) / ((rho[i] + rho[j]) * (r2 + eta2)) * f


@njit(cache=True, error_model="numpy")
def viscous_pairs(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim, dt,
                  g, morris, first, out_ptr, out_cols, out_vals, coef, at, kind, reach,
                  diag):
    """The matrix-free form of :func:`viscous_csr`: the scalar preconditioner matrix (one
    row per point), each pair's coefficient in ``coef`` (pair ``p`` of particle ``i`` at
    ``at[i] + p``, :func:`pair_offsets`) and each row's form in ``kind`` (see there) for
    :func:`viscous_apply`. The preconditioner's moving rows keep the pairs closer than
    ``reach`` (m; 0: all), see :func:`_viscous_rows`. With a ``diag`` of one value per
    row, only the matrix's diagonal is written there (Jacobi needs no more) and the
    ``out_`` arrays are not touched: ``coef`` may then be the memory of ``out_vals``.
    Returns ``(nnz, rhs)`` (nnz 0 with ``diag``)."""
    return _viscous_rows(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim,
                         dt, g, morris, first, out_ptr, out_cols, out_vals, True, coef, at,
                         kind, reach * reach if reach > 0.0 else np.inf, diag)


@njit(cache=True, error_model="numpy")
def pair_offsets(order, fluid, solid, slip, indptr, indices, at):
    """Where :func:`viscous_pairs` puts the pair coefficients of the rows ``order`` (local
    particles): pair ``p`` of particle ``i`` (its neighbour list entry) at ``coef[at[i] +
    p]``, the rows that can have pairs one after another: the moving ones (fluid, solid
    > 0) and the no-slip walls with a fluid neighbour. Writes ``at`` (one per owned
    particle; that of the other rows is left as it was) and returns the number of
    coefficients. One per pair of every list had been 257 bytes per particle in the 3D
    tank of ``jobs/bench_memory.py``, whose type-I solids and dry walls have none."""
    k = 0
    for q in range(order.shape[0]):
        i = order[q]
        need = fluid[i] or solid[i] > 0.0
        if not need and not slip[i]:
            for p in range(indptr[i], indptr[i + 1]):
                if fluid[indices[p]]:
                    need = True
                    break
        if need:
            at[i] = k - indptr[i]
            k += indptr[i + 1] - indptr[i]
    return k


@njit(cache=True, error_model="numpy")
def viscous_csr(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim, dt,
                g, morris, first, out_ptr, out_cols, out_vals):
    """CSR block and right-hand side of the implicit viscous predictor (30)/(34); see
    :func:`_viscous_rows`. Returns ``(nnz, rhs)``."""
    return _viscous_rows(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim,
                         dt, g, morris, first, out_ptr, out_cols, out_vals, False,
                         np.empty(0), np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int8),
                         np.inf, np.empty(0))


@njit(cache=True, error_model="numpy")
def _viscous_rows(x, v, m, rho, nu, fluid, solid, slip, row, indptr, indices, h, dim, dt,
                  g, morris, first, out_ptr, out_cols, out_vals, scalar, coef, at, kind,
                  reach2, diag):
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

    Assembled use (:func:`viscous_csr`): ``scalar`` False, ``coef`` and ``kind`` empty.
    Matrix-free use (:func:`viscous_pairs`, :func:`viscous_apply`): with ``scalar`` the block writes one scalar
    row per point (columns ``P``) whose pair entries are the blocks' traces over ``dim``,
    ``c r^2 / dim`` (the preconditioner's scalar Laplacian, one matrix for every
    component); ``coef`` (pair ``p`` of particle ``i`` at ``at[i] + p``) receives each pair's
    coefficient (``c``; ``W_wf / sum W`` of a no-slip wall row; 0 for a pair left out) and
    ``kind`` (one per owned particle) the row's form: 0 the blocks ``c r r^T`` of eq.
    (34), 1 Morris's ``c I``, 2 a no-slip ghost row, 3 an identity row. A scalar moving
    row leaves out the pairs at ``r^2 >= reach2`` with their share of its diagonal (the
    row sum stays 1, as the operator's): a sparser matrix for BoomerAMG, while ``coef``
    keeps every pair, so the operator the Krylov method solves is unchanged
    (docs/solvers.md).
    """
    n = indptr.shape[0] - 1
    rhs = np.zeros((n, dim))
    eta2 = ETA2 * h * h
    kc = constants(h, dim)
    nd = 1 if scalar else dim  # scalar rows per point
    pairs = coef.shape[0] > 0
    write = diag.shape[0] == 0  # the matrix (else its diagonal only)
    if write:
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
        bw = dim if moving and not morris and not scalar else 1
        c0 = 0
        if pairs:
            kind[i] = (1 if morris else 0) if moving else (2 if ghost else 3)
            if moving or ghost:
                c0 = at[i]
                for p in range(indptr[i], indptr[i + 1]):
                    coef[c0 + p] = 0.0
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
                d0, d1, d2, r2 = delta(x, i, j, dim)
                if moving:
                    c = _viscous_pair(m, rho, nu, fluid, i, j, r2, kc, dim, dt, eta2, morris) \
                        * (1.0 if fluid[i] else solid[i])
                    if scalar and r2 >= reach2:  # the operator's pair, not the matrix's
                        if pairs:
                            coef[c0 + p] = c
                        continue
                s = 0
                if write:
                    if dslot < 0 and rj >= ri:
                        dslot, t, last = _slot(out_cols, out_vals, base, span, bw, nd, t, last,
                                               ri)
                    s, t, last = _slot(out_cols, out_vals, base, span, bw, nd, t, last, rj)
                if ghost:
                    wij = w_k(math.sqrt(r2), kc) / wsum
                    if pairs:
                        coef[c0 + p] = wij
                    for a in range(nd if write else 0):
                        out_vals[base + a * span + s] += wij
                    continue
                if pairs:  # a moving row (the ghost rows went on above)
                    coef[c0 + p] = c
                if morris or scalar:
                    cs = c if morris else c * r2 / dim  # the block's trace over dim
                    e00 -= cs
                    for a in range(nd if write else 0):
                        out_vals[base + a * span + s] += cs
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
        if not write:
            diag[q] = e00
            continue
        if dslot < 0:
            dslot, t, last = _slot(out_cols, out_vals, base, span, bw, nd, t, last, ri)
        if bw == dim and nd == dim:
            _add_block(out_vals, base + dslot * dim, span, dim, e00, e01, e02, e11, e12, e22)
        else:  # a diagonal block: (1 - sum c) I (Morris, scalar), or the identity
            for a in range(nd):
                out_vals[base + a * span + dslot] += e00
        k = _close_rows(out_cols, out_vals, out_ptr, base, span, bw, nd, t, ri - first)
    return k, rhs


@njit(cache=True, error_model="numpy")
def viscous_apply(u, out, order, src, kind, coef, at, x, indptr, indices, dim):
    """The operator of :func:`viscous_csr` applied to ``u``, pair by pair: ``out = A u``.

    ``u`` holds the unknowns of the owned rows (row ``q``, shape (n_rows, dim)) followed
    by those of the other points the rows reach (from other ranks); ``src[j]`` is the
    position in ``u`` of local particle ``j`` (-1 if it is in no row). ``order[q]`` is the
    local particle of row ``q``; ``kind``, ``coef`` and ``at`` come from
    :func:`viscous_pairs`. Row ``q`` of particle ``i`` is
    ``u_i - sum_j c r r^T (u_i - u_j)`` (kind 0, eq. (34)),
    ``u_i - sum_j c (u_i - u_j)`` (1, Morris), ``u_i + sum_f w_if u_f`` (2, no-slip
    ghost) or ``u_i`` (3): the assembled block's row without its nine entries per pair.
    """
    for q in range(order.shape[0]):
        i = order[q]
        k = kind[i]
        ui0, ui1, ui2 = _vec(u, q, dim)
        o0, o1, o2 = ui0, ui1, ui2
        if k == 2:
            o0, o1, o2 = _ghost_sum(o0, o1, o2, 1.0, u, src, coef, at[i], indptr, indices, i,
                                    dim)
        elif k != 3:
            c0 = at[i]
            for p in range(indptr[i], indptr[i + 1]):
                c = coef[c0 + p]
                if c == 0.0:
                    continue
                s = src[indices[p]]
                uj0, uj1, uj2 = _vec(u, s, dim)
                if k == 1:
                    o0 -= c * (ui0 - uj0)
                    o1 -= c * (ui1 - uj1)
                    o2 -= c * (ui2 - uj2)
                else:
                    d0, d1, d2, r2 = delta(x, i, indices[p], dim)
                    dr = c * (d0 * (ui0 - uj0) + d1 * (ui1 - uj1) + d2 * (ui2 - uj2))
                    o0 -= d0 * dr
                    o1 -= d1 * dr
                    o2 -= d2 * dr
        _store(out, q, dim, o0, o1, o2)


def operator_callbacks(order, src, kind, coef, at, x, indptr, indices, dim, ghost_points):
    """The arguments of :meth:`solvers.OperatorSystem.set_operator` for the pairs of
    :func:`viscous_pairs`: the operator (:func:`viscous_apply`), the other ranks' points
    it reads, and the ghost rows solved exactly after each AMG application
    (:func:`ghost_rows_exact`)."""
    def apply(u, out):
        viscous_apply(u, out, order, src, kind, coef, at, x, indptr, indices, dim)

    def correct(u, b, out):
        ghost_rows_exact(u, b, out, order, src, kind, coef, at, indptr, indices, dim)

    return apply, ghost_points, correct


@njit(cache=True, error_model="numpy")
def ghost_rows_exact(u, b, out, order, src, kind, coef, at, indptr, indices, dim):
    """The no-slip ghost rows (kind 2) of :func:`viscous_apply` solved exactly for the
    fluid's values in ``u`` (laid out as there): ``out[q] = b[q] - sum_f w_qf u_f``.

    A preconditioner step after BoomerAMG (:class:`solvers.OperatorSystem`'s
    ``correct``). A ghost row is an extrapolation of the fluid (its couplings sum to 1);
    on one rank the forward Gauss-Seidel sweep, walls after the fluid, solves it, but a
    wall whose fluid is partly on another rank gets only a Jacobi update there: the 3D
    tank of ``jobs/bench_memory.py`` took 5 viscous iterations on 2 ranks, 3 on one."""
    for q in range(order.shape[0]):
        i = order[q]
        if kind[i] != 2:
            continue
        b0, b1, b2 = _vec(b, q, dim)
        o0, o1, o2 = _ghost_sum(b0, b1, b2, -1.0, u, src, coef, at[i], indptr, indices, i,
                                dim)
        _store(out, q, dim, o0, o1, o2)


@njit(cache=True, error_model="numpy", inline="always")
def _ghost_sum(o0, o1, o2, sign, u, src, coef, c0, indptr, indices, i, dim):
    """``o + sign sum_f w_if u_f`` over the fluid partners of the ghost row of particle
    ``i`` (``coef[c0 + p]`` its weights, 0 for a pair left out; ``u`` laid out as in
    :func:`viscous_apply`), summed in pair order: the ghost row of the operator
    (``sign`` 1) and its exact solve (-1)."""
    for p in range(indptr[i], indptr[i + 1]):
        c = coef[c0 + p]
        if c == 0.0:
            continue
        c = sign * c
        uj0, uj1, uj2 = _vec(u, src[indices[p]], dim)
        o0 += c * uj0
        o1 += c * uj1
        o2 += c * uj2
    return o0, o1, o2


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def viscous_explicit(x, v, v_ghost, m, rho, nu, fluid, solid, slip, indptr, indices, h, dim,
                     dt, g, morris):
    r"""Explicit viscous predictor of the owned fluid and type-II solid rows: eq. (30) with
    the viscous term (34) (or Morris et al. 1997) evaluated at :math:`\mathbf{v}^\beta`,

    .. math:: \mathbf{v}^*_i = \mathbf{v}_i + \Delta t\,\mathbf{g}
              + \sum_j c_{ij} \mathbf{r}_{ij} \mathbf{r}_{ij}^T (\mathbf{v}_i - \mathbf{v}_j),

    with the coefficients of :func:`viscous_csr` (no-slip walls at their ``v_ghost``,
    free-slip walls left out). It is one step of forward instead of backward Euler on the
    same operator; the two differ by O(zeta^2) for a viscous number
    :math:`\zeta = \nu \Delta t / h^2`, and forward Euler is stable below about 0.1
    (Morris et al. 1997).

    Coupling (eq. (47)), as in :func:`viscous_csr`: a fluid row sees a solid neighbour
    (``solid[j] > 0``) at its own velocity ``v[j]`` (the TLSPH predictor), and a solid row
    (``solid[i] > 0``, ``v[i]`` its predictor, no ``dt g``: the predictor has it) moves by
    the pairs with its fluid neighbours times ``solid[i]`` = (mass the fluid sees) / (true
    mass): the forces between the phases are equal and opposite. Other rows: ``v``.
    Shape (n_owned, dim)."""
    n = indptr.shape[0] - 1
    out = np.empty((n, dim))
    eta2 = ETA2 * h * h
    k = constants(h, dim)
    for i in range(n):
        fi = fluid[i]
        if not fi and solid[i] <= 0.0:
            for a in range(dim):
                out[i, a] = v[i, a]
            continue
        scale = 1.0 if fi else solid[i]
        vi0, vi1, vi2 = _vec(v, i, dim)
        o0, o1, o2 = vi0, vi1, vi2
        if fi:
            o0 += dt * g[0]
            o1 += dt * g[1]
            o2 += dt * g[2] if dim == 3 else 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            fj = fluid[j]
            if not fj and (slip[j] or not fi):  # a solid row: its fluid neighbours only
                continue
            d0, d1, d2, r2 = delta(x, i, j, dim)
            u0, u1, u2 = _vec(v if fj or solid[j] > 0.0 else v_ghost, j, dim)
            e0, e1, e2 = vi0 - u0, vi1 - u1, vi2 - u2
            c = _viscous_pair(m, rho, nu, fluid, i, j, r2, k, dim, dt, eta2, morris) * scale
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
