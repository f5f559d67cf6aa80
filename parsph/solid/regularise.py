r"""The internal length of a softening soil: an over-non-local plastic strain (docs/regularisation.md).

The paper's softening (Appendix A: :math:`c = c_0 + H\bar\epsilon^p`) and its phase-change
trigger (section 3.3: :math:`\bar\epsilon^p > \epsilon_p^{limit}`) are local: a shear band
is a few particles wide at any d, so its plastic strain, the slip at which it fluidises
and the fluidised volume follow the particle size. Here both see a length ℓ.

**The non-local plastic strain** :math:`\tilde\kappa` solves, over the soil's reference
configuration :math:`\Omega_0` (the implicit-gradient form of Peerlings et al. 1996),

.. math::
    \tilde\kappa - \ell^2\nabla_0^2\tilde\kappa = \kappa \ \text{in}\ \Omega_0, \qquad
    \nabla_0\tilde\kappa\cdot\mathbf N = 0 \ \text{on}\ \partial\Omega_0 ,

with :math:`\kappa = \bar\epsilon^p` the accumulated plastic strain. It is a weighted
average of κ whose weight (the equation's Green's function) decays over ℓ and
integrates to one, so a uniform κ is its own average. Discretised on the TLSPH
neighbour lists with the pairwise Laplacian of Brookshaw (1985), multiplied by
:math:`V_i` so the matrix is symmetric:

.. math::
    V_i\tilde\kappa_i + \sum_j 2\ell^2 V_i V_j |F_{ij}| (\tilde\kappa_i - \tilde\kappa_j)
    = V_i\kappa_i ,

:math:`F_{ij} = W'(R_{ij})/R_{ij}` in the reference configuration
(:func:`parsph.solid.kernels.pair_factors`). The pair sum is antisymmetric, so
:math:`\sum_i V_i\tilde\kappa_i = \sum_i V_i\kappa_i` exactly: no flux leaves the soil (the
natural boundary condition, also where particles left it by a phase change). A global
solve on PETSc (:class:`solvers.LinearSystem`, prefix ``nonlocal_``, CG + Jacobi by
default); the matrix depends on the reference configuration only, so it is built when
the solid's rows change (set-up, phase change) and each step only solves, from the
last step's :math:`\tilde\kappa`.

**Over-non-local softening** (Vermeer & Brinkgreve 1994; Galavi & Schweiger 2010;
Jirásek & Rolshoven 2003): the cohesion softens with

.. math::
    \hat\kappa = (1-m)\kappa + m\tilde\kappa , \qquad m > 1 ,

written in the return map as :math:`\hat\kappa^{\beta+1} = \kappa^{\beta+1} +
m(\tilde\kappa^\beta - \kappa^\beta)`: the local part is implicit in the return, the
non-local correction taken from the last step (explicit dynamics: steps of a fraction of
an elastic wave's transit of one particle). In a uniform field :math:`\tilde\kappa =
\kappa` and the model is the paper's. :math:`m = 1` (the softening sees only the
average) does not keep a band from narrowing to the particle size in softening
plasticity; m = 2 does (docs/regularisation.md).

**The trigger** of the phase change is :math:`\tilde\kappa > \epsilon_p^{limit}`.

Modified Cam-Clay's softening (its pre-consolidation pressure on the dry side) stays
local: the average reaches it only through the trigger (docs/regularisation.md).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from decomposition.numbering import global_offset
from decomposition.reduce import global_any, global_max
from parsph.core.tensor import eigh3, inv3_into

@njit(cache=True, error_model="numpy")
def helmholtz_block(reg, vol, ell2, n, indptr, indices, fp, gid):
    r"""CSR block of the owned regularised rows of :math:`V(I - \ell^2\nabla_0^2)`.

    Parameters
    ----------
    reg : ndarray (N,) of bool
        Rows of the average (solid rows of a regularised material), owned and halo.
    vol : ndarray (N,)
        Reference volumes V (m^dim).
    ell2 : ndarray (N,)
        ℓ² of each row (m²); a pair takes the mean of its two ends (a symmetric matrix).
    n : int
        Owned rows.
    indptr, indices : CSR neighbour lists in the reference configuration.
    fp : ndarray of float32
        Pair factors :math:`F_{ij} = W'(R)/R` of the lists (≤ 0; 0 for pairs out of the
        solid).
    gid : ndarray (N,) of int64
        Global row of each regularised row (owned and halo), -1 elsewhere.

    Returns
    -------
    ptr, cols, vals : ndarray
        Rows of the owned regularised rows in their order, columns (global, sorted and
        distinct: a periodic image is summed into its particle; a particle's own image
        drops out of the pair sum), values.
    """
    rows = 0
    nnz = 0
    for i in range(n):
        if reg[i]:
            rows += 1
            nnz += indptr[i + 1] - indptr[i] + 1
    ptr = np.zeros(rows + 1, dtype=np.int64)
    cols = np.empty(nnz, dtype=np.int64)
    vals = np.empty(nnz, dtype=np.float64)
    k = 0
    at = 0
    for i in range(n):
        if not reg[i]:
            continue
        start = at
        diag = vol[i]
        gi = gid[i]
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if not reg[j] or gid[j] == gi:
                continue
            c = (ell2[i] + ell2[j]) * vol[i] * vol[j] * abs(np.float64(fp[p]))
            if c == 0.0:
                continue
            diag += c
            cols[at] = gid[j]
            vals[at] = -c
            at += 1
        cols[at] = gi
        vals[at] = diag
        at += 1
        # sort the row's columns and sum duplicates (periodic images of one particle)
        order = np.argsort(cols[start:at], kind="mergesort")
        c_sorted = cols[start:at][order].copy()
        v_sorted = vals[start:at][order].copy()
        w = start
        for q in range(len(order)):
            if q > 0 and c_sorted[q] == cols[w - 1]:
                vals[w - 1] += v_sorted[q]
            else:
                cols[w] = c_sorted[q]
                vals[w] = v_sorted[q]
                w += 1
        at = w
        k += 1
        ptr[k] = at
    return ptr, cols[:at].copy(), vals[:at].copy()


@njit(cache=True, error_model="numpy")
def drift_since_solve(reg, n, value, average, shift):
    """Largest change of ``value`` on the owned regularised rows since the last solve,
    ``|value - (average - shift)|`` (the value then was ``average - shift``)."""
    out = 0.0
    for i in range(n):
        if reg[i]:
            out = max(out, abs(value[i] - average[i] + shift[i]))
    return out


#: The non-local strain is solved again once some particle's plastic strain has changed
#: by this much since the last solve (and after every change of the solid's rows): its
#: lag then moves the cohesion by at most m |H| 1e-5 and the trigger by 1e-5.
SOLVE_TOLERANCE = 1.0e-5


class NonlocalStrain:
    r"""The non-local plastic strain :math:`\tilde\kappa` of the regularised solid rows
    (module docstring): one PETSc system, rebuilt with the solid's rows, solved again
    once the plastic strain has moved by :data:`SOLVE_TOLERANCE`.

    Fields (``ctx.particles``; solid state, checkpointed and migrated with the rest):
    ``eps_p_nl`` :math:`\tilde\kappa` (the trigger of the phase change) and
    ``eps_p_shift`` :math:`\tilde\kappa - \kappa` at the last solve (the over-non-local
    correction of the softening).

    Parameters
    ----------
    comm : mpi4py communicator
    averaged, ell_of : sequence (n_materials,)
        Whether each material takes part in the average, and its ℓ (m).
    particles : ParticleSet
        Where the fields are added.
    """

    #: The per-particle state it adds (solid state: checkpointed, migrated, written back).
    FIELDS = ("eps_p_nl", "eps_p_shift")

    def __init__(self, comm, averaged, ell_of, particles):
        self.comm = comm
        self.averaged = np.asarray(averaged, dtype=bool)
        self.ell2_of = np.asarray(ell_of, dtype=float) ** 2
        self.system = None
        self.reg = None
        self.n_rows = 0
        self.total = 0
        self.iterations = 0
        self.solves = 0
        self.wall_s = 0.0
        for name in self.FIELDS:
            particles.add_field(name)

    def rows(self, material, sel) -> np.ndarray:
        """Rows of the average: solid rows of a regularised material."""
        return sel & self.averaged[np.maximum(material, 0)] & (material >= 0)

    def build(self, ctx, vol, sel, fp) -> None:
        """Collective: number the owned regularised rows, send their numbers to the halo,
        assemble the matrix (:func:`helmholtz_block`)."""
        import solvers

        p, n = ctx.particles, ctx.particles.n_owned
        material = p["material"]
        reg = self.rows(material, sel)
        self.reg = reg
        self.n_rows = int(reg[:n].sum())
        offset, total = global_offset(ctx.comm, self.n_rows)
        self.total = total
        if total == 0:  # every regularised row has left the solid
            self.destroy()
            return
        gid = p.add_field("nl_row", (), np.int64, fill=-1)
        gid[:] = -1
        gid[:n][reg[:n]] = offset + np.arange(self.n_rows)
        ctx.update_halo(["nl_row"])
        ell2 = self.ell2_of[np.maximum(material, 0)]
        ptr, cols, vals = helmholtz_block(reg, vol, ell2, n, ctx.indptr, ctx.indices, fp, gid)
        if self.system is None:
            # CG with incomplete Cholesky on each rank's block: of Jacobi, BoomerAMG,
            # GAMG and ICC the fastest here (docs/regularisation.md)
            self.system = solvers.LinearSystem(
                ctx.comm, "nonlocal_", self.n_rows, ksp_type="cg", pc_type="bjacobi",
                rtol=1e-9, max_it=10000, options={"sub_pc_type": "icc"})
        else:
            self.system.resize(self.n_rows)
        self.system.assemble_csr(ptr, cols, vals)

    def due(self, ctx) -> bool:
        """Collective: whether some owned regularised row's plastic strain moved by
        :data:`SOLVE_TOLERANCE` since the last solve (never without rows)."""
        p, n = ctx.particles, ctx.particles.n_owned
        if self.system is None:
            return False
        change = drift_since_solve(self.reg, n, p["eps_p"], p["eps_p_nl"], p["eps_p_shift"])
        return global_max(ctx.comm, change) > SOLVE_TOLERANCE

    def solve(self, ctx, vol) -> None:
        r"""Collective: :math:`\tilde\kappa = (I - \ell^2\nabla^2)^{-1}\kappa` on the owned
        regularised rows (from their last values) and the shifts; the other owned rows
        get their own plastic strain and no shift."""
        import time

        p, n = ctx.particles, ctx.particles.n_owned
        if self.system is None:
            return
        reg = self.reg[:n]
        t0 = time.perf_counter()
        kappa = p["eps_p"][:n]
        rhs = np.ascontiguousarray(vol[:n][reg] * kappa[reg])
        x, info = self.system.solve(rhs, x0=np.ascontiguousarray(p["eps_p_nl"][:n][reg]))
        its = info["iterations"]
        p["eps_p_nl"][:n][reg] = x
        p["eps_p_nl"][:n][~reg] = kappa[~reg]
        p["eps_p_shift"][:n][reg] = x - kappa[reg]
        p["eps_p_shift"][:n][~reg] = 0.0
        self.iterations = its
        self.solves += 1
        self.wall_s += time.perf_counter() - t0

    def destroy(self) -> None:
        if self.system is not None:
            self.system.destroy()
            self.system = None


#: The window's targets are binned in cells of side R / WINDOW_CELLS_PER_R in the
#: reference configuration (:func:`bin_window`): a row's window visits the
#: (2 WINDOW_CELLS_PER_R + 1)^3 cells around its own.
WINDOW_CELLS_PER_R = 2


def bin_window(X, sel, R, dim):
    """The window's targets (the rows of ``X`` where ``sel``) sorted by cell, for
    :func:`window_strain`: ``(order, start, lo, cell, ncell, reach)``, the rows in cell
    order, each cell's first position in it (dense over the targets' box, plus one), the
    box's low corner, the cell side, the cells per axis (3; 1 beyond ``dim``) and the
    cells a window reaches on each side. Cells of R / 2, or of R where that grid would
    hold more than eight cells per target (a sparse box)."""
    rows = np.flatnonzero(sel)
    Xp = np.zeros((len(X), 3))
    Xp[:, :dim] = X[:, :dim]
    lo = Xp[rows].min(axis=0) if len(rows) else np.zeros(3)
    extent = (Xp[rows].max(axis=0) - lo) if len(rows) else np.zeros(3)
    for per in (WINDOW_CELLS_PER_R, 1):
        cell = R / per
        ncell = np.floor(extent / cell).astype(np.int64) + 1
        if int(np.prod(ncell)) <= 8 * len(rows) + 1024:
            break
    idx = np.minimum(np.floor((Xp[rows] - lo) / cell).astype(np.int64), ncell - 1)
    lin = (idx[:, 0] * ncell[1] + idx[:, 1]) * ncell[2] + idx[:, 2]
    o = np.argsort(lin, kind="stable")
    start = np.searchsorted(lin[o], np.arange(int(np.prod(ncell)) + 1)).astype(np.int64)
    return rows[o].astype(np.int64), start, lo, float(cell), ncell, per


@njit(cache=True, error_model="numpy")
def window_strain(rows, X, x, order, start, lo, cell, ncell, per, Xs, xs, R, dim, out,
                  gain):
    r"""Shear strain of the deformation over a window of radius R in the reference
    configuration, for each row of ``rows``: the deformation gradient fitted by weighted
    least squares, :math:`\mathbf F = \mathbf B\mathbf M^{-1}`,
    :math:`\mathbf M = \sum_j w_j \mathbf X_{ij}\otimes\mathbf X_{ij}`,
    :math:`\mathbf B = \sum_j w_j \mathbf x_{ij}\otimes\mathbf X_{ij}` over the targets j
    within R (:func:`bin_window`'s cells ``order``, ``start``, ...: the rows of the
    window's solid; ``Xs``, ``xs`` their positions in that order; :math:`w = (1 -
    r^2/R^2)^2`), then its logarithmic strain's shear measure
    :math:`\sqrt{2\,\mathrm{dev}\,\mathbf e : \mathrm{dev}\,\mathbf e}` (the engineering
    shear in simple shear). The window spans gaps the fluidised soil left, so it sees the
    slip across them. ``gain`` gets :math:`\sum_j w_j |\mathbf X_{ij}| / \lambda_{min}
    (\mathbf M)` (1/m): :math:`|\dot{\mathbf F}| \le 2 v_{max}` times it. The targets are
    visited cell by cell, without neighbour lists (the window's lists had cost twice its
    fit: 65 against 33 ns a pair on the aso scene at d = 8 m)."""
    M = np.zeros((3, 3))
    B = np.zeros((3, 3))
    Minv = np.zeros((3, 3))
    F = np.zeros((3, 3))
    C = np.zeros((3, 3))
    R2 = R * R
    ci = np.zeros(3, dtype=np.int64)
    c0 = np.zeros(3, dtype=np.int64)
    c1 = np.zeros(3, dtype=np.int64)
    for k in range(len(rows)):
        i = rows[k]
        for a in range(3):
            ci[a] = 0
            if a < dim:
                ci[a] = min(max(int(math.floor((X[i, a] - lo[a]) / cell)), 0), ncell[a] - 1)
            c0[a] = max(ci[a] - per, 0)
            c1[a] = min(ci[a] + per, ncell[a] - 1)
        cnt = 0
        reach = 0.0
        # M (symmetric) and B in scalars: the 3 x 3 arrays' loads and stores had cost
        # three times the arithmetic
        m00 = m01 = m02 = m11 = m12 = m22 = 0.0
        b00 = b01 = b02 = b10 = b11 = b12 = b20 = b21 = b22 = 0.0
        Xi0, Xi1, xi0, xi1 = X[i, 0], X[i, 1], x[i, 0], x[i, 1]
        Xi2 = X[i, 2] if dim == 3 else 0.0
        xi2 = x[i, 2] if dim == 3 else 0.0
        for cx in range(c0[0], c1[0] + 1):
            for cy in range(c0[1], c1[1] + 1):
                for cz in range(c0[2], c1[2] + 1):
                    c = (cx * ncell[1] + cy) * ncell[2] + cz
                    for q in range(start[c], start[c + 1]):
                        d0 = Xs[q, 0] - Xi0
                        d1 = Xs[q, 1] - Xi1
                        d2 = Xs[q, 2] - Xi2 if dim == 3 else 0.0
                        r2 = d0 * d0 + d1 * d1 + d2 * d2
                        if r2 >= R2 or order[q] == i:
                            continue
                        w = (1.0 - r2 / R2) ** 2
                        cnt += 1
                        reach += w * math.sqrt(r2)
                        u0 = w * (xs[q, 0] - xi0)
                        u1 = w * (xs[q, 1] - xi1)
                        u2 = w * (xs[q, 2] - xi2) if dim == 3 else 0.0
                        w0, w1, w2 = w * d0, w * d1, w * d2
                        m00 += w0 * d0
                        m01 += w0 * d1
                        m02 += w0 * d2
                        m11 += w1 * d1
                        m12 += w1 * d2
                        m22 += w2 * d2
                        b00 += u0 * d0
                        b01 += u0 * d1
                        b02 += u0 * d2
                        b10 += u1 * d0
                        b11 += u1 * d1
                        b12 += u1 * d2
                        b20 += u2 * d0
                        b21 += u2 * d1
                        b22 += u2 * d2
        M[0, 0], M[0, 1], M[0, 2] = m00, m01, m02
        M[1, 0], M[1, 1], M[1, 2] = m01, m11, m12
        M[2, 0], M[2, 1], M[2, 2] = m02, m12, m22
        B[0, 0], B[0, 1], B[0, 2] = b00, b01, b02
        B[1, 0], B[1, 1], B[1, 2] = b10, b11, b12
        B[2, 0], B[2, 1], B[2, 2] = b20, b21, b22
        if cnt < 2 * dim:
            out[k] = 0.0
            gain[k] = math.inf
            continue
        if dim == 2:
            half = 0.5 * (M[0, 0] - M[1, 1])
            low = 0.5 * (M[0, 0] + M[1, 1]) - math.sqrt(half * half + M[0, 1] * M[0, 1])
            M[2, 2] = 1.0
            B[2, 2] = 1.0
        else:
            lam, _ = eigh3(M)
            low = lam[0]
        gain[k] = reach / low if low > 0.0 else math.inf
        inv3_into(M, Minv)
        for a in range(3):
            for b in range(3):
                s = 0.0
                for c in range(3):
                    s += B[a, c] * Minv[c, b]
                F[a, b] = s
        for a in range(3):
            for b in range(3):
                s = 0.0
                for c in range(3):
                    s += F[c, a] * F[c, b]
                C[a, b] = s
        lam, _ = eigh3(C)
        e0 = 0.5 * math.log(max(lam[0], 1e-300))
        e1 = 0.5 * math.log(max(lam[1], 1e-300))
        e2 = 0.5 * math.log(max(lam[2], 1e-300))
        mean = (e0 + e1 + e2) / 3.0
        out[k] = math.sqrt(2.0 * ((e0 - mean) ** 2 + (e1 - mean) ** 2 + (e2 - mean) ** 2))


from parsph.scene.materials import WINDOW_IN_ELL  # noqa: E402 (the window's radius in l)


class WindowTrigger:
    r"""The phase change's trigger strain over a window of the reference configuration
    (docs/regularisation.md): for each solid row that has yielded, the shear strain of
    the deformation gradient fitted over the solid within R = :data:`WINDOW_IN_ELL` ℓ of
    its reference position (:func:`window_strain`), in the units of its material's
    accumulated plastic strain (``factor``: ξ for Drucker–Prager, whose ε̄ᵖ grows by ξ
    per unit of plastic shear; 1/√3 for modified Cam–Clay's von Mises measure).

    The window reaches over the gaps the fluidised soil leaves, so a particle next to a
    fluidised band sees the slip across it: the zone that fluidises around a slip surface
    is set by R, not by the particle size.

    A row's window is evaluated again only when it could have reached the limit: its
    strain grows at most as fast as ``4 factor gain v_max`` (:func:`window_strain`: the
    fit's gain, v_max the solid's largest speed, a factor 2 for the logarithm), so a row
    at ``value`` evaluated at ``t_e`` cannot pass ``limit`` before
    ``t_e + (limit - value) / rate``. The trigger then fires at the step it would with an
    evaluation every step, and the window's positions cross the ranks only on a step
    where some rank has a row due. Per-row state (solid fields, so views, migration and
    checkpoints carry it): ``eps_trigger`` (the value at the row's last evaluation),
    ``trigger_time``, ``trigger_rate``.

    Parameters
    ----------
    comm : mpi4py communicator
    radius_of, factor_of : ndarray (n_materials,)
        R (m) and the strain factor per material (R = 0: the material's rows keep the
        local trigger, their accumulated plastic strain). The window takes the largest R.
    """

    #: A row is a candidate once its accumulated plastic strain passes this fraction of
    #: the limit: elastic soil does not change phase.
    CANDIDATE = 2e-3
    #: Per-row state it adds to the solid (view and main set).
    FIELDS = ("eps_trigger", "trigger_time", "trigger_rate")

    def __init__(self, comm, radius_of, factor_of):
        self.comm = comm
        self.radius_of = np.asarray(radius_of, float)
        self.factor_of = np.asarray(factor_of, float)
        self.R = float(self.radius_of.max()) if len(self.radius_of) else 0.0
        self.halo = None

    def build(self, vctx, sel) -> None:
        """Collective: the window's halo (the solid rows within R of this rank's, in X) and
        their fixed fields; after every change of the solid's rows."""
        from decomposition.halo import Halo

        p, n = vctx.particles, vctx.particles.n_owned
        self.halo = Halo.build(vctx.comm, vctx.rcb, p["X"][:n], self.R, vctx.box)
        # the deformation counts from the settled state after a geostatic stage
        # (parsph.solid.geostatic), else from the reference configuration
        ref = p["x_settled"] if "x_settled" in p else p["X"]
        fixed = self.halo.exchange({"X": ref[:n], "sel": sel[:n].astype(np.uint8)},
                                   shift_fields=("X",))
        self.X = np.ascontiguousarray(np.concatenate([ref[:n], fixed["X"]]))
        self.sel = np.concatenate([sel[:n], fixed["sel"].astype(bool)])
        self.cells = bin_window(self.X, self.sel, self.R, vctx.dim)
        self.Xs = np.ascontiguousarray(self.X[self.cells[0]])  # in cell order

    def strain(self, vctx, limit, t, vmax, out) -> None:
        """Collective: the trigger strain of the owned solid rows into ``out`` (n_owned):
        the window strain of the candidates (:data:`CANDIDATE`) at their last evaluation,
        their own accumulated plastic strain where R = 0, else 0. ``t`` the time (s),
        ``vmax`` the solid's largest speed (m/s, all ranks)."""
        p, n = vctx.particles, vctx.particles.n_owned
        material = np.maximum(p["material"][:n], 0)
        R_row = self.radius_of[material]
        eps = p["eps_p"][:n]
        if "eps_p_geostatic" in p:  # the geostatic stage's does not count
            eps = eps - p["eps_p_geostatic"][:n]
        value, t_e, rate = (p[k][:n] for k in self.FIELDS)
        cand = self.sel[:n] & (R_row > 0.0) & (eps > self.CANDIDATE * limit)
        rate_now = rate * vmax
        due = cand & ((rate_now == 0.0) | (value + rate_now * (t - t_e) >= limit))
        rows = np.flatnonzero(due)
        if global_any(vctx.comm, len(rows) > 0):  # the window's positions: collective
            moved = self.halo.exchange({"x": p["x"][:n]}, shift_fields=("x",))["x"]
        if len(rows):
            x = np.ascontiguousarray(np.concatenate([p["x"][:n], moved]))
            val = np.zeros(len(rows))
            gain = np.zeros(len(rows))
            window_strain(rows, self.X, x, *self.cells, self.Xs,
                          np.ascontiguousarray(x[self.cells[0]]), self.R, vctx.dim, val, gain)
            f = self.factor_of[material[rows]]
            value[rows] = f * val
            t_e[rows] = t
            rate[rows] = 4.0 * f * gain
        out[:] = np.where(self.sel[:n] & (R_row <= 0.0), eps, np.where(cand, value, 0.0))
