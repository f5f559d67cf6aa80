r"""The TLSPH solid stage: total-Lagrangian SPH for finite-strain elastoplastic soil.

One step (paper section 3, symplectic Euler as eqs. (7)-(8)), on the owned solid rows,
with the reference-configuration neighbour lists of the driver (``ctx.indptr``):

1. halo refresh of :math:`\mathbf Q = \mathbf L^T\mathbf P/\rho_0^2` (computed at the end
   of the previous step);
2. :math:`\frac{1}{\rho_0}\nabla_0\cdot\mathbf P` (eq. (13)), JST damping
   :math:`c_p d(\epsilon^{(2)}\nabla_0^2\mathbf v - d^2\epsilon^{(4)}\nabla_0^4\mathbf v)`
   (eqs. (9)-(12), one halo refresh of the Laplacian between the two passes) and
   :math:`\mathbf g` -> :math:`\mathbf v^{\beta+1}` (eq. (7));
3. Dirichlet constraints and wall contact (non-penetration, Coulomb friction) on
   :math:`\mathbf v^{\beta+1}`;
4. halo refresh of v; :math:`\dot{\mathbf F}` from eq. (14); F (eqs. (8), (20)-(21)),
   porosity (eq. (5)), constitutive return (Appendices A/B), P (eq. (27));
5. :math:`\mathbf x^{\beta+1} = \mathbf x^\beta + \Delta t\,\mathbf v^{\beta+1}`.

All per-particle state lives in ``ctx.particles`` (F, tau, eps_e, P, eps_p, p_c,
porosity, ...), so checkpoints and migration carry it.
"""
from __future__ import annotations

import math

import numpy as np

from decomposition import raise_if_any
from decomposition.reduce import global_any, global_max, global_sum
from parsph.errors import NumericalError
from parsph.scene.materials import PHASE_SOLID
from parsph.solid import geostatic, kernels
from parsph.core.contact import INSTANT, NO_MASS, contact_points_moved, solid_wall_set, \
    wall_contact
from parsph.core.energy import step_work
from parsph.core.particles import max_speed
from parsph.solid.boundary import initial_velocity, velocity_masks
from parsph.solid.update import CAM_CLAY, C, elastic_energy, material_table, stress_terms, \
    update_particles, wave_speed

TRIAXIAL_COLUMNS = ("axial_strain", "p_eff", "q", "spec_volume", "M", "sigma_axial")

#: Skin of the solids' wall-contact lists, in particle spacings (:meth:`TLSPH._contact`):
#: they are searched again once a solid has moved this far. Up to the skin a list holds
#: more walls than reach it: (2.9 / 2.4)^dim of them at h = 1.2 d.
CONTACT_SKIN = 0.5


class TLSPH:
    """Total-Lagrangian SPH solid stage (see the module docstring and docs/tlsph.md)."""

    name = "tlsph"
    output_fields = ()

    def __init__(self, ctx):
        p = ctx.particles
        for name in ("F", "tau", "eps_e"):
            p.add_field(name, (3, 3))
        for name in ("L", "Q"):
            p.add_field(name, (3, 3))
        p.add_field("lapv", (3,))
        for name in ("p_c", "rho0", "modulus"):
            p.add_field(name)
        p.add_field("solid_init", (), np.uint8)
        if geostatic.fields(ctx.scene, False):  # the stage's plastic strain, reported
            p.add_field("eps_p_geostatic")
        # the lagged normal contact acceleration of the wall friction (m/s^2, _contact)
        p.add_field("contact_a")
        self.num = ctx.scene.solid
        # the internal length of the soils that soften or change phase: softening (over-
        # non-local factor m) and trigger see the non-local strain (parsph.solid.regularise)
        regular = [getattr(m, "regularised", False) for m in ctx.materials]
        m_nl = [m.nonlocal_m if r and m.softens() else 0.0
                for m, r in zip(ctx.materials, regular)]
        self.tab = material_table(ctx.materials, m_nl)
        self.nl_strain = None
        self.output_fields = ()
        if any(m_nl):  # the softening soils' average (the trigger has its own window)
            self._init_nonlocal(ctx, [m > 0.0 for m in m_nl])
        if "eps_p_geostatic" in p:
            self.output_fields += ("eps_p_geostatic",)
        self.rho0_of = np.ascontiguousarray(self.tab[:, C["rho0"]])
        self.has_cam_clay = bool(np.any(self.tab[:, C["model"]] == CAM_CLAY))
        self.has_walls = bool(ctx.scene.walls)
        # each wall's Coulomb coefficient for the solid (walls.N.friction, else the scene's)
        self.wall_friction = np.array(
            [self.num.wall_friction if w.friction is None else w.friction
             for w in ctx.scene.walls] + [self.num.wall_friction])
        self.failure_fluidises = False  # set by the coupled stage (phase change)
        self.failed = np.zeros(0, dtype=np.int64)  # rows that failed in the last step
        #: size -> float64 memory idle during predict() or None (set by a coupled stage)
        self.scratch = lambda size: None
        self.stats_columns = ("solid_plastic", "solid_contacts", "elastic_energy")
        if self.nl_strain is not None:
            self.stats_columns += ("nonlocal_iterations", "wall_s_nonlocal")
        if self.num.ambient_pressure != 0.0:
            self.stats_columns += ("ambient_energy",)
        if self.num.triaxial_csv:
            self.stats_columns += TRIAXIAL_COLUMNS
        self._stats = {}
        self._walls = None  # the wall-contact lists (_contact)
        # a step's start velocities, body acceleration and constraint impulses: its work
        # (finish_step, parsph.core.energy)
        self._v0 = self._b = self._impulse = self._ahg = None

    # ------------------------------------------------------------------ set-up
    def _init_nonlocal(self, ctx, regular) -> None:
        """The non-local plastic strain of the regularised soils (fields and system)."""
        from parsph.solid.regularise import NonlocalStrain

        p = ctx.particles
        ell = [m.internal_length if r else 0.0 for m, r in zip(ctx.materials, regular)]
        self.nl_strain = NonlocalStrain(ctx.comm, regular, ell, p)
        self.output_fields = ("eps_p_nl",)
        self._nl_total = None  # regularised rows of the last build (all ranks)

    def _setup_nonlocal(self, ctx) -> None:
        """Collective: the non-local system on this set of solid rows; solved again when
        the rows changed (a phase change), or on a fresh run; a restarted run keeps the
        checkpoint's average."""
        nl = self.nl_strain
        nl.build(ctx, self.vol, self.sel, self.fp)
        total = global_sum(ctx.comm, nl.n_rows)
        changed = total != self._nl_total if self._nl_total is not None else not ctx.restarted
        self._nl_total = total
        if changed:
            nl.solve(ctx, self.vol)

    def _masks(self, ctx):
        p = ctx.particles
        self.sel = np.ascontiguousarray(p["phase"] == PHASE_SOLID)
        self.vol = np.ascontiguousarray(p["m"] / np.where(p["rho0"] > 0, p["rho0"], 1.0))
        self.X3 = self._pad(p["X"])
        n = p.n_owned
        self.vmask, self.vvalue = velocity_masks(ctx.scene.constraints, p["X"][:n],
                                                 self.sel[:n], p["body"][:n],
                                                 [b.name for b in ctx.scene.bodies])

    @staticmethod
    def _pad(a):
        """(N, dim) -> (N, 3) with zero third components in 2D (the pair loops are 3D)."""
        if a.shape[1] == 3:
            return np.ascontiguousarray(a)
        out = np.zeros((len(a), 3))
        out[:, : a.shape[1]] = a
        return out

    def setup(self, ctx, edit=None):
        """Initial state (fresh runs), correction matrices, halo of the fixed fields.

        ``edit`` (:class:`parsph.coupling.view.ViewEdit`): ``ctx`` is the last set-up's
        view less some rows (a phase change), so the pair factors are the last ones on
        the entries that stay and only the rows that lost a neighbour get a new
        correction matrix: the same values a set-up from scratch gives."""
        p, n, dim = ctx.particles, ctx.particles.n_owned, ctx.dim
        mat = p["material"][:n]
        solid = p["phase"][:n] == PHASE_SOLID
        rho0 = np.where(solid, self.rho0_of[np.maximum(mat, 0)], p["m"][:n] / ctx.d ** dim)
        p["rho0"][:n] = rho0
        fresh = solid & (p["solid_init"][:n] == 0)
        if fresh.any():
            self._initial_state(ctx, fresh)
        ctx.update_halo(["rho0"])
        self._masks(ctx)
        if edit is None:
            rows, self.clamp = np.arange(n), np.zeros(n, dtype=np.uint8)
            self.fp = kernels.pair_factors(p["X"], self.sel, n, ctx.indptr, ctx.indices, ctx.h,
                                           dim)
        else:
            rows, self.clamp = edit.lost, self.clamp[edit.keep]
            p["L"][:n] = edit.L
            self.fp = self.fp[edit.entry]
        kernels.correction_rows(rows, p["X"], self.vol, self.sel, self.fp, ctx.indptr,
                                ctx.indices, dim, self.num.correction_floor, p["L"], self.clamp)
        self._stats["correction_clamped"] = global_sum(ctx.comm, int(self.clamp.sum()))
        if self.nl_strain is not None:
            self._setup_nonlocal(ctx)
        self._stress_terms(ctx)
        ctx.update_halo(["v", "L"])

    def _initial_state(self, ctx, fresh):
        p = ctx.particles
        n = p.n_owned
        eye = np.eye(3)
        p["F"][:n][fresh] = eye
        p["eps_e"][:n][fresh] = 0.0
        p["tau"][:n][fresh] = 0.0
        for k, m in enumerate(ctx.materials):
            sel = fresh & (p["material"][:n] == k)
            if hasattr(m, "porosity"):
                p["porosity"][:n][sel] = m.porosity
            if int(self.tab[k, C["model"]]) == CAM_CLAY:
                p["tau"][:n][sel] = -m.initial_pressure * eye
                p["p_c"][:n][sel] = m.preconsolidation
        p["p"][:n][fresh] = -np.trace(p["tau"][:n][fresh], axis1=1, axis2=2) / 3.0
        initial_velocity(ctx.scene.constraints, p["X"][:n], p["v"][:n], fresh, p["body"][:n],
                         [b.name for b in ctx.scene.bodies])
        p["solid_init"][:n][fresh] = 1

    def _stress_terms(self, ctx):
        p = ctx.particles
        stress_terms(p["tau"], p["F"], p["L"], self.rho0_of, p["material"], self.sel,
                     p.n_owned, ctx.dim, self.num.ambient_pressure, p["Q"])

    # ------------------------------------------------------------------ time step
    def max_wave_speed(self, ctx) -> float:
        """Collective: the largest P-wave speed c_p of the owned solids (m/s)."""
        p = ctx.particles
        c = wave_speed(self.tab, p["material"], p["p"], p["porosity"], self.sel, p.n_owned,
                       p["modulus"])
        return global_max(ctx.comm, c)

    def max_dt(self, ctx) -> float:
        """CFL limit of eq. (49), solid part: ``C d / (c_p + |v|_max)``."""
        p = ctx.particles
        n = p.n_owned
        vmax = max_speed(p["v"], n, self.sel, True)
        speed = self.max_wave_speed(ctx) + global_max(ctx.comm, vmax)
        return self.num.cfl * ctx.d / speed if speed > 0 else math.inf

    def step(self, ctx, dt: float) -> None:
        """Advance the owned solid particles from t to t + dt (positions included)."""
        self.predict(ctx, dt)
        self.finish_step(ctx, dt)

    def predict(self, ctx, dt: float, extra=None, cp=None, body=None) -> None:
        r"""Steps 1-3: :math:`\mathbf v^{\beta+1}` of eq. (7) (stress, JST, body force, and
        ``extra``, an acceleration of the owned rows (n_owned, dim) if given), Dirichlet
        constraints and wall contact. A coupled step (section 5) corrects the type-II rows'
        velocity between :meth:`predict` and :meth:`finish_step`. ``cp``: the wave speed
        of the JST term (m/s; default: computed now, a collective); ``body``: the body
        acceleration (default gravity and the record, :meth:`Context.body_acceleration`;
        the geostatic stage gives gravity alone)."""
        p, n, dim = ctx.particles, ctx.particles.n_owned, ctx.dim
        X, sel, fp = self.X3, self.sel, self.fp
        args = (n, ctx.indptr, ctx.indices)
        if cp is None:
            cp = self.max_wave_speed(ctx)
        alpha = self.num.hourglass
        ctx.update_halo(["Q", "x", "F", "modulus"] if alpha > 0.0 else ["Q", "x"])
        acc = np.zeros((n, 3))
        v3 = self._pad(p["v"])
        x3 = self._pad(p["x"])
        kernels.stress_divergence(p["Q"], X, p["m"], fp, *args, acc)
        ahg = None
        if alpha > 0.0:  # (its own array: the work of its force, finish_step)
            ahg = np.zeros((n, 3))
            kernels.hourglass(x3, X, p["F"], p["m"], self.vol, p["modulus"], fp, *args, ctx.h,
                              dim, alpha, ahg)
            acc += ahg
        eps2, eps4 = self.num.jst_eps2, self.num.jst_eps4
        lap = lap4 = none = np.empty((0, 3))
        if eps2 > 0.0 or eps4 > 0.0:
            lap = p["lapv"]
            # the pairs' kernel terms (456 B per 3D particle: in idle memory if there is)
            size = len(ctx.indices) if eps4 > 0.0 else 0
            coef = self.scratch(size)
            coef = np.empty(size) if coef is None else coef
            kernels.laplacian(v3, x3, p["m"], p["rho0"], fp, *args, ctx.h, dim, lap, coef)
            if eps4 > 0.0:
                ctx.update_halo(["lapv"])
                lap4 = np.zeros((n, 3))
                kernels.laplacian_stored(lap, x3, coef, *args, lap4)
            coef = None
        g = np.asarray(ctx.body_acceleration(ctx.time) if body is None else body,
                       dtype=float)[:dim]
        self._v0, self._b, self._impulse, self._ahg = p["v"][:n].copy(), g, None, ahg
        kernels.kick(p["v"], acc, lap, lap4, g, none if extra is None else extra, sel, n, dt,
                     cp * ctx.d, eps2, ctx.d ** 2 * eps4, dim)
        self.constrain(ctx)
        self._stats["solid_contacts"] = self._contact(ctx, dt) if self.has_walls else 0

    def constrain(self, ctx) -> None:
        """Dirichlet velocity constraints (``[[constraints]]``) on the owned rows; their
        impulse is kept for their work in the step (:meth:`finish_step`)."""
        p = ctx.particles
        v, n, held = p["v"], p.n_owned, self.vmask
        if not held.any():
            return
        if self._impulse is None:
            self._impulse = np.zeros(held.shape)
        mass = np.broadcast_to(p["m"][:n, None], held.shape)[held]
        self._impulse[held] += mass * (self.vvalue[held] - v[:n][held])
        v[:n][held] = self.vvalue[held]

    def finish_step(self, ctx, dt: float, stats: bool = True) -> None:
        r"""Steps 4-5: :math:`\dot{\mathbf F}` (eq. (14)) from the final velocities, the
        constitutive update and :math:`\mathbf x^{\beta+1}`; ``stats`` (collective sums
        for stats.csv) may be skipped in all but the last sub-step of a coupled step."""
        p, n, dim = ctx.particles, ctx.particles.n_owned, ctx.dim
        X, sel, fp = self.X3, self.sel, self.fp
        args = (n, ctx.indptr, ctx.indices)
        v = p["v"]
        ctx.update_halo(["v"])
        fdot = np.zeros((n, 3, 3))
        kernels.velocity_gradient(self._pad(v), X, self.vol, p["L"], fp, *args, fdot)
        failed = np.zeros(n, dtype=np.uint8)
        nl = self.nl_strain
        bad, plastic = update_particles(self.tab, p["material"], sel, n, dt, fdot, p["F"],
                                        p["tau"], p["eps_e"], p["eps_p"], p["p_c"],
                                        p["porosity"], p["p"], failed, dim,
                                        p["eps_p" if nl is None else "eps_p_shift"])
        # coupled scenes with phase change: a failed particle becomes fluid (docs/coupling.md)
        self.failed = np.flatnonzero(failed)
        error = None
        if bad >= 0 and not self.failure_fluidises:
            error = NumericalError(
                f"TLSPH: particle id {int(p['id'][bad])} inverted (det F <= 0) or its return "
                f"map failed at t = {ctx.time:.6g} s (rank {ctx.comm.rank}); reduce solid.cfl "
                f"or run.dt, or raise solid.jst_eps4")
        raise_if_any(ctx.comm, error)
        if nl is not None:
            nl.iterations = 0
            if nl.due(ctx):
                nl.solve(ctx, self.vol)
        if self._v0 is not None:  # the step's work: body force, constraints, hourglass
            self._add_work(ctx, dt)
        kernels.drift(p["x"], v, sel, n, dt, dim)
        self._stress_terms(ctx)
        if not stats:
            return
        self._stats["solid_plastic"] = global_sum(ctx.comm, plastic)
        self._stats["elastic_energy"] = self._elastic_energy(ctx)
        if self.nl_strain is not None:
            self._stats["nonlocal_iterations"] = self.nl_strain.iterations
            self._stats["wall_s_nonlocal"] = self.nl_strain.wall_s
            self.nl_strain.wall_s = 0.0
        if self.num.ambient_pressure != 0.0:
            self._stats["ambient_energy"] = self._ambient_energy(ctx)
        if self.num.triaxial_csv:
            self._triaxial(ctx, dt)

    def _contact(self, ctx, dt) -> int:
        """Collective: :func:`wall_contact` of the solids against the walls near them.

        The Coulomb bound of the friction follows each particle's normal contact force
        over ``solid.friction_time`` near rest and over a slip ``solid.friction_slip``
        when sliding (field ``contact_a``; friction_time 0: at once), the regularisation
        of :func:`wall_contact` (docs/loading.md). A run starts without that history: over
        its first t* the bound is the running mean of the normal force since t = 0 (a
        block launched along a rough floor at t = 0 had slid with too little friction for
        t*, 0.05 m/s faster after 0.08 s at mu = 0.5).

        The lists of the walls near each solid are Verlet lists: built with a skin of
        :data:`CONTACT_SKIN` particle spacings (:meth:`_wall_lists`) and kept while no
        solid has moved that far (:func:`contact_points_moved`); the kernel counts only
        the walls within reach, so the contact is the same as with lists built each step.
        Built each step, their search had been 0.16 of a 2D coupled step's 1 ms of fixed
        cost (``jobs/bench_overhead.py``)."""
        p, n = ctx.particles, ctx.particles.n_owned
        solid = self.sel[:n]
        lists = self._walls
        stale = lists is None or contact_points_moved(
            p["x"], solid, n, lists["rows"], lists["x0"], (CONTACT_SKIN * ctx.d) ** 2,
            lists["kept"], lists["xall"])
        if global_any(ctx.comm, stale):
            lists = self._walls = self._wall_lists(ctx, solid)
            # a solid out of the walls' reach has no contact force to remember
            far = np.ones(n, dtype=bool)
            far[lists["kept"]] = False
            p["contact_a"][:n][far] = 0.0
        count = 0
        tau = self.num.friction_time
        lag = INSTANT
        if tau > 0.0:
            # exponential weights over t*; over a run's first t*, where the filter has no
            # history yet, the running mean since t = 0 (at once in the first step)
            fresh = max(-math.expm1(-dt / tau), dt / (ctx.time + dt))
            lag = (p["contact_a"], 1.0 - fresh, dt, self.num.friction_slip)
        if len(lists["kept"]):
            count = wall_contact(lists["xall"], p["v"], lists["k"], lists["kept"],
                                 lists["wall"], lists["still"], lists["indptr"],
                                 lists["indices"], ctx.h, ctx.d, ctx.dim, lists["mu"],
                                 lists["push"], lists["mu_w"], ctx.radius ** 2, *NO_MASS,
                                 *lag)
        return global_sum(ctx.comm, count)

    def _wall_lists(self, ctx, solid) -> dict:
        """Collective: the solids' lists of the walls within ``radius`` + skin and the
        point set :func:`wall_contact` takes (:func:`solid_wall_set`)."""
        from parsph.core.cross import build_cross_csr

        p, n = ctx.particles, ctx.particles.n_owned
        reach = ctx.radius + CONTACT_SKIN * ctx.d
        near = ctx.nearby_walls(["x", "body"], around=solid, reach=reach)
        xw = near["x"]
        rows = np.flatnonzero(solid).astype(np.int64)
        lists = dict(rows=rows, x0=p["x"][:n][rows], kept=rows[:0])
        if len(xw) and len(rows):
            # the walls near each solid; only the solids with any take part (most have
            # none: the contact had cost 16 ms of a 0.48 s 3D tank step, 5 of them on rows
            # with empty lists)
            indptr, indices = build_cross_csr(lists["x0"], xw, reach)
            kept, indptr, indices, xall, wall, mu, mu_w = solid_wall_set(
                p["x"], rows, indptr, indices, xw, self.num.wall_friction,
                self.wall_friction[near["body"] - len(ctx.scene.bodies)])
            lists.update(kept=kept, indptr=indptr, indices=indices, xall=xall, wall=wall,
                         mu=mu, mu_w=mu_w, k=np.arange(len(kept)),
                         push=np.zeros((len(kept), ctx.dim)),
                         still=np.zeros_like(xall))  # fixed walls
        if not len(lists["kept"]):
            lists["xall"] = np.zeros((0, ctx.dim))
        return lists

    def _add_work(self, ctx, dt) -> None:
        """The work of the body force, the constraints and the hourglass control on the
        owned solids in this step (:func:`parsph.core.energy.step_work`) to the context's
        step total; the hourglass control has no energy function (its force leaves out
        the change of F with x), so its store is booked as the work its force did."""
        p, n, dim = ctx.particles, ctx.particles.n_owned, ctx.dim
        none = np.zeros((0, dim))
        held = none if self._impulse is None else self._impulse
        body, constraint = step_work(p["m"], self._v0, p["v"], self.sel, n, dt, self._b, held)
        hourglass = 0.0
        if self._ahg is not None:  # its impulse m dt a
            impulse = (p["m"][:n, None] * dt) * self._ahg[:, :dim]
            hourglass = step_work(p["m"], self._v0, p["v"], self.sel, n, dt, np.zeros(dim),
                                  impulse)[1]
        ctx.add_work(body, constraint, hourglass)
        self._v0 = self._impulse = self._ahg = None

    def _elastic_energy(self, ctx) -> float:
        """Collective: the stored elastic energy of the owned solids (:func:`elastic_energy`:
        Hencky and Drucker-Prager, whose elastic part is Hencky's), summed over the ranks."""
        p, n = ctx.particles, ctx.particles.n_owned
        local = elastic_energy(self.tab, p["material"], self.sel, n, self.vol, p["eps_e"])
        return global_sum(ctx.comm, local)

    def _ambient_energy(self, ctx) -> float:
        r"""Collective: :math:`p_{amb}\sum V_0 (J - 1)` over the owned solids (J, J/m in
        2D), the potential of the uniform external pressure ``solid.ambient_pressure``
        (:func:`parsph.solid.update.stress_terms`): the work the solid does against it."""
        p, n = ctx.particles, ctx.particles.n_owned
        solid = self.sel[:n]
        J = np.linalg.det(p["F"][:n][solid]) if solid.any() else np.zeros(0)
        local = self.num.ambient_pressure * float((self.vol[:n][solid] * (J - 1.0)).sum())
        return global_sum(ctx.comm, local)

    def _triaxial(self, ctx, dt) -> None:
        """Specimen averages for the drained triaxial test (docs/tlsph.md)."""
        p, n, dim = ctx.particles, ctx.particles.n_owned, ctx.dim
        solid = self.sel[:n]
        vol0 = self.vol[:n][solid]
        J = np.linalg.det(p["F"][:n][solid])
        tau = p["tau"][:n][solid]
        ax = dim - 1
        vs = 1.0 / (1.0 - p["porosity"][:n][solid])
        Fzz = p["F"][:n][solid][:, ax, ax]
        head = [vol0.sum(), (J * vol0).sum(), (vol0 * Fzz).sum(), (vol0 * vs).sum()]
        sums = np.concatenate([head, (tau * vol0[:, None, None]).sum(axis=0).ravel()])
        sums = global_sum(ctx.comm, sums)
        sigma = sums[4:].reshape(3, 3) / sums[1]
        pe = -np.trace(sigma) / 3.0
        s = sigma + pe * np.eye(3)
        q = math.sqrt(1.5 * float(np.sum(s * s)))
        mats = [m for m in ctx.materials if hasattr(m, "critical_state_ratio")]
        M = mats[0].critical_state_ratio if mats else float("nan")
        row = {"axial_strain": 1.0 - sums[2] / sums[0], "p_eff": pe, "q": q,
               "spec_volume": sums[3] / sums[0], "M": M, "sigma_axial": -sigma[ax, ax]}
        self._stats.update(row)

    def finish(self, ctx) -> None:
        """Write ``DIR/triaxial.csv`` from stats.csv at the end of a triaxial run; free the
        non-local system."""
        if self.nl_strain is not None:
            self.nl_strain.destroy()
        if "p_eff" in self.stats_columns and ctx.comm.rank == 0:
            from parsph.solid.triaxial import write_from_stats

            write_from_stats(ctx.out)

    def settle(self, ctx) -> dict | None:
        """A fresh run's geostatic stage ([geostatic], :func:`geostatic.settle`)."""
        return geostatic.settle(ctx, self, ctx)

    def stats(self) -> dict:
        return {k: self._stats.get(k, 0.0) for k in self.stats_columns}

    def state(self) -> dict:
        return {}

    def restore(self, ctx, state) -> None:
        """All state is in particle fields; recompute the derived arrays."""
        self._masks(ctx)
