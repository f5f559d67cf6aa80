r"""The IISPH stage: projection method of the paper, eqs. (30)-(41), on PETSc.

One step from :math:`t^\beta` to :math:`t^{\beta+1} = t^\beta + \Delta t` (current layout:
neighbour lists within 2h of the current positions, owned rows first, halo after):

1. global PETSc point of every owned row (``offset + local``), sent to the halo rows;
2. summation density (33) and free-surface flag (:math:`\rho_i < \beta \rho_0`);
3. strain rate (39), Bingham viscosity (40) (+ eddy viscosity (41) if asked), from the
   velocity and pressure of the last step;
4. an implicit step (``fluid.splitting = "projection_first"``, the default): the
   stabilised PPE (32)/(35)/(36) (``ppe_`` system, GMRES + BoomerAMG; free surface
   :math:`p = 0`, wall pressure extrapolated from the fluid, Adami et al. 2012) on
   :math:`\mathbf{v}^\beta + \Delta t\,\mathbf{g}`, the corrector (31) with the
   gradient (37), then the viscosity (40) again with the new pressure and the implicit
   viscous solve (30)/(34) (``visc_`` system, block size ``dim``) on the projected
   velocity; wall ghost velocities as extra unknowns. With ``splitting = "paper"`` the
   viscous predictor (30) comes first, as in the paper: with
   :math:`\nu \Delta t / h^2 \gg 1` it carries part of a deposit's weight to a no-slip
   floor and the deposit creeps (docs/coupling.md);
5. an explicit step (``fluid.viscous_solver = "auto"`` and a viscous number below
   ``fluid.explicit_viscous_number``): the same operator applied to the present velocity,
   then the PPE and the corrector;
6. positions :math:`\mathbf{x} \mathrel{+}= \Delta t \mathbf{v}^{\beta+1}` (symplectic Euler).

The time step is eq. (49) with :math:`C^f_{CFL}` = ``fluid.cfl`` and no viscous limit.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from decomposition.numbering import global_offset
from decomposition.reduce import global_any, global_max, global_min, global_reduce, global_sum
from parsph.fluid import assembly, response, rheology, viscous
from parsph.fluid.ppe import density_error_factor, ppe_csr
from parsph.fluid.surface import surface_contact
from parsph.core.energy import step_work
from parsph.core.particles import max_speed
from parsph.fluid.walls import row_order, system_rows, wall_slip
from parsph.scene.materials import PHASE_FLUID, PHASE_WALL
from solvers.csr import scale_rows, sort_neighbours_by_row

#: Fields of a step alone (name, vector): the systems' row numbers, v*, and (coupled) the
#: solids' inverse true mass and self-response (:mod:`parsph.fluid.response`); all but
#: the first are dropped before a viscous solve after the projection. 80 B per particle
#: in 3D that had sat beside the next lists, the solid's step, a checkpoint, that solve.
STEP_FIELDS = (("fluid_row", False), ("v_star", True), ("inv_mass", True), ("a_self", True))

#: BoomerAMG defaults of the PPE beyond every system's smoother: aggressive HMIS coarsening,
#: ext+i interpolation of at most 4 points (docs/solvers.md; the options database wins).
PPE_HYPRE_OPTIONS = {"pc_hypre_boomeramg_agg_nl": "1", "pc_hypre_boomeramg_coarsen_type": "HMIS",
                     "pc_hypre_boomeramg_interp_type": "ext+i", "pc_hypre_boomeramg_P_max": "4"}

STATS = ("viscous_number", "visc_iterations", "visc_residual", "ppe_iterations", "ppe_residual",
         "ppe_density_error", "ppe_setup", "n_free_surface", "fluid_contacts", "max_divergence",
         "density_work", "wall_s_fluid_assembly", "wall_s_fluid_solve", "wall_s_visc_solve",
         "wall_s_ppe_solve", "wall_s_fluid_halo")


def lattice_density_ratio(h_over_d: float, dim: int) -> float:
    """Summation density (33) of an interior particle of a regular lattice over m / d^dim.

    The reference density of the stabilisation term of eq. (32) and of the free-surface
    test is rho_0 times this ratio (0.99976 in 2D, 1.00081 in 3D for h = 1.2 d), the
    discrete rest state, as the reference particle number density n_0 of MPS
    (Koshizuka & Oka 1996); otherwise a fluid initially at rest on the lattice would be
    driven by the lattice's own summation error.
    """
    from parsph.core.kernel import w_array

    reach = int(np.ceil(2.0 * h_over_d))
    k = np.arange(-reach, reach + 1)
    grid = np.stack(np.meshgrid(*([k] * dim)), axis=-1).reshape(-1, dim)
    return float(w_array(np.linalg.norm(grid, axis=1), h_over_d, dim).sum())


@dataclass
class Coupling:
    """What a coupled step (section 5) hands the fluid step.

    ``inv_mass``: inverse true mass (1/kg) of the owned rows per component, zero but for
    solid rows and zero on a component a ``[[constraints]]`` box holds: the solid's
    response to the pressure in the strongly coupled PPE (:mod:`parsph.fluid.response`);
    ``mass``: the mass of every row (owned and halo) as the fluid sees it — a solid
    particle of volume V counts as V rho_f (fixed wall ghost particles of the fluid's
    density, Adami et al. 2012), so the fluid's summation density, Laplacian and
    divergence do not see the solid's density; ``scale``: 0 for non-solid rows, the ratio
    ``mass / m`` for solid rows (the viscous reaction on the solid's true mass).
    """

    inv_mass: np.ndarray
    mass: np.ndarray
    scale: np.ndarray


class IISPH:
    """Implicit incompressible SPH fluid (Newtonian or Bingham), paper section 4.

    Per-particle fields it adds: ``rho`` (summation density, eq. 33), ``rho0`` (rest
    density), ``nu`` (viscosity, eqs. 40-41), ``v_ghost`` (no-slip ghost velocity of wall
    rows, Adami et al. 2012), ``free_surface`` (uint8), ``wall_slip`` (uint8, 1 =
    free-slip wall); during a step only (:data:`STEP_FIELDS`) ``fluid_row`` (int64:
    global PETSc point of the row) and ``v_star`` (predictor velocity, eq. 30).

    Notes
    -----
    Parallel: each rank assembles the rows of its owned particles (fluid and walls) with
    global column indices taken from ``fluid_row`` of owned and halo rows, which is
    refreshed with one halo exchange per step; fields a kernel reads on halo rows (``rho``,
    ``nu``, ``v_star``, ``p``) are refreshed after they change. The two systems are kept
    while no rank's owned count changes and rebuilt on every rank otherwise; both build
    their matrices over one CSR buffer (docs/solvers.md).
    """

    name = "iisph"
    output_fields = ("nu", "free_surface")
    stats_columns = STATS

    def __init__(self, ctx):
        p = ctx.particles
        dim = ctx.dim
        self.num = ctx.scene.fluid
        p.add_field("rho")
        p.add_field("rho0")
        p.add_field("nu")
        p.add_field("v_ghost", (dim,))
        p.add_field("free_surface", dtype=np.uint8)
        p.add_field("wall_slip", dtype=np.uint8)
        # the PPE's last solution of every row, the next solve's initial guess (a solid
        # row's p is its mean stress, which the TLSPH stage writes, not an interface
        # pressure: as a guess it made GMRES diverge at once where the soil failed)
        p.add_field("p_ppe")
        p.add_field("ppe_band", dtype=np.uint8)  # the wall rows till the next sync step
        self.table = rheology.material_table(ctx.materials)
        n = p.n_owned
        fluid = p["phase"][:n] == PHASE_FLUID
        mat = np.maximum(p["material"][:n], 0)
        rest = np.where(fluid, self.table["rho0"][mat] if len(mat) else 0.0,
                        p["m"][:n] / ctx.d ** dim)
        rest = rest * lattice_density_ratio(ctx.h / ctx.d, dim)
        p["rho0"][:n] = rest
        p["rho"][:n] = rest
        p["wall_slip"][:n] = wall_slip(ctx.scene, p["body"][:n], ~fluid)
        if not ctx.restarted:  # a boundary is out of contact with the fluid until it touches
            p["free_surface"][:n] = ~fluid
        self.les = self.num.smagorinsky * self.num.les_width * ctx.h
        self._ppe = self._visc = None
        self._ppe_ids = None  # the particles of the PPE's rows at its last assembly
        self.buffers = assembly.WorkArrays()  # kept from step to step, idle between steps
        self._n_rows = -1
        self._dt_cfl = 0.0
        self._stats = {k: 0.0 for k in STATS}

    # -- systems ------------------------------------------------------------------

    def _systems(self, ctx, n):
        """The two linear systems for ``n`` rows on this rank (collective)."""
        if self._ppe is not None and global_any(ctx.comm, n != self._n_rows):
            # particles moved between ranks: the same systems over the new rows
            self._ppe.resize(n)
            self._visc.resize(n)
            self._n_rows = n
            self._ppe_ids = None
        if self._ppe is None:
            from solvers import LinearSystem

            self.destroy()
            tol = dict(max_it=self.num.max_it)
            # PPE: cheaper V-cycles and set-ups with PPE_HYPRE_OPTIONS (docs/solvers.md)
            # a density-error tolerance bounds the true residual: preconditioned on the right
            self._ppe = LinearSystem(ctx.comm, "ppe_", n, ksp_type="gmres", rtol=self.num.ppe_rtol,
                                     reuse_preconditioner=self.num.preconditioner_reuse,
                                     hypre_options=PPE_HYPRE_OPTIONS, **tol, pc_side="right"
                                     if self.num.ppe_density_error > 0 else "left")
            # viscous: afresh every step (a lagged set-up: the slope demo's solves 43 % slower)
            if self.num.viscous_operator == "matrix_free":
                from solvers import OperatorSystem

                self._visc = OperatorSystem(ctx.comm, "visc_", n, ctx.dim,
                                            rtol=self.num.visc_rtol, **tol)
            else:
                self._visc = LinearSystem(ctx.comm, "visc_", n, block_size=ctx.dim,
                                          ksp_type="gmres", rtol=self.num.visc_rtol, **tol)
            self._n_rows = n
            self._ppe_ids = None
        return self._ppe, self._visc

    def renew_preconditioners(self) -> None:
        """The PPE's next assembly sets its preconditioner up afresh."""
        self._ppe_ids = None

    def _same_ppe_rows(self, ids) -> bool:
        """Whether the PPE's rows are the particles ``ids`` of its last assembly (then its
        preconditioner set-up may be kept, see ``fluid.preconditioner_reuse``)."""
        same = self._ppe_ids is not None and np.array_equal(self._ppe_ids, ids)
        if not same:
            self._ppe_ids = ids.copy()
        return same

    def destroy(self) -> None:
        """Free the PETSc objects (collective)."""
        for system in (self._ppe, self._visc):
            if system is not None:
                system.destroy()
        self._ppe = self._visc = None

    # -- protocol -----------------------------------------------------------------

    def max_dt(self, ctx) -> float:
        """Eq. (49): ``cfl d / v_max`` over the fluid, with a floor on v_max (see FluidNumerics)."""
        p = ctx.particles
        n = ctx.n_owned
        vmax = global_max(ctx.comm, max_speed(p["v"], n, p["phase"], PHASE_FLUID))
        g = ctx.body_acceleration_norm(ctx.time)
        vmax = max(vmax, self.num.velocity_floor * math.sqrt(g * ctx.d))
        dt = self.num.cfl * ctx.d / vmax if vmax > 0 else math.inf
        if self.num.dt_max > 0:
            dt = min(dt, self.num.dt_max)
        self._dt_cfl = dt if math.isfinite(dt) else 0.0
        return dt

    @staticmethod
    def _pin_if_confined(ctx, fluid, free, n_coupled) -> bool:
        """Collective: with no free surface anywhere (a closed or periodic box) and no
        solid in the PPE (whose inertia fixes the level, docs/coupling.md) the PPE fixes
        the pressure only up to a constant; the fluid particle of smallest id then gets
        p = 0 (a Dirichlet row) so that the matrix is not singular. True if pinned."""
        if global_sum(ctx.comm, int(free[fluid.astype(bool)].sum()) + int(n_coupled)) > 0:
            return False
        ids = ctx.particles["id"][: ctx.n_owned]
        mine = ids[fluid.astype(bool)]
        first = global_min(ctx.comm, int(mine.min()) if len(mine) else np.iinfo(np.int64).max)
        free[(ids == first) & fluid.astype(bool)] = 1
        return True

    def _halo(self, ctx, names):
        t0 = time.perf_counter()
        ctx.update_halo(names)
        self._t_halo += time.perf_counter() - t0

    def _viscosity(self, ctx, gamma, fluid) -> None:
        """``nu`` of the owned rows from the strain rate and the present ``p`` (eqs. 40-41)."""
        p, n, h = ctx.particles, ctx.n_owned, ctx.h
        p["nu"][:n] = rheology.viscosity(gamma, p["p"][:n], fluid, p["material"][:n],
                                         self.table, self.les)
        if self.num.numerical_viscosity > 0:  # kappa h sqrt(|g| h), vanishes as h^1.5
            gnorm = ctx.body_acceleration_norm(ctx.time)
            p["nu"][:n][fluid == 1] += self.num.numerical_viscosity * h * math.sqrt(gnorm * h)

    def _viscous_solve(self, ctx, visc, order, dt, g, morris, m, row, indptr, indices, fluid,
                       solid, moved, wall, out):
        """The implicit viscous system (30)/(34) on the present ``v`` plus ``dt g``.

        Writes the new velocity of the ``moved`` rows (fluid and type II) to ``out`` and the
        no-slip ghost velocity of the ``wall`` rows to ``v_ghost``; keeps the type-II rows'
        velocity change in ``solid_viscous_dv`` (the viscous exchange of eq. (47)).
        Returns the solve's info and the assembly time.
        """
        p, n, dim, h = ctx.particles, ctx.n_owned, ctx.dim, ctx.h
        t0 = time.perf_counter()
        if self.num.viscous_operator == "matrix_free":
            rhs = self._viscous_operator(ctx, visc, order, dt, g, morris, m, row, indptr,
                                         indices, fluid, solid)
        else:
            ptr, cols, vals = self.buffers.csr(visc, assembly.csr_capacity(
                fluid, solid, row, indptr, dim, not morris))
            nnz, rhs = viscous.viscous_csr(
                p["x"], p["v"], m, p["rho"], p["nu"], fluid, solid, p["wall_slip"], row,
                indptr, indices, h, dim, dt, g, morris, visc.offset // dim, ptr, cols, vals)
            visc.assemble_csr(ptr, cols[:nnz], vals[:nnz])
        t_asm = time.perf_counter() - t0
        rhs = rhs[order]  # (the other order not held through the solve)
        vstar, info = visc.solve(rhs, x0=p["v"][:n][order])
        if self.num.viscous_operator == "matrix_free":
            visc.release()  # not held beside the PPE's and the next lists
        full = np.zeros((n, dim))
        full[order] = vstar
        self.solid_viscous_dv = np.where((solid[:n] > 0)[:, None] & moved[:, None],
                                         full - p["v"][:n], 0.0)
        np.copyto(out[:n], full, where=moved[:, None])
        p["v_ghost"][:n][wall] = full[wall]
        return info, t_asm

    def _viscous_operator(self, ctx, visc, order, dt, g, morris, m, row, indptr, indices,
                          fluid, solid):
        """Collective: the matrix-free viscous system (:class:`solvers.OperatorSystem`):
        a coefficient per pair of the rows with pairs (:func:`viscous.pair_offsets`) and
        the scalar preconditioner matrix (Jacobi: its diagonal) from
        :func:`viscous.viscous_pairs`, the operator :func:`viscous.viscous_apply` on them.
        Returns the right-hand side (owned, (n, dim))."""
        p, n, dim, h = ctx.particles, ctx.n_owned, ctx.dim, ctx.h
        first = visc.offset // dim
        ptr, cols, vals = self.buffers.csr(visc.scalar, assembly.csr_capacity(
            fluid, solid, row, indptr, 1, False))
        at = np.zeros(n, dtype=np.int64)
        size = viscous.pair_offsets(order, fluid, solid, p["wall_slip"], indptr, indices, at)
        if self._jacobi and size <= vals.size:  # no matrix to write: the coefficients in
            coef = vals[:size]  # the memory of the PPE's, whose solve is done (227 B/p in 3D)
            self.buffers.drop("visc_coef")
        else:
            coef = self.buffers.floats("visc_coef", size)
        kind = np.full(n, 3, dtype=np.int8)
        x = p["x"]
        diag = np.empty(order.size if self._jacobi else 0)
        nnz, rhs = viscous.viscous_pairs(
            x, p["v"], m, p["rho"], p["nu"], fluid, solid, p["wall_slip"], row,
            indptr, indices, h, dim, dt, g, morris, first, ptr, cols, vals, coef, at, kind,
            self.num.viscous_preconditioner_reach * ctx.d, diag)
        if self._jacobi:  # a small viscous number: Jacobi, not an AMG set-up
            visc.set_jacobi(np.divide(1.0, diag, out=np.ones_like(diag), where=diag > 0.0))
        else:
            visc.assemble_preconditioner(ptr, cols[:nnz], vals[:nnz])
        # where each local particle's unknowns sit in the operator's input: the owned rows
        # in row order, then the points of other ranks (halo particles in a row)
        src = np.full(len(row), -1, dtype=np.int64)
        src[order] = np.arange(order.size)
        halo = np.flatnonzero(row[n:] >= 0) + n
        src[halo] = order.size + np.arange(halo.size)
        visc.set_operator(*viscous.operator_callbacks(order, src, kind, coef, at, x, indptr,
                                                      indices, dim, row[halo]))
        return rhs

    def step(self, ctx, dt, coupling=None) -> None:
        r"""Advance the owned fluid particles from t to t + dt (eqs. (30)-(37)).

        Coupled scenes (section 5) pass ``coupling`` (:class:`Coupling`), the solid rows'
        ``v`` (owned and halo) holding their TLSPH predictor of eq. (7). Solid rows with a
        fluid neighbour (type II) then take part in both systems (eqs. (47)-(48)) and on
        return hold :math:`\mathbf{v}^{\beta+1}` in ``v``; type-I rows are left out.
        """
        p = ctx.particles
        n, dim, h, d = ctx.n_owned, ctx.dim, ctx.h, ctx.d
        self._t_halo = 0.0
        t0 = time.perf_counter()
        v_start = p["v"][:n].copy()  # (the body force's work in the step)
        fluid = (p["phase"] == PHASE_FLUID).astype(np.uint8)
        coupled = coupling is not None
        for name, vector in STEP_FIELDS[:None if coupled else 2]:
            p.add_field(name, (dim,) if vector else (), np.float64 if vector else np.int64)
        solid = coupling.scale if coupled else np.zeros(len(fluid))
        if coupled:
            p["inv_mass"][:n] = coupling.inv_mass
        # rows of the systems: fluid rows, boundary rows with a fluid neighbour and the
        # walls the fluid can reach before the next sync step (walls.system_rows)
        is_wall = p["phase"][:n] == PHASE_WALL
        act = system_rows(ctx, fluid, is_wall)
        # the rows in order: fluid and solid rows, then the walls (walls.row_order)
        order = row_order(act, is_wall)
        n_act = len(order)
        ppe, visc = self._systems(ctx, n_act)
        offset, _ = global_offset(ctx.comm, n_act)
        row = p["fluid_row"]
        row[:n] = -1
        row[:n][order] = offset + np.arange(n_act, dtype=np.int64)
        t_asm = time.perf_counter() - t0
        self._halo(ctx, ["fluid_row", "inv_mass"] if coupled else ["fluid_row"])
        t0 = time.perf_counter()
        x = p["x"]
        m = coupling.mass if coupled else p["m"]
        # neighbours in global row order: the matrix rows come out (nearly) sorted. In
        # place: nothing reads the lists in ascending order after this (they are built
        # afresh for the next step)
        indptr, indices = ctx.indptr, sort_neighbours_by_row(
            ctx.indptr, ctx.indices, row, inplace=True, ascending=True, order=ctx.list_order)
        slip = p["wall_slip"]
        rho, rho0 = p["rho"], p["rho0"]
        free = p["free_surface"]
        max_div = assembly.density_and_surface(
            x, p["v"], m, fluid, rho0, indptr, indices, h, dim, self.num.free_surface_beta,
            self.num.free_surface_gamma, rho, free)
        own_solid = (solid[:n] > 0) & act  # type II
        confined = self._pin_if_confined(ctx, fluid[:n], free[:n], own_solid.sum())
        t_asm += time.perf_counter() - t0
        self._halo(ctx, ["rho", "free_surface"])

        t0 = time.perf_counter()
        gamma = rheology.fluid_strain_rate(x, p["v"], p["v_ghost"], m, rho, fluid, solid, slip,
                                           indptr, indices, h, dim, p["material"], self.table)
        self._viscosity(ctx, gamma, fluid[:n])
        own_fluid = fluid[:n] == 1
        # the fluid's largest viscous number; a type-II row's pair coefficients are the
        # fluid's times its scale, so forward Euler is stable while their product is small
        _, (zeta, heavy), _ = global_reduce(ctx.comm, maxs=(
            float(p["nu"][:n][own_fluid].max()) * dt / (h * h) if own_fluid.any() else 0.0,
            float(solid[:n][own_solid].max()) if own_solid.any() else 0.0))
        strong = coupled and heavy > 0  # a type-II row on some rank: the solid-response terms
        if strong:  # the solids' acceleration per unit of their own pressure
            p["a_self"][:n] = response.self_response(x, m, rho, rho0, fluid, solid,
                                                     p["inv_mass"], indptr, indices, h, dim)
        t_asm += time.perf_counter() - t0

        g = np.asarray(ctx.body_acceleration(ctx.time), dtype=np.float64)
        wall = act & ~own_fluid & (solid[:n] == 0)
        morris = self.num.viscous_term == "morris"
        mode = self.num.viscous_solver
        explicit = mode == "explicit" or (
            mode == "auto" and zeta * max(1.0, heavy) < self.num.explicit_viscous_number)
        self._jacobi = zeta < self.num.explicit_viscous_number  # (docs/solvers.md)
        # an implicit step projects first unless the paper's order is asked for: with
        # nu dt / h^2 >> 1 the viscous predictor would carry part of the weight to a
        # no-slip wall through a non-solenoidal v* (docs/coupling.md)
        first = not explicit and self.num.splitting == "projection_first"
        vs = p["v_star"]
        vs[:n] = p["v"][:n]  # walls and solids: their velocity (the fluid rows: below)
        info_v = dict(iterations=0, residual_norm=0.0, time_s=0.0)
        moved = own_fluid | own_solid  # the rows whose velocity the viscous solve sets
        self.solid_viscous_dv = np.zeros((0, dim))  # (set by a viscous solve, else none)
        if first:  # the PPE's predictor: the body force alone
            np.add(vs[:n], dt * g, out=vs[:n], where=own_fluid[:, None])
            self._halo(ctx, ["v_star", "a_self"] if coupled else ["v_star"])
        elif explicit:  # zeta << 1: forward Euler on the operator of eq. (34), no matrix
            t0 = time.perf_counter()
            viscous.ghost_velocity(x, p["v"], fluid, slip, indptr, indices, h, dim,
                                    p["v_ghost"])
            t_asm += time.perf_counter() - t0
            self._halo(ctx, ["nu", "v_ghost"])
            t0 = time.perf_counter()
            vexp = viscous.viscous_explicit(x, p["v"], p["v_ghost"], m, rho, p["nu"], fluid,
                                             solid, slip, indptr, indices, h, dim, dt, g, morris)
            np.copyto(vs[:n], vexp, where=moved[:, None])
            vexp = None
            t_asm += time.perf_counter() - t0
            self._halo(ctx, ["v_star", "a_self"] if coupled else ["v_star"])
        else:  # the paper's order: the viscous predictor (30) first
            self._halo(ctx, ["nu", "a_self"] if coupled else ["nu"])
            info_v, dt_asm = self._viscous_solve(ctx, visc, order, dt, g, morris, m, row,
                                                 indptr, indices, fluid, solid, moved, wall, vs)
            t_asm += dt_asm
            self._halo(ctx, ["v_star"])

        t0 = time.perf_counter()
        # a step shorter than the CFL step (a fixed run.dt, a solid-limited coupled step)
        # would amplify the density term of eq. (32) by (dt_cfl / dt)^2: alpha is
        # rescaled so the correction is per CFL step
        alpha = self.num.alpha * min(1.0, (dt / self._dt_cfl) ** 2) if self._dt_cfl > 0 \
            else self.num.alpha
        ptr, cols, vals = self.buffers.csr(ppe, assembly.csr_capacity(
            fluid, solid, row, indptr, 1, False))
        expansion = self.num.density_correction == "both" or (
            self.num.density_correction == "auto" and not confined)
        nnz, rhs = ppe_csr(
            x, vs, m, rho, rho0, fluid, free, row, indptr, indices, h, dim, dt, alpha, d,
            self.num.ppe_laplacian == "corrected", expansion, ppe.offset, ptr, cols, vals)
        if strong:  # the solid-response term (strong coupling, docs/coupling.md)
            near = self.buffers.csr(ppe, response.near_capacity(
                fluid, free, solid, row, indptr, indices, ppe.offset, ptr), key="near")
            n_near = response.add_near_response(
                x, m, rho, rho0, fluid, free, solid, row, p["inv_mass"], p["a_self"], indptr,
                indices, h, dim, d, ppe.offset, ptr, cols, vals, *near)
            blocks = response.response_blocks(x, m, rho, rho0, fluid, free, solid, row,
                                              p["inv_mass"], indptr, indices, h, dim, d)
        # every row scaled to a unit diagonal: a boundary row barely in contact has a
        # diagonal of 1e-9 one step and 1e-7 the next, and a lagged set-up then took 60
        # iterations where a fresh one took 9 (with the scaling: 11; docs/solvers.md)
        # over the shared buffer, no copy: the viscous system rewrites it after this solve
        scale = ppe.assemble_csr_over(ptr, cols[:nnz], vals[:nnz], self._same_ppe_rows(
            p["id"][:n][order]), self.num.ppe_preconditioner_drop, unit_diagonal=True)
        if strong:
            scale_rows(near[0], near[2][:n_near], scale)
            ppe.set_product(*blocks, near=(near[0], near[1][:n_near], near[2][:n_near]),
                            row_scale=scale)
        inner = own_fluid & (free[:n] == 0)
        eta, err = self.num.ppe_density_error, math.nan
        if eta > 0:  # as the KSP's atol (density_error_factor)
            err = density_error_factor(ctx.comm, scale, rho[:n][order], inner[order],
                                       int(own_fluid.sum()), dt, d)
            ppe.ksp.setTolerances(atol=eta / err if err > 0 else 1e-50)
        t_asm += time.perf_counter() - t0
        pres, info_p = ppe.solve(rhs[order] * scale, x0=p["p_ppe"][:n][order])
        p["p_ppe"][:n][order] = pres
        if self.num.clamp_negative_pressure:  # MPS practice (Koshizuka & Oka 1996)
            # every row: a boundary's negative pressure is suction, which would hold the
            # fluid to a wall or the soil it leaves
            pres = np.maximum(pres, 0.0)
        p["p"][:n][order] = pres
        self._halo(ctx, ["p"])
        # the work the density term of eq. (32) lets the pressure do: it asks a compressed
        # particle to expand by alpha (rho - rho0) / rho0 in the step, which a projection
        # without it would not (a source of kinetic energy: stats.csv density_work)
        drho = rho[:n] - rho0[:n] if expansion else np.maximum(rho[:n] - rho0[:n], 0.0)
        work = alpha * p["p"][:n] * m[:n] / rho[:n] * drho / rho0[:n]
        density_work = float(np.maximum(work[inner], 0.0).sum())

        t0 = time.perf_counter()
        mode = self.num.pressure_gradient
        if mode == "corrected":
            grad = assembly.pressure_gradient_corrected(x, p["p"], m, rho, fluid, indptr,
                                                        indices, h, dim)
        else:  # (hybrid: the surface rows, p = 0 and half a support, corrected below)
            surface = (free[:n] == 1).astype(np.uint8) & fluid[:n]
            grad = assembly.pressure_gradient(x, p["p"], m, rho, fluid[:n] & (
                1 - surface if mode == "hybrid" else 1), indptr, indices, h, dim)
            if mode == "hybrid":
                # the fluid's pressure over its fluid neighbours only, and each solid
                # neighbour's (type II in contact: a no-penetration multiplier) by the
                # symmetric pair of eq. (37), the exact reaction of the force the solid
                # gets (eq. (45)); walls hold a surface particle through the contact rule
                # below (docs/coupling.md, "Free-surface rows next to a solid")
                wet = (fluid == 1).astype(np.uint8)
                corr = assembly.pressure_gradient_corrected(x, p["p"], m, rho, surface, indptr,
                                                            indices, h, dim, wet)
                if (solid > 0).any():  # (no solid row here: it adds zero)
                    p_bnd = np.where(solid > 0, p["p"], 0.0)
                    corr += assembly.pressure_gradient(x, p_bnd, m, rho, surface, indptr,
                                                       indices, h, dim)
                grad[surface == 1] = corr[surface == 1]
        vnew = vs[:n] - dt * grad / rho0[:n, None]
        if own_solid.any():  # eq. (48): the reaction of the fluid pressure, eq. (45)
            if explicit:  # the viscous exchange of eq. (47), as a solve's (not held by the PPE)
                self.solid_viscous_dv = np.where(own_solid[:, None], vs[:n] - p["v"][:n], 0.0)
            mark = np.zeros(len(fluid))
            mark[:n][own_solid] = solid[:n][own_solid]
            force = response.solid_pressure_force(x, p["p"], m, rho, rho0, fluid, mark,
                                                  indptr, indices, h, dim)
            p["v"][:n][own_solid] = vs[:n][own_solid] \
                + dt * p["inv_mass"][:n][own_solid] * force[own_solid]
            self.solid_force = force
        else:
            self.solid_force = np.zeros((n, dim))
        contacts = 0
        if self.num.surface_wall_contact:  # (fluid/surface.py)
            contacts, reaction = surface_contact(ctx, vnew, own_fluid, free, fluid, solid,
                                                 strong, m, grad, rho0, dt, self.table,
                                                 indptr, indices)
            if reaction is not None:  # (only with a type-II row)
                self.solid_force[:n] += reaction / dt
        np.copyto(p["v"][:n], vnew, where=own_fluid[:, None])
        grad = vnew = corr = vs = None  # not held through the viscous solve
        t_asm += time.perf_counter() - t0
        if first:  # the viscous solve on the projected velocity, the new p in eq. (40)
            for name, _ in STEP_FIELDS[1:]:
                p.data.pop(name, None)
            t0 = time.perf_counter()
            self._viscosity(ctx, gamma, fluid[:n])
            t_asm += time.perf_counter() - t0
            self._halo(ctx, ["nu"])
            info_v, dt_asm = self._viscous_solve(ctx, visc, order, dt, np.zeros(dim), morris,
                                                 m, row, indptr, indices, fluid, solid, moved,
                                                 wall, p["v"])
            t_asm += dt_asm
        t0 = time.perf_counter()
        np.add(p["x"][:n], dt * p["v"][:n], out=p["x"][:n], where=own_fluid[:, None])
        # the body force's work on the fluid rows (a type-II solid's is the solid stage's)
        ctx.add_work(step_work(p["m"], v_start, p["v"], own_fluid, n, dt, g[:dim],
                               np.zeros((0, dim)))[0])
        v_start = None
        t_asm += time.perf_counter() - t0

        (n_free, n_contacts, density_work, n_coupled), (max_div,), _ = global_reduce(
            ctx.comm, sums=(int(free[:n][own_fluid].sum()), contacts, density_work,
                            int(own_solid.sum())),
            maxs=(max_div,))
        self._stats = {
            "viscous_number": zeta,
            "visc_iterations": info_v["iterations"],
            "visc_residual": info_v["residual_norm"],
            "ppe_iterations": info_p["iterations"],
            "ppe_residual": info_p["residual_norm"],
            "ppe_density_error": err * info_p["residual_norm"],
            "ppe_setup": int(info_p["fresh_setup"]),
            "n_free_surface": int(n_free),
            "fluid_contacts": int(n_contacts),
            "max_divergence": max_div,
            "density_work": density_work,
            "wall_s_fluid_assembly": t_asm,
            "wall_s_fluid_solve": info_v["time_s"] + info_p["time_s"],
            "wall_s_visc_solve": info_v["time_s"],
            "wall_s_ppe_solve": info_p["time_s"],
            "wall_s_fluid_halo": self._t_halo,
        }
        if coupled:
            self._stats["n_coupled"] = int(n_coupled)
        for name, _ in STEP_FIELDS:
            p.data.pop(name, None)

    def stats(self) -> dict:
        """Iterations and residuals of both solves, free-surface count, timings of the last step."""
        return dict(self._stats)

    def state(self) -> dict:
        """No scalar state: everything lives in the particle fields."""
        return {}

    def restore(self, ctx, state) -> None:
        """Nothing to restore (the systems are rebuilt on the next step)."""
