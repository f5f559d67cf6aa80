r"""The geostatic stage: the soil in equilibrium under gravity before the run starts.

The paper starts its slopes stress-free with gravity acting from t = 0 (section 6.2: the
collapse *is* that loading). An earthquake analysis starts instead from the ground's
stress in equilibrium, as PLAXIS (K0 procedure, gravity loading) and the MPM codes
(quasi-static gravity loading with local damping) do; otherwise the soil settles while
the record starts, its stresses overshoot, and some of its plastic strain comes from the
start-up, not from the earthquake. ``[geostatic]`` (docs/geostatic.md):

- **K0 field** (``k0``): on the owned solid rows of the Hencky and Drucker-Prager soils,
  :math:`\sigma_v = -\rho_0 |g| (z_{top} + d/2 - z)` below the highest solid particle of
  the particle's column, :math:`\sigma_h = K_0\sigma_v` on the other axes (2D: the
  out-of-plane one too), no shear; :math:`K_0 = 1 - \sin\varphi` (Jaky 1944) for
  Drucker-Prager, :math:`\nu/(1-\nu)` (the laterally confined elastic column) for Hencky,
  or ``geostatic.k0``. With F = I the Kirchhoff stress is that Cauchy stress and the
  elastic Hencky strain is :math:`\varepsilon^e = \mathrm{tr}\,\tau/(9K)\,\mathbf I +
  \mathrm{dev}\,\tau/(2\mu)` (inverse of eq. (26)). Exact in equilibrium for level ground.
- **Gravity loading** (``gravity``): the TLSPH step (eqs. (7), (14), (20)-(27)) under
  gravity alone (no record, no phase change, the fluid held), with Cundall's local
  damping: each free velocity component's change :math:`\Delta v = \Delta t\,f/m` in a
  step becomes :math:`\Delta v - \alpha|\Delta v|\,\mathrm{sign}(v)`, until the mean
  unbalanced force :math:`\sum_i m_i|\Delta\mathbf v_i|/\Delta t` is below ``tolerance``
  of the weight :math:`\sum_i m_i|\mathbf g|` and the kinetic energy below ``tolerance``
  of its peak in the stage.
- ``k0_gravity``: the K0 field, then the gravity loading (the K0 field is the start; the
  loading makes it an equilibrium where the ground is not level).

Then the run starts at t = 0 from rest: velocities zero, stresses kept. The solid keeps
its reference configuration X (TLSPH's: the stress-free lattice) and F the stage's
deformation, consistent with the kept stress; what the run reports as deformation counts
from the settled state: the plastic strain gathered in the stage (``eps_p_geostatic``,
written to every frame) is taken off the phase change's trigger, and the windowed trigger
(:class:`parsph.solid.trigger.WindowTrigger`) fits the deformation from the settled
positions (``x_settled``), unless ``count_plastic_strain``. The softening keeps the
stage's plastic strain: the soil has softened.
"""
from __future__ import annotations

import json
import logging
import math
import os

import numpy as np

from decomposition.reduce import global_max, global_min, global_reduce, global_sum
from parsph.errors import ParsphError
from parsph.scene.materials import CamClay, DruckerPrager, Hencky
from parsph.scene.params_solid import geostatic_procedure as procedure
from parsph.solid.update import C, CAM_CLAY

log = logging.getLogger("parsph")

#: The K0 field's column grid is refused past this many columns (memory on every rank).
MAX_COLUMNS = 50_000_000


def fields(scene, window: bool) -> tuple:
    """The per-particle fields the stage adds: ``eps_p_geostatic`` (reported), and
    ``x_settled`` where a windowed trigger should count from the settled state."""
    if procedure(scene) == "none" or scene.geostatic.count_plastic_strain:
        return ()
    return ("eps_p_geostatic",) + (("x_settled",) if window else ())


def k0_of(material, k0: float) -> float:
    """K0 of a soil: the scene's ``geostatic.k0`` if given, else Jaky's 1 - sin(phi) for
    Drucker-Prager and modified Cam-Clay (phi from M), nu / (1 - nu) for Hencky."""
    if k0 > 0.0:
        return k0
    if isinstance(material, DruckerPrager):
        return 1.0 - math.sin(math.radians(material.friction_angle))
    if isinstance(material, CamClay):
        M = material.critical_state_ratio
        return 1.0 - 3.0 * M / (6.0 + M)
    if isinstance(material, Hencky):
        return material.poisson_ratio / (1.0 - material.poisson_ratio)
    return 0.0


def _columns(comm, x, sel, axes, d):
    """Column index of each row on the horizontal ``axes`` (lattice columns: spacing d from
    the lowest solid position), and the number of columns."""
    if not axes:
        return np.zeros(len(x), dtype=np.int64), 1
    lo, counts = [], []
    for a in axes:
        mine = x[sel, a]
        low = global_min(comm, float(mine.min()) if len(mine) else math.inf)
        high = global_max(comm, float(mine.max()) if len(mine) else -math.inf)
        lo.append(low)
        counts.append(int(round((high - low) / d)) + 1 if math.isfinite(low) else 1)
    total = int(np.prod(counts))
    if total > MAX_COLUMNS:
        raise ParsphError(f"geostatic K0 field: {total:,} columns of d = {d:g} m exceed "
                          f"{MAX_COLUMNS:,}; use geostatic.procedure = \"gravity\"")
    idx = [np.clip(np.rint((x[:, a] - l) / d).astype(np.int64), 0, c - 1)
           for a, l, c in zip(axes, lo, counts)]
    return np.ravel_multi_index(idx, counts), total


def apply_k0(ctx, solid, sctx) -> int:
    """Collective: the K0 stress field on the owned solid rows of Hencky and
    Drucker-Prager soils (module docstring); returns the number of rows set (all ranks)."""
    p, n, dim, d = sctx.particles, sctx.particles.n_owned, ctx.dim, ctx.d
    g = np.asarray(ctx.gravity, float)[:dim]
    axis = int(np.flatnonzero(g)[0])
    up, gn = -math.copysign(1.0, g[axis]), abs(float(g[axis]))
    material = np.maximum(p["material"][:n], 0)
    model = solid.tab[material, C["model"]]
    rows = solid.sel[:n] & (model != CAM_CLAY)
    x = p["x"][:n]
    col, total = _columns(ctx.comm, x, solid.sel[:n], [a for a in range(dim) if a != axis], d)
    height = up * x[:, axis]
    top = np.full(total, -np.inf)
    np.maximum.at(top, col[solid.sel[:n]], height[solid.sel[:n]])
    top = global_max(ctx.comm, top)
    depth = np.maximum(top[col] + 0.5 * d - height, 0.0)
    k0 = np.array([k0_of(m, ctx.scene.geostatic.k0) for m in ctx.materials] or [0.0])
    sv = -solid.rho0_of[material] * gn * depth
    tau = np.zeros((n, 3, 3))
    for a in range(3):
        tau[:, a, a] = sv if a == axis else k0[material] * sv
    K, mu = solid.tab[material, C["K"]], solid.tab[material, C["mu"]]
    mean = np.trace(tau, axis1=1, axis2=2) / 3.0
    eps = (tau - mean[:, None, None] * np.eye(3)) / (2.0 * np.where(mu > 0, mu, 1.0))[:, None, None]
    eps += (mean / (3.0 * np.where(K > 0, K, 1.0)))[:, None, None] * np.eye(3)
    p["tau"][:n][rows] = tau[rows]
    p["eps_e"][:n][rows] = eps[rows]
    p["p"][:n][rows] = -mean[rows]
    solid._stress_terms(sctx)
    return int(global_sum(ctx.comm, int(rows.sum())))


def gravity_loading(ctx, solid, sctx) -> dict:
    """Collective: the damped gravity loading (module docstring) until equilibrium.

    Raises
    ------
    ParsphError
        No equilibrium within ``geostatic.max_steps``: the slope is not stable under
        gravity alone, or it needs more steps."""
    geo = ctx.scene.geostatic
    p, n, dim, comm = sctx.particles, sctx.particles.n_owned, ctx.dim, ctx.comm
    sel = solid.sel[:n]
    act = sel[:, None] & ~solid.vmask
    m = p["m"][:n]
    gvec = np.asarray(ctx.gravity, float)[:dim]
    weight = global_sum(comm, float(m[sel].sum()) * float(np.linalg.norm(gvec)))
    peak, ratio, ke, t = 0.0, math.inf, 0.0, 0.0
    sctx.time = 0.0
    for step in range(1, geo.max_steps + 1):
        dt = solid.max_dt(sctx)
        solid.predict(sctx, dt, body=gvec)
        v = p["v"]
        dv = np.where(act, v[:n] - solid._v0, 0.0)
        v[:n] -= geo.damping * np.abs(dv) * np.sign(solid._v0) * act
        unbalanced = float((m * np.sqrt((dv * dv).sum(axis=1)))[sel].sum()) / dt
        solid.finish_step(sctx, dt, stats=False)
        kin = 0.5 * float((m[sel] * (v[:n][sel] ** 2).sum(axis=1)).sum())
        unbalanced, ke = global_sum(comm, np.array([unbalanced, kin]))
        ratio = unbalanced / weight if weight > 0 else 0.0
        peak = max(peak, ke)
        t += dt
        if ratio < geo.tolerance and ke <= geo.tolerance * peak:
            return {"steps": step, "time_s": t, "unbalanced_force_ratio": ratio,
                    "kinetic_energy_ratio": ke / peak if peak > 0 else 0.0}
    raise ParsphError(
        f"geostatic stage: no equilibrium after {geo.max_steps} steps ({t:.4g} s): the mean "
        f"unbalanced force is {ratio:.3g} of the weight, the kinetic energy {ke / max(peak, 1e-300):.3g} "
        f"of its peak (tolerance {geo.tolerance:g}). The slope is not stable under gravity alone "
        f"(it would fail without the earthquake), or the stage needs more steps: raise "
        f"geostatic.max_steps, or start stress-free with geostatic.procedure = \"none\"")


def settle(ctx, solid, sctx, coupled=None) -> dict | None:
    """Collective, a fresh run's start: the scene's geostatic procedure on the TLSPH stage
    ``solid`` acting on ``sctx`` (the run's context, or the solid view's of the
    ``coupled`` stage); returns the report (also logged and written to
    ``DIR/geostatic.json``), None without one. The driver refreshes the main set
    afterwards."""
    chosen = procedure(ctx.scene)
    if chosen == "none":
        return None
    if coupled is not None:
        coupled.view.locate()
        coupled.view.sync(("x", "v"))
    p, n = sctx.particles, sctx.particles.n_owned
    sel = solid.sel[:n]
    x0 = p["x"][:n].copy()
    report = {"procedure": chosen}
    if "k0" in chosen:
        report["k0_rows"] = apply_k0(ctx, solid, sctx)
        report["k0"] = {name: k0_of(m, ctx.scene.geostatic.k0)
                        for name, m in ctx.scene.materials.items() if "tlsph" in m.stages}
    if "gravity" in chosen:
        report.update(gravity_loading(ctx, solid, sctx))
    eps = p["eps_p"][:n][sel]
    move = np.sqrt(((p["x"][:n] - x0) ** 2).sum(axis=1))[sel]
    (yielded, ), (eps_max, move_max), _ = global_reduce(
        ctx.comm, sums=(int((eps > 0).sum()),), maxs=(
            float(eps.max()) if len(eps) else 0.0, float(move.max()) if len(move) else 0.0))
    report.update(plastic_rows=int(yielded), eps_p_max=eps_max, displacement_max_m=move_max,
                  elastic_energy=solid._elastic_energy(sctx),
                  counted=bool(ctx.scene.geostatic.count_plastic_strain))
    if "eps_p_geostatic" in p:
        p["eps_p_geostatic"][:n] = np.where(sel, p["eps_p"][:n], 0.0)
    if "x_settled" in p:
        p["x_settled"][:n] = p["x"][:n]
    p["v"][:n][sel] = 0.0
    solid.constrain(sctx)
    solid._impulse = None
    ctx.work[:] = 0.0
    if coupled is not None:
        coupled.view.write_back(coupled.solid_state
                                + fields(ctx.scene, coupled.window is not None))
        if coupled.window is not None:
            coupled.window.build(sctx, solid.sel)
    _log(ctx, report)
    return report


def _log(ctx, report) -> None:
    if ctx.comm.rank != 0:
        return
    text = f"geostatic stage ({report['procedure']})"
    if "steps" in report:
        text += (f": equilibrium after {report['steps']} steps ({report['time_s']:.3g} s), "
                 f"unbalanced force {report['unbalanced_force_ratio']:.2g} of the weight")
    text += (f"; {report['plastic_rows']} rows yielded (largest eps_p {report['eps_p_max']:.3g}, "
             f"{'counted' if report['counted'] else 'not counted'} toward the phase change), "
             f"largest displacement {report['displacement_max_m']:.3g} m")
    log.info(text)
    with open(os.path.join(ctx.out, "geostatic.json"), "w") as fh:
        json.dump(report, fh, indent=1)
