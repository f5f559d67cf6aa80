"""After each step: the state checked, particles migrated to their owners (the partition
rebuilt when unbalanced), the halo and the neighbour lists rebuilt."""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from decomposition import raise_if_any
from decomposition.exchange import migrate
from decomposition.coupled import coupled_halo
from decomposition.halo import Halo
from decomposition.partition import RCB, imbalance
from decomposition.reduce import global_any, global_reduce
from decomposition.box import masked_bounds
from parsph.core.neighbours import build_csr
from parsph.core.particles import PHASE_FLUID, PHASE_SOLID, PHASE_WALL
from parsph.errors import NumericalError


def timed(ctx, name, fn, *args):
    t0 = time.perf_counter()
    result = fn(*args)
    ctx.timers[name] = ctx.timers.get(name, 0.0) + time.perf_counter() - t0
    return result


@njit(cache=True, error_model="numpy")
def _first_non_finite(x, v, n):
    """``(kind, i)``: the first of the first ``n`` rows with a non-finite position (kind
    1), else with a non-finite velocity (2); ``(0, 0)`` if none. One pass each, no
    temporaries: with the box test (:meth:`decomposition.box.Box.first_outside`) the
    numpy form had cost 57 us of a 2D coupled step of 1,100 particles
    (jobs/bench_overhead.py)."""
    for name in range(2):
        a = x if name == 0 else v
        for i in range(n):
            for k in range(a.shape[1]):
                if not np.isfinite(a[i, k]):
                    return name + 1, i
    return 0, 0


def check_state(ctx) -> None:
    """Collective: stop every rank with one message on NaN/inf or a particle out of the box."""
    p = ctx.particles
    n = p.n_owned
    kind, i = _first_non_finite(p["x"], p["v"], n)
    if kind == 0:
        i = ctx.box.first_outside(p["x"][:n])
        kind = 3 if i >= 0 else 0
    error = None
    if kind in (1, 2):
        error = NumericalError(
            f"non-finite {'x' if kind == 1 else 'v'} of particle id {int(p['id'][i])} at step "
            f"{ctx.step}, t = {ctx.time:.6g} s (rank {ctx.comm.rank}); the last good frame and "
            f"stats are kept; try a smaller time step (run.cfl or run.dt)")
    elif kind == 3:
        error = NumericalError(
            f"particle id {int(p['id'][i])} left the domain at step {ctx.step}, "
            f"t = {ctx.time:.6g} s, x = {np.array2string(p['x'][i], precision=4)} "
            f"(rank {ctx.comm.rank}); enlarge domain.lo/domain.hi or check the walls")
    raise_if_any(ctx.comm, error)


#: Work of a wall particle relative to a fluid or solid one, for the partition. A wall
#: row is binned and has a neighbour list, but it is no unknown of the PPE or viscous
#: systems and no TLSPH row; the kernels only extrapolate its pressure and velocity.
#: Counting walls as whole particles gave the rank with the dam-break column 1.3 % more
#: PPE rows than the mean (docs/scaling.md).
WALL_WORK = 0.25


def _work(phase) -> np.ndarray:
    """Partition weight of each row (1, or :data:`WALL_WORK` for walls)."""
    return np.where(phase == PHASE_WALL, WALL_WORK, 1.0)


def _unbalanced(counts, tolerance: float) -> bool:
    """The largest of the ranks' ``counts`` exceeds ``tolerance`` times their mean, by at
    least one row (3 rows on 2 ranks are as balanced as they can be)."""
    total, largest = int(counts.sum()), int(counts.max())
    return largest * len(counts) > tolerance * total and largest - total / len(counts) >= 1.0


def _distribute(ctx, force: bool = False) -> None:
    """Migrate particles to their owners; rebuild the partition when unbalanced.

    The partition follows ``ctx.key``: current positions ``x`` (fluids: particles
    migrate as they move), or reference positions ``X`` (TLSPH solids: ownership, halo
    and neighbour lists are fixed for the whole run). It balances work, not particles:
    walls weigh :data:`WALL_WORK`. In the mixed layout (coupled scenes) each kind has a
    partition of its own: the solids by ``X``, the walls and the fluid by ``x``; the
    solids' and the fluid's are re-partitioned when their counts exceed
    ``run.rebalance_tolerance`` times the mean (docs/decomposition.md).
    """
    p, comm, key = ctx.particles, ctx.comm, ctx.key
    if (_alone(ctx) and not force and ctx.rcb is not None
            and (ctx.layout != "mixed" or ctx.rcb_ref is not None)):
        # one rank without images: every row stays and is never wrapped (a 2D coupled
        # step of 262 particles spent 0.15 of its 2.4 ms finding that out); only a
        # halo, if one was added, is dropped
        if p.n_halo:
            p.set_owned(p.owned_fields())
        return
    owned = p.owned_fields()
    if ctx.box.periodic and any(ctx.box.periodic):
        # a TLSPH solid keeps its unwrapped x, continuous with its reference X (its
        # neighbours across the boundary are images, shifted in x and X alike)
        keep = owned["phase"] == PHASE_SOLID if ctx.layout != "current" else None
        wrapped = ctx.box.wrap(owned["x"])
        owned["x"] = wrapped if keep is None else np.where(keep[:, None], owned["x"], wrapped)
    tolerance = ctx.scene.run.rebalance_tolerance
    if ctx.layout == "mixed":  # solids by X, walls and fluid by x, each balanced on its own
        phase, x = owned["phase"], owned["x"]
        solid, wall = phase == PHASE_SOLID, phase == PHASE_WALL
        fluid = ~solid & ~wall
        # the walls do not move: a partition of their own, built once, balancing them
        # alone. One partition for walls and fluid balanced their summed work, not the
        # fluid: the former aso_like at d = 4 m had 6 and 1,684 fluid rows on its 2 ranks
        # (docs/decomposition.md)
        if force or ctx.rcb_wall is None:
            ctx.rcb_wall = RCB.build(comm, x[wall], ctx.box)
        # per rank, in one reduction: the solids it owns, the fluid rows it would own
        # under the present cuts (those that fluidised in the last step are still on the
        # rank that held them as solids), and the fluid's bounding box
        counts = np.zeros((2, comm.size))
        counts[0, comm.rank] = solid.sum()
        xf = x[fluid]
        to = None if ctx.rcb is None else ctx.rcb.owner(xf)
        if to is None:
            counts[1, comm.rank] = fluid.sum()
        else:
            counts[1] = np.bincount(to, minlength=comm.size)
        # (inf, -inf where none; numpy's reductions along axis 0 took 1 ms per step of
        # the 3D tank of jobs/bench_memory.py on 2 ranks)
        lo, hi = masked_bounds(x, fluid)
        sums, hi, lo = global_reduce(comm, counts.ravel(), hi, lo)
        counts = np.asarray(sums).reshape(2, comm.size).astype(np.int64)
        # the solids' partition is fixed by X, but the phase change empties the ranks
        # that hold the failing toe: rebuilt when their counts drift past the tolerance
        if force or ctx.rcb_ref is None or _unbalanced(counts[0], tolerance):
            ctx.solids_moved = ctx.rcb_ref is not None
            ctx.rcb_ref = RCB.build(comm, owned["X"][solid], ctx.box)
            if ctx.solids_moved and ctx.fields_outside is not None:
                # the state a stage holds outside the set migrates with its rows (the
                # stage's next view takes it from the set)
                owned.update(p.owned_fields(ctx.fields_outside()))
        n_fluid = int(counts[1].sum())
        rebuilt = force or to is None or (n_fluid and _unbalanced(counts[1], tolerance))
        if rebuilt:
            # before any soil fluidises: the walls' cuts (a fluid row's owner is defined)
            ctx.rcb = RCB.build(comm, xf, ctx.box) if n_fluid else ctx.rcb_wall
            to = ctx.rcb.owner(xf)
        dest = np.empty(len(phase), dtype=np.int32)
        if ctx.solids_placed is ctx.rcb_ref and not force:
            # X does not change: every solid is on its owner since it was placed under
            # these cuts (the owner of each solid had cost 0.45 ms per step of the 3D
            # tank of jobs/bench_memory.py on 2 ranks)
            dest[solid] = comm.rank
        else:
            dest[solid] = ctx.rcb_ref.owner(owned["X"][solid])
            ctx.solids_placed = ctx.rcb_ref
        # the halo follows the rows' boxes (coupled_halo), so any owner is correct: between
        # sync steps strays stay, and so do the walls
        if not rebuilt and _lazy(ctx) and _keep_strays(ctx, xf, to):
            dest[wall] = comm.rank
        else:
            dest[wall] = _wall_owner(ctx, x[wall], np.asarray(lo), np.asarray(hi))
        dest[fluid] = to
        # the walls after the rest, as the fluid's systems number them: each rank's rows
        # in the systems then ascend with the index, and so do its neighbours' in the
        # halo, and a list is sorted by row as built (solvers.csr.sort_neighbours_by_row)
        p.set_owned(migrate(comm, owned, dest, last=wall))
        return
    work = _work(owned["phase"])
    rebuilt = force or ctx.rcb is None or imbalance(comm, float(work.sum())) > tolerance
    if rebuilt:
        ctx.rcb = RCB.build(comm, owned[key], ctx.box, weights=work)
    dest = ctx.rcb.owner(owned[key])
    if not rebuilt and _lazy(ctx):
        _keep_strays(ctx, owned[key], dest)
    # the walls after the rest, as the fluid's systems number them (parsph.fluid.stage)
    p.set_owned(migrate(comm, owned, dest, last=owned["phase"] == PHASE_WALL))


def _alone(ctx) -> bool:
    """One rank without periodic images: no row ever changes rank or has a halo copy."""
    return ctx.comm.size == 1 and not ctx.box.any_periodic


def _lazy(ctx) -> bool:
    """Whether this step's migration may leave strays where they are (not a sync step)."""
    return ctx.skin > 0 and not ctx.sync_point and bool(ctx.step % ctx.migrate_every)


def _wall_owner(ctx, x, lo, hi) -> np.ndarray:
    """Owner of each wall row: the fluid's partition within ``2 ctx.radius`` of the
    fluid's bounding box ``[lo, hi]`` (a wet wall is owned with the fluid it bounds), the
    walls' own partition elsewhere.

    A wall row of the PPE and of the viscous system only extrapolates its fluid
    neighbours (Adami et al. 2012). Owned by another rank than they are, its O(1)
    couplings cross the ranks, where BoomerAMG's smoothing and coarsening see them
    weakly: the 3D tank of ``jobs/bench_memory.py`` (its water on 2 ranks, its floor cut
    by the walls' partition) took 11 PPE iterations on 2 ranks and 8 on one, the
    viscous solve 5 and 4; with the walls under the fluid's cuts, 8 and 4 on both. The
    box and the cuts depend only on the global state, so a restart owns alike."""
    near = np.all((x >= lo - 2 * ctx.radius) & (x <= hi + 2 * ctx.radius), axis=1)
    owner = ctx.rcb_wall.owner(x)
    if near.any():
        owner[near] = ctx.rcb.owner(x[near])
    return owner


def _keep_strays(ctx, x, dest) -> bool:
    """Collective: lagged migration. Rows that left their rank's sub-box stay (``dest`` is
    set to this rank) while every stray on every rank is within ``ctx.skin`` of its
    owner's sub-box (True), else changes nothing (False). In the current layout the
    halo is ``ctx.skin`` wider, so every neighbour within 2h of a stray still reaches it;
    the coupled halo follows the rows' boxes. Unchanged rows keep the PPE's AMG set-up
    (``fluid.preconditioner_reuse``); strays move every ``ctx.migrate_every`` steps."""
    me = ctx.comm.rank
    stray = np.nonzero(dest != me)[0]
    lo, hi = ctx.rcb.subbox(me)
    gap = np.maximum(0.0, np.maximum(lo - x[stray], x[stray] - hi))
    far = bool(((gap * gap).sum(axis=1) > ctx.skin * ctx.skin).any())
    if global_any(ctx.comm, far):
        return False
    dest[stray] = me
    return True


def list_order(ctx):
    """The rows as the fluid's systems number them: the halo rows from lower ranks, the
    owned rows, the halo rows from higher ranks (each rank numbers its rows after the
    lower ranks' and keeps its walls after its other rows, in storage order: see
    ``last`` in :func:`_distribute`). Lists built in this order are sorted by system
    row with no sort (:func:`solvers.csr.sort_neighbours_by_row`): on the second of 2
    ranks, whose halo rows are the lower, the lists by the cut had needed one (1.15 ms
    per step of the 3D tank of jobs/bench_memory.py). None where that is the index
    order (no halo rows from a lower rank)."""
    n = ctx.particles.n_owned
    below = int(ctx.halo.recv_counts[:ctx.comm.rank].sum()) if ctx.halo is not None else 0
    if below == 0:
        return None
    total = len(ctx.particles["x"])
    return np.concatenate([np.arange(n, n + below), np.arange(n),
                           np.arange(n + below, total)])


def refresh(ctx, force_partition: bool = False) -> None:
    """Migrate, refresh the halo, rebuild neighbour lists (infrastructure of every step).

    In the reference layout this runs once: the reference neighbourhood never changes,
    and stages refresh halo values with :meth:`Context.update_halo`.
    """
    if ctx.layout == "reference" and ctx.halo is not None:
        return
    timed(ctx, "migrate", _distribute, ctx, force_partition)
    p, key = ctx.particles, ctx.key

    # mixed layout: current-configuration halo and lists only while there is fluid
    # (the solid's reference halo and lists live in the coupled stage)
    current = ctx.layout != "mixed" or global_any(
        ctx.comm, bool((p["phase"][: p.n_owned] == PHASE_FLUID).any()))

    def halo():
        if _alone(ctx) and ctx.halo is not None:
            p.set_halo({})  # one rank without images has no halo rows
            return
        if ctx.layout == "mixed":
            n = p.n_owned
            phase = p["phase"][:n]
            ctx.halo = coupled_halo(ctx.comm, p["x"][:n], phase == PHASE_FLUID,
                                    ctx.radius if current else -1.0, ctx.box)
        else:
            ctx.halo = Halo.build(ctx.comm, ctx.rcb, p[key][: p.n_owned], ctx.radius + ctx.skin,
                                  ctx.box)
        names = [k for k in p.data if k not in ctx.halo_skip]
        p.set_halo(ctx.halo.exchange(p.owned_fields(names), shift_fields=("x", "X")))

    timed(ctx, "halo", halo)

    def neighbours():
        if current:
            wet = p["phase"] == PHASE_FLUID if ctx.wet_lists else None
            ctx.near_fluid = np.zeros(p.n_owned, dtype=np.uint8) if ctx.wet_lists else None
            ctx.indptr = ctx.indices = None  # the last lists are not held beside the new
            ctx.list_order = list_order(ctx) if ctx.wet_lists else None
            ctx.indptr, ctx.indices = build_csr(p[key], p.n_owned, ctx.radius, wet,
                                                ctx.near_fluid, ctx.list_order)
        else:
            ctx.indptr = np.zeros(p.n_owned + 1, dtype=np.int64)
            ctx.indices = np.zeros(0, dtype=np.int64)
            ctx.near_fluid = np.zeros(p.n_owned, dtype=np.uint8)

    timed(ctx, "neighbours", neighbours)
