r"""The coupled step: TLSPH solid and IISPH fluid as one FSI problem, and phase change.

One step (paper section 5, eqs. (42)-(48); docs/coupling.md), after the driver's refresh
of the main set (mixed layout):

1. TLSPH predictor on the solid view: :math:`\mathbf v^{pred} = \mathbf v^\beta + \Delta t
   (\nabla_0\cdot\mathbf P/\rho_0 + \mathbf g)` (eq. (7)), constraints, wall contact;
2. if there is fluid anywhere: the IISPH step on the main set with the solid rows in
   it — type-II solids (fluid neighbours) are unknowns of the viscous predictor
   (eq. (47), right-hand side :math:`\mathbf v^{pred}`) and of the PPE, strongly
   coupled: the fluid's divergence sees their velocity after the pressure has acted on
   their true mass, and their own row is the no-penetration of their fluid neighbours
   (:mod:`parsph.fluid.response`); their velocity then gets that reaction
   (eqs. (45), (48)); type-I solids stay out;
3. TLSPH corrector on the view: :math:`\dot{\mathbf F}` from the final velocities,
   constitutive update, positions;
4. phase change (section 3.3): owned solid rows with :math:`\varepsilon_p` past
   ``phase_change.eps_p_limit`` (or whose F would have inverted in this step, left
   un-updated, with ``phase_change.fluidise_failed``) become fluid rows of ``phase_change.fluid`` (id, x, v, m
   kept: mass, momentum and ids are conserved); the solid view (reference halo and
   lists, correction matrices) is rebuilt on every rank; the next refresh moves the new
   fluid rows to their owner by current position.
"""
from __future__ import annotations

import math
import time

import numpy as np

from decomposition.reduce import allgather, global_max, global_reduce, global_sum
from parsph.coupling.view import VIEW_FIELDS, SolidView
from parsph.core.particles import max_speed
from parsph.scene.materials import PHASE_FLUID, PHASE_SOLID

#: Fields the TLSPH step changes on solid rows (copied back to the main set each step).
#: (``rho0`` and ``rho`` of solid rows in the main set are what the fluid sees; the
#: solid's own rest density lives in the view.)
SOLID_STATE = ("x", "v", "p_c", "modulus", "solid_init", "eps_p", "p", "porosity",
               "contact_a")
#: The regularised soils' non-local strains (:mod:`parsph.solid.regularise`), where a
#: scene has them: solid state too.
NONLOCAL_STATE = ("eps_p_nl", "eps_p_shift")

#: The solid's tensors, which only the TLSPH step reads: held by the view alone, and put
#: back in the main set (:meth:`Coupled.state_to_main`) only for a checkpoint, a probe
#: sample, or while the solids migrate to a new partition. In the main set they cost
#: 240 bytes on every row of every phase in 3D, and their copy back each step a pass
#: over them (docs/performance.md).
VIEW_STATE = ("F", "tau", "eps_e", "lapv")

#: Fields of the main set the solid's view does without: the fluid stage's and the
#: coupling's own (the fluid's force on a solid is read from the main set). Copied into
#: the view they had cost 160 bytes per solid particle.
MAIN_ONLY = ("nu", "v_star", "v_ghost", "free_surface", "wall_slip", "fluid_row", "p_ppe",
             "ppe_band", "fluidised", "inv_mass", "a_self", "fsi_force")

#: Fields of the main set no stage reads on its current-configuration halo rows: the
#: solid's state (the TLSPH step reads it in the view, on the view's reference halo) and
#: the coupling's per-row flags; with the tensors (in the main set while the solids
#: migrate) 375 of a 3D row's 613 bytes, which had been 40 % of the 2-rank halo
#: exchange's time (docs/performance.md).
HALO_SKIP = VIEW_STATE + ("X", "eps_p", "p_c", "porosity", "modulus", "ref_count0",
                          "contact_a", "solid_init", "fluidised", "ppe_band",
                          "eps_p_geostatic", "x_settled") + NONLOCAL_STATE \
    + ("eps_trigger", "trigger_time", "trigger_rate", "trigger_reach")

#: stats.csv columns of the coupling; ``fsi_force_*`` (N, N/m in 2D) is the net force of
#: the fluid on the solid (eq. (45), pressure and viscous parts) before constraints.
STATS = ("solid_substeps", "n_fluidised", "n_failed", "fluidised_volume", "n_solid_rank_min", "n_solid_rank_max",
         "n_fluid_rank_min", "n_fluid_rank_max", "wall_s_solid", "wall_s_fluid",
         "wall_s_phase_change")


class Coupled:
    """TLSPH + IISPH + phase change on one particle set (see the module docstring)."""

    name = "coupled"

    def __init__(self, ctx):
        from parsph.fluid.stage import IISPH, lattice_density_ratio
        from parsph.solid import geostatic
        from parsph.solid.stage import TLSPH

        self.solid = TLSPH(ctx)  # adds the solid fields to the main set
        self.window = self._window(ctx)
        if "x_settled" in geostatic.fields(ctx.scene, self.window is not None):
            ctx.particles.add_field("x_settled", (ctx.dim,))  # the windowed trigger's start
        self.solid_state = SOLID_STATE + tuple(k for k in NONLOCAL_STATE if k in ctx.particles) \
            + (self.window.FIELDS if self.window is not None else ())
        for name in VIEW_FIELDS:  # but these live in the solid's view only
            ctx.particles.data.pop(name, None)
        self.fluid = IISPH(ctx)  # adds the fluid fields
        # the solid's predictor runs between the fluid's steps: its scratch in the memory of
        # the fluid's matrices, idle then
        self.solid.scratch = self.fluid.buffers.idle
        ctx.particles.add_field("fluidised", dtype=np.uint8)
        ctx.particles.add_field("ref_count0", dtype=np.int32)  # initial reference neighbours
        # the fluid's force on each solid particle in the last coupled step (N, N/m in 2D):
        # the solid's sub-steps feel it (lagged), see step()
        ctx.particles.add_field("fsi_force", (ctx.dim,))
        pc = ctx.scene.phase_change
        names = list(ctx.scene.materials)
        self.limit = pc.eps_p_limit
        self.min_support = pc.min_support
        self.solid.failure_fluidises = self.limit > 0.0 and pc.fluidise_failed
        self.target = names.index(pc.fluid) if pc.fluid else -1
        fluids = [m for m in ctx.materials if "iisph" in m.stages]
        # the density the fluid sees solid particles with (one fluid density per scene:
        # the phase-change target's, else the first fluid material's)
        self.rho_f = ctx.materials[self.target].density if self.target >= 0 \
            else fluids[0].density
        self.target_rho0 = self.rho_f * lattice_density_ratio(ctx.h / ctx.d, ctx.dim)
        self.output_fields = tuple(self.fluid.output_fields) + ("fluidised",) \
            + tuple(self.solid.output_fields) + (("eps_trigger",) if self.window else ())
        self.stats_columns = tuple(self.solid.stats_columns) + tuple(self.fluid.stats_columns) \
            + ("n_coupled",) + STATS + tuple(f"fsi_force_{a}" for a in "xyz"[:ctx.dim])
        ctx.halo_skip = HALO_SKIP
        ctx.fields_outside, ctx.outside_names = self.state_to_main, VIEW_STATE
        self.view = None
        self._stats = {k: 0.0 for k in STATS}
        self._stats["n_fluidised"] = 0  # a count, as restored from a checkpoint
        self._fluid_any = False
        self._dt_solid = math.inf

    # -- set-up ------------------------------------------------------------------
    def _window(self, ctx):
        """The regularised trigger (:class:`parsph.solid.trigger.WindowTrigger`) if
        some soil that changes phase has an internal length, else None; adds the
        ``eps_trigger`` field (written to every frame)."""
        from parsph.solid.trigger import WINDOW_IN_ELL, WindowTrigger
        from parsph.solid.update import C as COL, CAM_CLAY

        if ctx.scene.phase_change.eps_p_limit <= 0.0:
            return None
        ell = [m.internal_length if getattr(m, "regularised", False) else 0.0
               for m in ctx.materials]
        if not any(ell):
            return None
        tab = self.solid.tab
        factor = [1.0 / math.sqrt(3.0) if int(tab[k, COL["model"]]) == CAM_CLAY
                  else tab[k, COL["xi"]] for k in range(len(ctx.materials))]
        window = WindowTrigger(ctx.comm, [WINDOW_IN_ELL * e for e in ell], factor)
        for name in window.FIELDS:
            ctx.particles.add_field(name, fill=window.FILL.get(name, 0.0))
        return window

    def _build_view(self, ctx, edit=False, left=None) -> None:
        """The solid's view of the owned solid rows: its state from the main set, the
        tensors of :data:`VIEW_STATE` from the last view where the main set has them not
        (then they leave the main set). ``edit``: the last view less the rows a phase
        change took out of the solid, its halo and lists edited rather than built
        (:meth:`SolidView.without_fluidised`; the same view)."""
        if edit:
            self.view = self.view.without_fluidised(MAIN_ONLY, VIEW_STATE)
        else:
            self.view = SolidView(ctx, MAIN_ONLY, VIEW_STATE, self.view)
        sp, ns = self.view.ctx.particles, self.view.n
        count = np.diff(self.view.ctx.indptr).astype(np.int32)
        first = sp["ref_count0"][:ns] == 0
        sp["ref_count0"][:ns][first] = count[first]
        self.solid.setup(self.view.ctx, self.view.edit)
        if self.window is not None:
            self.window.build(self.view.ctx, self.solid.sel)
            if left is not None:  # the windows that lost targets (WindowTrigger)
                self.window.targets_left(self.view.ctx, left)
        self.view.write_back(self.solid_state + ("ref_count0",))
        for name in VIEW_STATE:
            ctx.particles.data.pop(name, None)

    def state_to_main(self, names=None) -> tuple:
        """Put the tensors of :data:`VIEW_STATE` (those ``names``) back in the main set (the
        view's values on the owned solid rows; ``Context.fields_outside``); returns the
        names put back. The next view build takes them out again."""
        names = VIEW_STATE if names is None else tuple(k for k in names if k in VIEW_STATE)
        return self.view.state_to(names) if self.view is not None else ()

    def _orphans(self) -> np.ndarray:
        """Main-set rows of the solids left with too small a share of their reference
        neighbours (a gap of the paper filled: such a fragment cannot carry stress)."""
        view = self.view
        count = np.diff(view.ctx.indptr)
        ref0 = view.ctx.particles["ref_count0"][: view.n]
        return view.rows[count < self.min_support * ref0]

    def setup(self, ctx) -> None:
        self._build_view(ctx)
        p, n = ctx.particles, ctx.n_owned
        solid = p["phase"][:n] == PHASE_SOLID
        p["rho0"][:n][solid] = self.target_rho0  # as the fluid sees them
        p["rho"][:n][solid] = self.target_rho0
        # the halo copies were made before: the first coupled step's fluid sees them too
        # (with the solid's own rho0 there, fluid rows by the rank cut were flagged free
        # surface in the first step, and 1 and 2 ranks differed)
        if ctx.halo is not None:
            ctx.update_halo(["rho0", "rho"])
        self._count(ctx)

    def _coupling(self, ctx, inv_mass):
        """Masses as the fluid sees them: a solid particle counts as d^dim of fluid."""
        from parsph.fluid.stage import Coupling

        p = ctx.particles
        solid = p["phase"] == PHASE_SOLID
        m_fluid = self.rho_f * ctx.d ** ctx.dim
        mass = np.where(solid, m_fluid, p["m"])
        scale = np.where(solid, m_fluid / p["m"], 0.0)
        return Coupling(inv_mass=inv_mass, mass=mass, scale=scale)

    def restore(self, ctx, state) -> None:
        self.solid.restore(self.view.ctx, state.get("solid", {}))
        self._stats["n_fluidised"] = int(state.get("n_fluidised", 0))
        self._stats["n_failed"] = int(state.get("n_failed", 0))

    def renew_preconditioners(self) -> None:
        """At a sync point (see :func:`parsph.step.run.run`): the fluid's next solves set up afresh."""
        self.fluid.renew_preconditioners()

    def state(self) -> dict:
        return {"n_fluidised": int(self._stats["n_fluidised"]),
                "n_failed": int(self._stats["n_failed"])}

    def _count(self, ctx) -> None:
        p = ctx.particles
        self._fluid_any = global_sum(ctx.comm, int((p["phase"][: p.n_owned] == PHASE_FLUID)
                                                   .sum())) > 0

    # -- protocol ----------------------------------------------------------------
    def max_dt(self, ctx) -> float:
        """Eq. (49). Without fluid: the solid's limit. With fluid: the fluid's limit, which
        the solid's speed bounds too (``fluid.cfl d / |v|``), but at most
        ``solid.max_substeps`` times the solid's own limit (its wave speed), which the
        solid then meets by sub-steps (:meth:`step`)."""
        self.view.locate()
        self._dt_solid = self.solid.max_dt(self.view.ctx)
        if not self._fluid_any:
            return self._dt_solid
        dt = self.fluid.max_dt(ctx)
        vmax = global_max(ctx.comm, max_speed(self.view.ctx.particles["v"], self.view.n))
        if vmax > 0.0:
            dt = min(dt, self.fluid.num.cfl * ctx.d / vmax)
        return min(dt, ctx.scene.solid.max_substeps * self._dt_solid)

    def substeps(self, dt) -> int:
        """Solid sub-steps in a coupled step of ``dt``: the TLSPH stage keeps its own CFL
        limit (the wave speed, eq. (49)), the fluid takes the step its own limit allows."""
        if not self._fluid_any or dt <= self._dt_solid:
            return 1
        return int(math.ceil(dt / self._dt_solid * (1.0 - 1e-12)))

    def step(self, ctx, dt) -> None:
        r"""One coupled step of ``dt`` (module docstring), with ``k`` solid sub-steps of
        ``dt / k`` (:meth:`substeps`).

        Notes
        -----
        Sub-steps (multiple time stepping: the structure is explicit and stiffer than the
        fluid). The first ``k - 1`` are whole TLSPH steps in which the solid also feels
        the fluid's force of the last coupled step (``fsi_force``, pressure and viscous);
        the last one predicts the velocity, from which that lagged impulse
        :math:`\Delta t\,\mathbf f/m` is taken out again, so the fluid step (viscous
        predictor and strongly coupled PPE, at the positions of the start of the step,
        for which the neighbour lists were built) applies this step's whole fluid impulse;
        the last sub-step then finishes with the final velocity. With ``k = 1`` this is
        the plain coupled step: TLSPH predictor, fluid step, TLSPH corrector. Stepping the
        solid a second time from the start of the step with this step's fluid force
        instead of the lagged one changed nothing measurable (``elastic_gate``: the free
        end within 0.1 mm to 0.12 s) at twice the solid's cost.
        """
        p, n, dim = ctx.particles, ctx.n_owned, ctx.dim
        view = self.view
        sctx = view.ctx
        sctx.step = ctx.step
        t0 = time.perf_counter()
        view.locate()
        view.sync(("x", "v"))
        ns = view.n
        sp = sctx.particles
        k = self.substeps(dt)
        sub = dt / k
        free = ~self.solid.vmask
        extra = None
        failed = []
        cp = self.solid.max_wave_speed(sctx)  # of the JST term, once per coupled step
        if k > 1:  # the fluid's force of the last step, per unit true mass, not on held axes
            extra = np.where(free, p["fsi_force"][view.rows] / sp["m"][:ns, None], 0.0)
            for j in range(k - 1):
                sctx.time = ctx.time + j * sub
                self.solid.predict(sctx, sub, extra, cp)
                self.solid.finish_step(sctx, sub, stats=False)
                failed.append(self.solid.failed)
        sctx.time = ctx.time + (k - 1) * sub
        self.solid.predict(sctx, sub, extra, cp)
        if extra is not None:
            sp["v"][:ns] -= dt * extra
        t_solid = time.perf_counter() - t0
        t_fluid = 0.0
        fsi = np.zeros((ns, dim))
        if self._fluid_any:
            t0 = time.perf_counter()
            p["v"][view.rows] = sp["v"][:ns]
            # the solids' inverse true masses, zero on the components a constraint holds:
            # their response to the pressure in the strongly coupled PPE
            inv = np.zeros((n, dim))
            inv[view.rows] = np.where(free, 1.0 / sp["m"][:ns, None], 0.0)
            ctx.update_halo(["v"])
            self.fluid.step(ctx, dt, self._coupling(ctx, inv))
            # the fluid's force on each solid particle (eq. (45)) before constraints: the
            # pressure's and the viscous exchange of the viscous solve (47)
            fsi = self.fluid.solid_force[view.rows]
            if len(self.fluid.solid_viscous_dv):
                fsi = fsi + sp["m"][:ns, None] * self.fluid.solid_viscous_dv[view.rows] / dt
            p["fsi_force"][view.rows] = fsi
            sp["v"][:ns] = p["v"][view.rows]
            self.solid.constrain(sctx)
            t_fluid = time.perf_counter() - t0
        force = global_sum(ctx.comm, fsi.sum(axis=0))
        self._stats.update({f"fsi_force_{a}": float(force[c]) for c, a in enumerate("xyz"[:dim])})
        t0 = time.perf_counter()
        self.solid.finish_step(sctx, sub)
        failed.append(self.solid.failed)
        # a particle that failed in any sub-step has failed in the step
        self.solid.failed = np.unique(np.concatenate(failed)) if k > 1 else failed[0]
        view.write_back(self.solid_state)
        t_solid += time.perf_counter() - t0
        t0 = time.perf_counter()
        self._phase_change(ctx, dt)
        self._stats.update(wall_s_solid=t_solid, wall_s_fluid=t_fluid, solid_substeps=k,
                           wall_s_phase_change=time.perf_counter() - t0)

    def _trigger_strain(self, ctx, dt) -> np.ndarray:
        """The main set's owned rows' strain the phase change compares with its limit: the
        window strain of the regularised soils (:class:`parsph.solid.regularise.
        WindowTrigger`), the accumulated plastic strain of the others (section 3.3)."""
        p, n = ctx.particles, ctx.n_owned
        if self.window is None:  # less the geostatic stage's (docs/geostatic.md)
            return p["eps_p"][:n] - (p["eps_p_geostatic"][:n] if "eps_p_geostatic" in p else 0.0)
        view = self.view
        value = np.zeros(view.n)
        self.window.strain(view.ctx, self.limit, ctx.time, dt, value)
        view.write_back(self.window.FIELDS)
        out = np.zeros(n)
        out[view.rows] = value
        return out

    def _phase_change(self, ctx, dt) -> None:
        """Section 3.3: solid rows past the plastic-strain limit become fluid."""
        p, n = ctx.particles, ctx.n_owned
        if self.limit > 0.0:
            past = (p["phase"][:n] == PHASE_SOLID) & (self._trigger_strain(ctx, dt) > self.limit)
            failed = self.view.rows[self.solid.failed]  # det F <= 0: it has failed
            past[failed] = True
            flag = np.flatnonzero(past)
            # one reduction for both counts (a coupled step's hot path)
            count, n_failed = (int(c) for c in global_sum(
                ctx.comm, np.array([len(flag), len(failed)], dtype=np.int64)))
            self._stats["n_failed"] = int(self._stats["n_failed"]) + n_failed
            while count:  # then the fragments they leave behind, until none is left
                p["phase"][flag] = PHASE_FLUID
                p["material"][flag] = self.target
                p["fluidised"][flag] = 1
                p["rho0"][flag] = self.target_rho0
                p["rho"][flag] = self.target_rho0
                p["nu"][flag] = 0.0
                p["wall_slip"][flag] = 0
                self._stats["n_fluidised"] = int(self._stats["n_fluidised"]) + int(count)
                # reference halo and lists without them
                left = None
                if self.window is not None:
                    ref = p["x_settled"] if "x_settled" in p else p["X"]
                    left = np.concatenate(allgather(ctx.comm, ref[flag]))
                self._build_view(ctx, edit=True, left=left)
                flag = self._orphans()
                count = global_sum(ctx.comm, len(flag))
        self._count(ctx)

    def settle(self, ctx) -> dict | None:
        """A fresh run's geostatic stage on the solid view (:mod:`parsph.solid.geostatic`;
        the fluid is held)."""
        from parsph.solid.geostatic import settle

        return settle(ctx, self.solid, self.view.ctx, self)

    def stats(self) -> dict:
        ctx_stats = dict(self._stats)
        ctx_stats.update(self.solid.stats())
        if self._fluid_any:
            ctx_stats.update(self.fluid.stats())
        return {k: ctx_stats.get(k, 0.0) for k in self.stats_columns}

    def after_refresh(self, ctx) -> None:
        """Per-rank counts and the fluidised volume, after the re-distribution; the solid
        view again if the solids were re-partitioned (their state is in the main set)."""
        if ctx.solids_moved and self.view is not None:
            self._build_view(ctx)
        ctx.solids_moved = False
        p, n, comm = ctx.particles, ctx.n_owned, ctx.comm
        phase = p["phase"][:n]
        ns, nf = int((phase == PHASE_SOLID).sum()), int((phase == PHASE_FLUID).sum())
        mine = p["fluidised"][:n] == 1
        vol = float((p["m"][:n][mine] / self.target_rho0).sum()) if mine.any() else 0.0
        (vol,), (ns_max, nf_max), (ns_min, nf_min) = global_reduce(
            comm, sums=(vol,), maxs=(ns, nf), mins=(ns, nf))
        self._stats.update(
            n_solid_rank_min=int(ns_min), n_solid_rank_max=int(ns_max),
            n_fluid_rank_min=int(nf_min), n_fluid_rank_max=int(nf_max), fluidised_volume=vol)

    def finish(self, ctx) -> None:
        self.solid.finish(self.view.ctx if self.view is not None else ctx)
        self.fluid.destroy()
