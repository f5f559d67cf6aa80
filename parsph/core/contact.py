r"""Contact of a particle with the particles of a boundary (walls, or the soil for a fluid).

One kernel for both phases: the TLSPH solid against wall particles (non-penetration and
Coulomb friction, ``solid.wall_friction``), and the IISPH fluid's free-surface particles
against walls and soil (``fluid.surface_wall_contact``; the PPE gives them p = 0 and does
not hold them off a boundary, docs/iisph.md). Imports no phase, so a scene loads only
the stages it needs.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.core.kernel import fac_grad, w

__all__ = ["INSTANT", "NO_MASS", "contact_points_moved", "solid_wall_set", "wall_contact"]

#: :func:`wall_contact`'s ``inv_m, mass, react`` when every partner is fixed (walls)
NO_MASS = (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
#: :func:`wall_contact`'s ``lag, keep, dt, slip_len`` for the instantaneous Coulomb bound
INSTANT = (np.zeros(0), 0.0, 1.0, math.inf)


@njit(cache=True, error_model="numpy")
def wall_contact(x, v, rows, vrows, wall, vw, indptr, indices, h, d, dim, mu, push, mu_w,
                 r2max, inv_m, mass, react, lag, keep, dt, slip_len):
    r"""Non-penetration and Coulomb friction against boundary particles, in place on ``v``.

    For each ``k``, the particle at ``x[rows[k]]`` (velocity ``v[vrows[k]]``) against its
    neighbours ``j`` in CSR row ``rows[k]`` with ``wall[j] = 1`` within the kernel's
    support (squared distance below ``r2max``, so that lists built wider, Verlet lists,
    are exact; ``math.inf`` takes every listed neighbour), which move with ``vw[j]``
    (zero for fixed walls):

    - outward normal :math:`\mathbf n = -\sum_w \nabla W(\mathbf x_k - \mathbf x_w)`
      normalised (points from the boundary into the body);
    - gap :math:`\delta = \min_w (\mathbf x_k - \mathbf x_w)\cdot\mathbf n`; a particle
      is in contact when :math:`\delta < d` (one particle spacing: a body resting on a
      wall has :math:`\delta = d`);
    - velocity relative to the boundary :math:`\mathbf v_k - \bar{\mathbf v}_w`
      (:math:`\bar{\mathbf v}_w` the kernel-weighted mean of the partners'); in contact
      and approaching (:math:`v_n < 0`) its normal part is removed,
      :math:`\Delta v_n = -v_n`, and its tangential part is reduced by at most
      :math:`\mu_k (\Delta v_n + \max(\mathbf p_k\cdot\mathbf n, 0))` (Coulomb: the
      friction impulse is bounded by mu times the normal impulse; sticking when it would
      reverse the slip); :math:`\mu_k` is the kernel-weighted mean of the partners'
      ``mu_w[j]`` (each wall's own coefficient, ``walls.N.friction``: a rough floor
      beside smooth side walls), or ``mu[k]`` where ``mu_w`` is negative (the caller
      sets one or the other for all partners). ``push[k]`` is a velocity change of this
      step by which the boundary already holds the particle (the fluid's pressure
      impulse; zero for the solid).

    A boundary of finite mass (``inv_m``: its partners' inverse masses per axis, rows of
    ``x``; empty: every partner fixed) takes its share of each impulse: the particle
    (mass ``mass[vrows[k]]``) changes its relative velocity by the fraction
    :math:`s = 1 / (1 + m_k \sum_j f_j^2 / m_j)` only, :math:`f_j` the partners' kernel
    weights over their sum, and the opposite impulse goes to the partners in proportion
    to :math:`f_j`, added to ``react`` (momentum, rows of ``x``) for the caller to apply.
    That is the plastic impulse of two bodies, reduced mass :math:`m_r = 1/(1/m_k +
    1/M_b)`: momentum is kept and the kinetic energy falls by :math:`m_r v_n^2/2`. Against a
    fixed boundary :math:`s = 1`, the full impulse, as before: a fluid particle struck by
    a moving solid had taken the solid's velocity without slowing it, adding up to 1.4
    J to a step in which gravity could supply 1.2 (docs/iisph.md).

    **Lagged Coulomb bound** (``lag`` not empty: the solid, ``solid.friction_time``;
    docs/loading.md). The bound of a step is then :math:`\mu_k \bar a_k \Delta t`, where
    :math:`\bar a_k` (``lag[vrows[k]]``, m/s², updated in place) follows the particle's
    normal contact acceleration :math:`a_k = (\Delta v_n + \max(\mathbf p_k\cdot\mathbf
    n, 0)) / \Delta t` (zero out of contact) at the rate :math:`1/t^* + V_k/L`, :math:`V_k`
    the particle's slip speed on the wall before this step's friction:
    :math:`\bar a_k \leftarrow \kappa \bar a_k + (1 - \kappa) a_k`,
    :math:`\kappa = \kappa_0 e^{-V_k \Delta t / L}`, ``keep`` :math:`\kappa_0 =
    e^{-\Delta t / t^*}`, ``slip_len`` :math:`L` (``inf``: the time alone), ``dt``
    :math:`\Delta t`. It acts on every particle in contact (:math:`\delta < d`),
    approaching or not. That is the simplified law of Prakash & Clifton (1993) in the
    form of Cochard & Rice (2000) and Ranjith & Rice (2001),
    :math:`\dot{\bar\sigma} = -(|V| + V^*)/L\,(\bar\sigma - \sigma)` with
    :math:`V^* = L/t^*`, by which the frictional strength follows a change of the normal
    stress over a slip :math:`L` (or a time :math:`t^*` near rest) instead of at once:
    with the instantaneous bound, a stiff elastic block shaken on a rough floor (mu = 0.35)
    chattered at the particle scale, each particle in contact only in some steps, and
    slipped 1.5, 3.5 and 13 % more than the rigid block at d = 0.02, 0.01, 0.005 m: the
    friction-induced flutter of an elastic body on a Coulomb surface (Martins et al. 1995;
    Simões & Martins 1998), whose growth rate rises as the wavelength falls, so that the
    result does not converge as d shrinks. The lag keeps the time integral of the bound
    (:math:`\sum_n \bar a_n = \sum_n a_n`) while a particle stays in contact. The slip
    term keeps a sliding particle's bound within :math:`L/V` of its normal force: with
    the time alone the bound of debris sliding at metres per second lagged over
    :math:`V t^*`, 1-3 cm, about a particle spacing at the slope's sizes, and the slope's
    run-out at one d moved by up to 7 % with :math:`t^*` (docs/loading.md).

    Returns the number of particles in contact.
    """
    shared = inv_m.shape[0] > 0
    lagged = lag.shape[0] > 0
    count = 0
    nv = np.zeros(3)
    vb = np.zeros(3)
    vr = np.zeros(3)
    dv = np.zeros(3)
    tv = np.zeros(3)
    for k in range(rows.shape[0]):
        r = rows[k]
        i = vrows[k]
        nv[:] = 0.0
        vb[:] = 0.0
        wsum = 0.0
        musum = 0.0
        for q in range(indptr[r], indptr[r + 1]):
            j = indices[q]
            if not wall[j]:
                continue
            r2 = _dist2(x, r, j, dim)
            if r2 >= r2max:
                continue
            dist = math.sqrt(r2)
            f = -fac_grad(dist, h, dim)
            wt = w(dist, h, dim)
            wsum += wt
            musum += wt * mu_w[j]
            for a in range(dim):
                nv[a] += f * (x[r, a] - x[j, a])
                vb[a] += wt * vw[j, a]
        norm = 0.0
        for a in range(dim):
            norm += nv[a] * nv[a]
        norm = math.sqrt(norm)
        if wsum == 0.0 or norm == 0.0:
            if lagged:  # out of contact: the bound relaxes towards zero
                lag[i] *= keep
            continue
        for a in range(dim):
            nv[a] /= norm
            vb[a] /= wsum
        gap = 1e300
        for q in range(indptr[r], indptr[r + 1]):
            j = indices[q]
            if not wall[j]:
                continue
            if _dist2(x, r, j, dim) < r2max:
                g = 0.0
                for a in range(dim):
                    g += (x[r, a] - x[j, a]) * nv[a]
                gap = min(gap, g)
        if gap >= d * (1.0 + 1e-6):
            if lagged:
                lag[i] *= keep
            continue
        vn = 0.0
        pn = 0.0
        for a in range(dim):
            vr[a] = v[i, a] - vb[a]
            vn += vr[a] * nv[a]
            pn += push[k, a] * nv[a]
        if vn >= 0.0 and pn <= 0.0 and not (lagged and lag[i] > 0.0):
            if lagged:
                lag[i] = 0.0  # (kept at zero: resting without pressing)
            continue
        count += 1
        for a in range(dim):
            dv[a] = v[i, a]
        dvn = max(pn, 0.0)
        if vn < 0.0:
            sn = _share(x, r, mass[i], wall, indptr, indices, h, dim, r2max, inv_m, nv,
                        wsum) if shared else 1.0
            dvn -= vn * sn
            for a in range(dim):
                v[i, a] -= vn * sn * nv[a]
                vr[a] -= vn * nv[a]
            vn = 0.0
        vt2 = 0.0
        for a in range(dim):
            vt2 += (vr[a] - vn * nv[a]) ** 2
        vt = math.sqrt(vt2)
        muk = musum / wsum if musum >= 0.0 else mu[k]
        if lagged:  # the bound follows the normal impulse over t*, faster as it slips
            kk = keep * math.exp(-vt * dt / slip_len)
            lag[i] = kk * lag[i] + (1.0 - kk) * dvn / dt
            dvn = lag[i] * dt
        if vt > 0.0 and muk > 0.0:
            st = 1.0
            if shared:
                for a in range(dim):
                    tv[a] = (vr[a] - vn * nv[a]) / vt
                st = _share(x, r, mass[i], wall, indptr, indices, h, dim, r2max, inv_m, tv,
                            wsum)
            fac = max(0.0, 1.0 - muk * dvn / (vt * st))
            for a in range(dim):  # the tangential part only
                v[i, a] -= (1.0 - fac) * st * (vr[a] - vn * nv[a])
        if shared:  # the opposite impulse to the partners, by weight
            for a in range(dim):
                dv[a] = mass[i] * (v[i, a] - dv[a]) / wsum
            for q in range(indptr[r], indptr[r + 1]):
                j = indices[q]
                wt = _partner_weight(x, r, j, wall, h, dim, r2max)
                if wt > 0.0:
                    for a in range(dim):
                        react[j, a] -= wt * dv[a]
    return count


@njit(cache=True, error_model="numpy", inline="always")
def _share(x, r, m, wall, indptr, indices, h, dim, r2max, inv_m, e, wsum):
    """:func:`wall_contact`'s fraction of an impulse along ``e`` that the particle at
    ``x[r]`` (mass ``m``) takes: ``1 / (1 + m sum_j f_j^2 e.diag(inv_m[j]).e)``."""
    q2 = 0.0
    for q in range(indptr[r], indptr[r + 1]):
        j = indices[q]
        f = _partner_weight(x, r, j, wall, h, dim, r2max) / wsum
        if f == 0.0:
            continue
        ee = 0.0
        for a in range(dim):
            ee += e[a] * e[a] * inv_m[j, a]
        q2 += f * f * ee
    return 1.0 / (1.0 + m * q2)


@njit(cache=True, error_model="numpy", inline="always")
def _dist2(x, r, j, dim):
    """Squared distance of the points ``x[r]`` and ``x[j]``, summed over the axes in order
    (the test of the neighbour searches)."""
    r2 = 0.0
    for a in range(dim):
        r2 += (x[r, a] - x[j, a]) ** 2
    return r2


@njit(cache=True, error_model="numpy", inline="always")
def _partner_weight(x, r, j, wall, h, dim, r2max):
    """Kernel weight of ``j`` as :func:`wall_contact`'s partner of ``x[r]``: ``W`` for a
    boundary row within reach, else 0."""
    if not wall[j]:
        return 0.0
    r2 = _dist2(x, r, j, dim)
    return w(math.sqrt(r2), h, dim) if r2 < r2max else 0.0


@njit(cache=True, error_model="numpy")
def solid_wall_set(x, rows, indptr, indices, xw, mu_solid, mu_wall):
    """The point set :func:`wall_contact` takes for the solids ``rows`` (rows of ``x``)
    and the walls ``xw`` near them, from their cross lists (``indptr``, ``indices`` into
    ``xw``, :func:`parsph.core.cross.build_cross_csr`), in one pass where numpy's took 60
    of a 2D coupled step's 1.2 ms of fixed cost.

    Only the solids with a wall in reach are kept. Returns ``(kept, indptr, indices,
    xall, wall, mu, mu_w)``: the kept rows, their lists into ``xall`` (the kept solids,
    then the walls), the wall flag and the friction coefficients of ``xall``'s points
    (``mu_solid`` for each kept solid, ``mu_wall`` per wall).
    """
    nq, nw, dim = rows.shape[0], xw.shape[0], x.shape[1]
    nr = 0
    for i in range(nq):
        nr += indptr[i + 1] > indptr[i]
    kept = np.empty(nr, dtype=np.int64)
    ptr = np.zeros(nr + 1, dtype=np.int64)
    xall = np.empty((nr + nw, dim))
    k = 0
    for i in range(nq):
        if indptr[i + 1] > indptr[i]:
            kept[k] = rows[i]
            ptr[k + 1] = ptr[k] + indptr[i + 1] - indptr[i]
            xall[k] = x[rows[i]]
            k += 1
    xall[nr:] = xw
    shifted = indices + np.int32(nr)  # a solid without walls had no entries
    wall = np.zeros(nr + nw, dtype=np.uint8)
    wall[nr:] = 1
    mu_w = np.zeros(nr + nw)
    mu_w[nr:] = mu_wall
    return kept, ptr, shifted, xall, wall, np.full(nr, mu_solid), mu_w



@njit(cache=True, error_model="numpy")
def contact_points_moved(x, sel, n, rows, x0, skin2, kept, xall):
    """Whether the wall-contact lists of the solids are stale: the selected rows among
    the first ``n`` (``sel``) are not ``rows`` any more, or one of them has moved by
    ``sqrt(skin2)`` or more from ``x0`` (its position when the lists were built). If not,
    the kept solids' present positions are written to the front of ``xall`` (the point
    set of :func:`solid_wall_set`), ready for :func:`wall_contact`.

    A list of the walls within ``radius + skin`` of where a solid was holds every wall
    within ``radius`` of where it is while it has moved less than the skin (the walls
    are fixed), whichever particle the row now is."""
    c = 0
    m = rows.shape[0]
    for i in range(n):
        if not sel[i]:
            continue
        if c >= m or rows[c] != i:
            return True
        r2 = 0.0
        for a in range(x.shape[1]):
            r2 += (x[i, a] - x0[c, a]) ** 2
        if r2 >= skin2:
            return True
        c += 1
    if c != m:
        return True
    for k in range(kept.shape[0]):
        xall[k] = x[kept[k]]
    return False
