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
solve on PETSc (:func:`nonlocal_system`, prefix ``nonlocal_``, CG + block ICC by
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

**The trigger** of the phase change sees the length through a window of radius 2ℓ in
the reference configuration, not through :math:`\tilde\kappa`
(:mod:`parsph.solid.trigger`).

Modified Cam-Clay's softening (its pre-consolidation pressure on the dry side) stays
local: the average reaches it only through the trigger (docs/regularisation.md).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from decomposition.numbering import global_offset
from decomposition.reduce import global_max

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
        # sort the row's columns and sum duplicates (periodic images of one particle):
        # a stable insertion sort in place, the columns of the owned neighbours coming
        # ascending already (an argsort and its copies per row had cost three times the
        # row's sums)
        for q in range(start + 1, at):
            cq, vq = cols[q], vals[q]
            r = q
            while r > start and cols[r - 1] > cq:
                cols[r] = cols[r - 1]
                vals[r] = vals[r - 1]
                r -= 1
            cols[r] = cq
            vals[r] = vq
        w = start
        for q in range(start, at):
            if q > start and cols[q] == cols[w - 1]:
                vals[w - 1] += vals[q]
            else:
                cols[w] = cols[q]
                vals[w] = vals[q]
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


def nonlocal_system(comm, n_rows):
    """The PETSc system of the average (options prefix ``nonlocal_``): CG with incomplete
    Cholesky on each rank's block, of Jacobi, BoomerAMG, GAMG and ICC the fastest here
    (docs/regularisation.md); it stops at a fall of the residual by 1e-9 (an absolute
    stop at a hundredth of :data:`SOLVE_TOLERANCE` took 8.7 -> 6.7 iterations a step
    on the 3D slope, but 1 and 2 ranks, whose block preconditioners differ, then agreed
    to 6e-8 m instead of 1e-9: dropped)."""
    import solvers

    return solvers.LinearSystem(comm, "nonlocal_", n_rows, ksp_type="cg", pc_type="bjacobi",
                                rtol=1e-9, max_it=10000,
                                options={"sub_pc_type": "icc"})


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
            self.system = nonlocal_system(ctx.comm, self.n_rows)
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
