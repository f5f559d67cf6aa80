"""The run driver: build particles, compose the step from the scene, march, write output.

One step (see DESIGN.md, "One time step, as data flow")::

    dt = min over stages of their limit (eq. 49)      (never clipped: see below)
    stage.step(ctx, dt) for each physics stage        (positions move last)
    check: NaN/inf, particles leaving the domain      (collective, one message)
    migrate to owners (re-partition when unbalanced), refresh halo, neighbour lists
    stage.after_refresh(ctx) for diagnostic stages    (e.g. density, eq. 33)
    stats.csv row; frame when due; probes when due; checkpoint when due (at a sync step)
    SIGTERM/SIGUSR1 seen by any rank: checkpoint on every rank at the next sync step,
    stop (exit status 4)

Output never changes the result: the step sequence depends on the physics and the
numerics only, never on ``output.every``, ``output.checkpoint_every``, the probes or
``run.end_time``. A frame is written at the first step at or after its time (with the
time reached), and a run stops at the first *sync step* at or after ``run.end_time``.
Sync steps are every ``fluid.preconditioner_reuse`` steps in scenes with an implicit
fluid (every step otherwise): there stray particles move to their owners and the PPE's
next solve sets its preconditioner up afresh, as in a run restarted from there. Every
checkpoint is written at a sync step, so a run restarted or branched from any checkpoint
continues the uninterrupted run's steps bit for bit (docs/reliability.md).
"""
from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from decomposition import collective, raise_if_any, world
from decomposition.box import Box
from decomposition.exchange import migrate
from decomposition.halo import Halo, coupled_halo
from decomposition.partition import RCB, imbalance
from decomposition.reduce import global_any, global_max, global_min, global_sum
from parsph.budget import check_budget
from parsph.errors import NumericalError, ParsphError
from parsph.geometry import generate
from parsph.kernel import smoothing_length, support_radius
from parsph.materials import PHASE_FLUID, PHASE_SOLID, PHASE_WALL
from parsph.neighbours import build_csr
from parsph.particles import ParticleSet
from parsph.pipeline import INFRASTRUCTURE, layout, plan, uses_petsc

log = logging.getLogger("parsph")


@dataclass
class Context:
    """What the stages of a step see."""

    scene: object
    comm: object
    particles: ParticleSet
    box: Box
    dim: int
    d: float
    h: float
    radius: float
    rcb: RCB = None
    rcb_ref: RCB = None
    #: mixed layout: the walls' partition (``rcb`` is then the fluid's)
    rcb_wall: RCB = None
    #: set when the solids' partition (by X) was rebuilt: their view must be rebuilt too
    solids_moved: bool = False
    halo: Halo = None
    indptr: np.ndarray = None
    indices: np.ndarray = None
    layout: str = "current"
    key: str = "x"
    restarted: bool = False
    out: str = ""
    materials: list = field(default_factory=list)
    time: float = 0.0
    step: int = 0
    timers: dict = field(default_factory=dict)
    #: Lagged migration (current layout with a fluid): an owned particle may stray this
    #: far (m) beyond its rank's sub-box before it must move; the halo is this much wider.
    skin: float = 0.0
    #: ... and strays move every this many steps (when the AMG set-up is renewed).
    migrate_every: int = 1
    #: Sync steps (``step % sync_every == 0``): strays move to their owners and the PPE's
    #: next solve sets up afresh; checkpoints and the end of a run fall on them (see
    #: :func:`run`). ``fluid.preconditioner_reuse`` with an implicit fluid, else 1.
    sync_every: int = 1
    sync_point: bool = False

    @property
    def n_owned(self) -> int:
        return self.particles.n_owned

    def update_halo(self, names) -> None:
        """Refresh the halo rows of the named fields from their owners (same pattern)."""
        p = self.particles
        fresh = self.halo.exchange(p.owned_fields(names), shift_fields=("x", "X"))
        for name, rows in fresh.items():
            p[name][p.n_owned:] = rows

    def nearby_walls(self, names, around=None) -> dict:
        """Collective: the named fields of every wall row near this rank's particles
        (``around``: bool mask of owned rows, default all), see :meth:`nearby`."""
        p = self.particles
        return self.nearby(p["phase"][: p.n_owned] == PHASE_WALL, names, around=around)

    def body_acceleration(self, t: float) -> np.ndarray:
        """g − s a_ground(t − t_0) (m/s²): gravity and the earthquake record, section 6.3.

        The walls are fixed, so the record acts in the frame moving with the ground
        (see :mod:`parsph.loading`); without a record this is g.
        """
        record = self.scene.data.get("record")
        if record is None:
            return self.gravity
        load = self.scene.loading
        return self.gravity - load.scale * record.at(t - load.start_time)

    @property
    def gravity(self) -> np.ndarray:
        return np.asarray(self.scene.gravity.g, dtype=float)

    def nearby(self, select, names, radius: float | None = None, around=None) -> dict:
        """Collective: owned rows of every rank (``select`` mask) near this rank's particles.

        ``around`` (bool mask of owned rows, default all) chooses the particles whose
        current bounding box, widened by ``radius`` (default 2h), defines "near". Returns
        the named fields of those rows, this rank's own included. Used for neighbours in
        the current configuration when ownership follows the reference one (walls seen
        by TLSPH particles).
        """
        from decomposition.halo import proximity_halo

        p = self.particles
        x = p["x"][: p.n_owned]
        pts = x if around is None else x[around]
        if len(pts):
            lo, hi = pts.min(axis=0), pts.max(axis=0)
        else:
            lo, hi = np.full(self.dim, np.inf), np.full(self.dim, -np.inf)
        halo = proximity_halo(self.comm, x, select, radius or self.radius, lo, hi, self.box)
        return halo.exchange(p.owned_fields(names), shift_fields=("x", "X"))


def prepare_output(comm, out: str) -> None:
    """Collective: create ``out`` and check it is writable (on rank 0), before any work."""
    with collective(comm):
        if comm.rank == 0:
            try:
                os.makedirs(out, exist_ok=True)
                probe = os.path.join(out, f".parsph-write-test-{os.getpid()}")
                with open(probe, "w") as fh:
                    fh.write("ok")
                os.remove(probe)
            except OSError as exc:
                raise ParsphError(f"output directory '{out}' is not writable ({exc.strerror}); "
                                  f"choose another with --out DIR") from None


def _timed(ctx, name, fn, *args):
    t0 = time.perf_counter()
    result = fn(*args)
    ctx.timers[name] = ctx.timers.get(name, 0.0) + time.perf_counter() - t0
    return result


def _check_state(ctx) -> None:
    """Collective: stop every rank with one message on NaN/inf or a particle out of the box."""
    p = ctx.particles
    n = p.n_owned
    error = None
    for name in ("x", "v"):
        bad = ~np.isfinite(p[name][:n]).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            error = NumericalError(
                f"non-finite {name} of particle id {int(p['id'][i])} at step {ctx.step}, "
                f"t = {ctx.time:.6g} s (rank {ctx.comm.rank}); the last good frame and stats "
                f"are kept; try a smaller time step (run.cfl or run.dt)")
            break
    if error is None:
        out = ctx.box.outside(p["x"][:n])
        if out.any():
            i = int(np.argmax(out))
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
    owned = p.owned_fields()
    if ctx.box.periodic and any(ctx.box.periodic):
        # a TLSPH solid keeps its unwrapped x, continuous with its reference X (its
        # neighbours across the boundary are images, shifted in x and X alike)
        keep = owned["phase"] == PHASE_SOLID if ctx.layout != "current" else None
        wrapped = ctx.box.wrap(owned["x"])
        owned["x"] = wrapped if keep is None else np.where(keep[:, None], owned["x"], wrapped)
    tolerance = ctx.scene.run.rebalance_tolerance
    work = _work(owned["phase"])
    if ctx.layout == "mixed":  # solids by X, walls and fluid by x, each balanced on its own
        phase, x = owned["phase"], owned["x"]
        solid, wall = phase == PHASE_SOLID, phase == PHASE_WALL
        fluid = ~solid & ~wall
        # the walls do not move: a partition of their own, built once. One partition for
        # walls and fluid balanced their summed work, not the fluid: aso_like at d = 4 m
        # had 6 and 1,684 fluid rows on its 2 ranks (docs/decomposition.md)
        if force or ctx.rcb_wall is None:
            ctx.rcb_wall = RCB.build(comm, x[wall], ctx.box)
        # per rank, in one reduction: the solids it owns, and the fluid rows it would own
        # under the present cuts (those that fluidised in the last step are still on the
        # rank that held them as solids)
        counts = np.zeros((2, comm.size), dtype=np.int64)
        counts[0, comm.rank] = solid.sum()
        to = None if ctx.rcb is None else ctx.rcb.owner(x[fluid])
        if to is None:
            counts[1, comm.rank] = fluid.sum()
        else:
            counts[1] = np.bincount(to, minlength=comm.size)
        counts = global_sum(comm, counts)
        # the solids' partition is fixed by X, but the phase change empties the ranks
        # that hold the failing toe: rebuilt when their counts drift past the tolerance
        if force or ctx.rcb_ref is None or _unbalanced(counts[0], tolerance):
            ctx.solids_moved = ctx.rcb_ref is not None
            ctx.rcb_ref = RCB.build(comm, owned["X"][solid], ctx.box)
        n_fluid = int(counts[1].sum())
        if force or to is None or (n_fluid and _unbalanced(counts[1], tolerance)):
            # before any soil fluidises: the walls' cuts (a fluid row's owner is defined)
            ctx.rcb = RCB.build(comm, x[fluid], ctx.box) if n_fluid else ctx.rcb_wall
            to = ctx.rcb.owner(x[fluid])
        dest = np.empty(len(phase), dtype=np.int32)
        dest[solid] = ctx.rcb_ref.owner(owned["X"][solid])
        dest[wall] = ctx.rcb_wall.owner(x[wall])
        dest[fluid] = to
        p.set_owned(migrate(comm, owned, dest))
        return
    rebuilt = force or ctx.rcb is None or imbalance(comm, float(work.sum())) > tolerance
    if rebuilt:
        ctx.rcb = RCB.build(comm, owned[key], ctx.box, weights=work)
    dest = ctx.rcb.owner(owned[key])
    if ctx.skin > 0 and not rebuilt and not ctx.sync_point and ctx.step % ctx.migrate_every:
        _keep_strays(ctx, owned[key], dest)
    p.set_owned(migrate(comm, owned, dest))


def _keep_strays(ctx, x, dest) -> None:
    """Collective: lagged migration. Rows that left their rank's sub-box stay (``dest`` is
    set to this rank) while every stray on every rank is within ``ctx.skin`` of its
    owner's sub-box; the halo is ``ctx.skin`` wider, so every neighbour within 2h of a
    stray still reaches it. Unchanged rows keep the PPE's AMG set-up
    (``fluid.preconditioner_reuse``); strays move every ``ctx.migrate_every`` steps."""
    me = ctx.comm.rank
    stray = np.nonzero(dest != me)[0]
    lo, hi = ctx.rcb.subbox(me)
    gap = np.maximum(0.0, np.maximum(lo - x[stray], x[stray] - hi))
    far = bool(((gap * gap).sum(axis=1) > ctx.skin * ctx.skin).any())
    if not global_any(ctx.comm, far):
        dest[stray] = me


def refresh(ctx, force_partition: bool = False) -> None:
    """Migrate, refresh the halo, rebuild neighbour lists (infrastructure of every step).

    In the reference layout this runs once: the reference neighbourhood never changes,
    and stages refresh halo values with :meth:`Context.update_halo`.
    """
    if ctx.layout == "reference" and ctx.halo is not None:
        return
    _timed(ctx, "migrate", _distribute, ctx, force_partition)
    p, key = ctx.particles, ctx.key

    # mixed layout: current-configuration halo and lists only while there is fluid
    # (the solid's reference halo and lists live in the coupled stage)
    current = ctx.layout != "mixed" or global_any(
        ctx.comm, bool((p["phase"][: p.n_owned] == PHASE_FLUID).any()))

    def halo():
        if ctx.layout == "mixed":
            n = p.n_owned
            phase = p["phase"][:n]
            ctx.halo = coupled_halo(ctx.comm, p["x"][:n], phase == PHASE_SOLID,
                                    phase == PHASE_FLUID, ctx.radius if current else -1.0,
                                    ctx.box)
        else:
            ctx.halo = Halo.build(ctx.comm, ctx.rcb, p[key][: p.n_owned], ctx.radius + ctx.skin,
                                  ctx.box)
        p.set_halo(ctx.halo.exchange(p.owned_fields(), shift_fields=("x", "X")))

    _timed(ctx, "halo", halo)

    def neighbours():
        if current:
            ctx.indptr, ctx.indices = build_csr(p[key], p.n_owned, ctx.radius)
        else:
            ctx.indptr = np.zeros(p.n_owned + 1, dtype=np.int64)
            ctx.indices = np.zeros(0, dtype=np.int64)

    _timed(ctx, "neighbours", neighbours)


def _renew_preconditioners(stages) -> None:
    """At a sync step: the next solves set their preconditioners up afresh, as a run
    restarted from a checkpoint written here does, so that the restart is bit for bit."""
    for s in stages:
        if hasattr(s, "renew_preconditioners"):
            s.renew_preconditioners()


def _time_step(ctx, stages, end: float) -> float:
    """``run.dt``, or the smallest limit of the stages (eq. 49).

    Never clipped, neither to frame or checkpoint times nor to ``end``: the steps of a
    run are the same whatever its output schedule and end time, so a longer run, or one
    restarted from any checkpoint, goes through the same states bit for bit. (Clipping
    also made slivers: a step of 1e-3 dt makes the projection's pressure, the divergence
    over dt, a spike.) Only when nothing limits the step (no stage does, or everything is
    at rest without gravity) does ``end`` set it: one step to the end.
    """
    fixed = ctx.scene.run.dt
    dt = fixed if fixed > 0 else min([s.max_dt(ctx) for s in stages] + [math.inf])
    if not math.isfinite(dt):
        dt = end - ctx.time if end > ctx.time else end
    return dt


def _next_time(t: float, every: float) -> float:
    """The first multiple of ``every`` after ``t`` (s): the next frame or checkpoint time.
    A multiple within 1e-9 ``every`` of ``t`` counts as reached."""
    return (math.floor(t / every + 1e-9) + 1) * every


def same_directory(restart: str, out: str) -> bool:
    """Whether ``out`` is the directory of the checkpoint ``restart`` (then the restart
    continues that run there; otherwise it starts a new run directory, a branch)."""
    here = os.path.dirname(os.path.abspath(restart))
    return os.path.realpath(here) == os.path.realpath(out)


def kinetic_energy(ctx) -> tuple[float, float]:
    """Collective: ``(kinetic energy, mass)`` of the moving (non-wall) particles (J, kg;
    per metre in 2D)."""
    p, n = ctx.particles, ctx.particles.n_owned
    moving = p["phase"][:n] != PHASE_WALL
    v = p["v"][:n][moving]
    m = p["m"][:n][moving]
    ke, mass = global_sum(ctx.comm, np.array([0.5 * float((m * (v * v).sum(axis=1)).sum()),
                                              float(m.sum())]))
    return float(ke), float(mass)


def energy_budget(ke0, ke1, ee0, ee1, mass, g, dt, work=0.0) -> tuple[float, float]:
    r"""``(bound, ratio)`` of one step: what gravity, the stored elastic energy and the
    density term of the PPE can supply to the kinetic energy over ``dt``,
    :math:`|g|\sqrt{2 M \max(K_0, K_1)}\,\Delta t + \max(0, E_0 - E_1) + W_\alpha` (J; the
    first term bounds :math:`\int \sum m\,\mathbf g\cdot\mathbf v\,dt` by
    Cauchy-Schwarz; :math:`W_\alpha` = ``work``, the work of the pressure on the expansion
    the density term of eq. (32) asks of compressed particles), and the kinetic energy's
    rise over it, :math:`(K_1 - K_0) / \text{bound}`: a step that makes energy has a ratio
    above 1 (docs/reliability.md)."""
    bound = g * math.sqrt(2.0 * mass * max(ke0, ke1, 0.0)) * dt + max(ee0 - ee1, 0.0) \
        + max(work, 0.0)
    rise = ke1 - ke0
    if bound <= 0.0:
        return 0.0, (0.0 if rise <= 0.0 else math.inf)
    return bound, rise / bound


def _stats_row(ctx, dt, stage_objs) -> dict:
    p, comm = ctx.particles, ctx.comm
    n = p.n_owned
    phase = p["phase"][:n]
    counts = np.array([n, (phase == PHASE_SOLID).sum(), (phase == PHASE_FLUID).sum(),
                       (phase == PHASE_WALL).sum(), 0.0, 0.0], dtype=np.float64)
    v = p["v"][:n]
    moving = phase != PHASE_WALL
    speed2 = (v * v).sum(axis=1)[moving]
    counts[4] = 0.5 * float((p["m"][:n][moving] * speed2).sum())
    counts[5] = float(p["m"][:n][moving].sum())
    e = np.asarray(ctx.scene.output.front_direction or (1.0,) + (0.0,) * (ctx.dim - 1), float)
    along = p["x"][:n][moving] @ (e / np.linalg.norm(e))
    counts = global_sum(comm, counts)
    ke = float(counts[4])
    n_max, n_min = global_max(comm, n), global_min(comm, n)
    front = global_max(comm, float(along.max()) if len(along) else -math.inf)
    vmax = math.sqrt(global_max(comm, float(speed2.max()) if len(speed2) else 0.0))
    row = {"step": ctx.step, "time": ctx.time, "dt": dt,
           "n_particles": int(counts[0]), "n_solid": int(counts[1]), "n_fluid": int(counts[2]),
           "n_wall": int(counts[3]), "n_owned_min": n_min, "n_owned_max": n_max,
           "kinetic_energy": ke, "max_speed": vmax, "front": front, "mass": float(counts[5])}
    for s in stage_objs:
        row.update(s.stats())
    for name, seconds in ctx.timers.items():
        row[f"wall_s_{name}"] = seconds
    return row


def stats_columns(stages) -> list[str]:
    """stats.csv columns: counts, energy, each stage's own columns, wall seconds per stage."""
    cols = ["step", "time", "dt", "n_particles", "n_solid", "n_fluid", "n_wall",
            "n_owned_min", "n_owned_max", "kinetic_energy", "energy_bound", "energy_ratio",
            "max_speed", "front"]
    cols += [c for s in stages for c in getattr(s, "stats_columns", ())]
    cols += [f"wall_s_{name}" for name, _ in INFRASTRUCTURE]
    cols += [f"wall_s_{s.name}" for s in stages] + ["wall_s_output"]
    return cols


class _StopRequest:
    """SIGTERM / SIGUSR1 (what batch systems send before killing a job) set a flag; the
    ranks agree on it after each step, write a checkpoint and stop together."""

    SIGNALS = ("SIGTERM", "SIGUSR1")

    def __init__(self):
        self.signal = None
        self.previous = {}

    def __enter__(self):
        import signal

        for name in self.SIGNALS:
            signum = getattr(signal, name)
            try:
                self.previous[signum] = signal.signal(signum, self._handler)
            except ValueError:  # not the main thread (e.g. embedded use): no handler
                pass
        return self

    def _handler(self, signum, frame):
        self.signal = signum

    def __exit__(self, *exc):
        import signal

        for signum, handler in self.previous.items():
            signal.signal(signum, handler)


def _build(scene, out, comm, petsc_args, restart):
    """Everything before the first step: checks, particles (generated or read from a
    checkpoint), partition, halo, neighbours and the scene's stages, set up."""
    from parsph import checkpoint

    from parsph.scene import geometry_warnings

    specs = plan(scene)
    check_budget(comm, scene, specs)
    if comm.rank == 0:
        for text in geometry_warnings(scene):
            log.warning(text)
    # a checkpoint is checked before anything is written: a refused restart or branch
    # leaves no new directory behind
    ck = checkpoint.read(restart, comm, scene) if restart is not None else None
    prepare_output(comm, out)
    dim, d = scene.domain.dim, scene.domain.particle_size
    h = smoothing_length(d)
    box = Box(tuple(scene.domain.lo), tuple(scene.domain.hi), tuple(scene.domain.periodic))
    if ck is None:
        fields = generate(comm, scene)
        fields["X"] = fields["x"].copy()  # reference configuration (section 3)
    else:
        fields = ck.fields
    particles = ParticleSet(dim, fields)
    for name in ("eps_p", "p", "porosity"):  # written to every frame (zeros if unused)
        particles.add_field(name)
    lay = layout(specs)
    ctx = Context(scene=scene, comm=comm, particles=particles, box=box, dim=dim, d=d, h=h,
                  radius=support_radius(h), layout=lay, key="X" if lay == "reference" else "x",
                  materials=list(scene.materials.values()), restarted=ck is not None, out=out)
    reuse = scene.fluid.preconditioner_reuse
    if lay == "current" and reuse > 1 and any(s.name == "iisph" for s in specs):
        ctx.skin, ctx.migrate_every = 0.5 * d, reuse
    if uses_petsc(specs):  # the PPE's lagged preconditioner is renewed every `reuse` steps
        ctx.sync_every = max(1, reuse)
    if ck is not None:
        ctx.time, ctx.step = float(ck.meta["time"]), int(ck.meta["step"])
        ctx.rcb = ck.rcb  # None at another rank count: re-partitioned below
        ctx.rcb_ref = ck.rcb_ref  # mixed layout: the solids' partition (fixed by X)
        ctx.rcb_wall = ck.rcb_wall  # and the partition of the walls
    if uses_petsc(specs):  # only then is petsc4py imported
        import solvers

        solvers.init(list(petsc_args))
    stages = [spec.load()(ctx) for spec in specs]
    refresh(ctx, force_partition=ctx.rcb is None)
    for s in stages:
        if hasattr(s, "setup"):
            _timed(ctx, s.name, s.setup, ctx)
        if ck is not None and hasattr(s, "restore"):
            s.restore(ctx, ck.stage_states.get(s.name, {}))
    for s in stages:
        if hasattr(s, "after_refresh"):
            _timed(ctx, s.name, s.after_refresh, ctx)
    _check_state(ctx)
    return ctx, specs, stages, ck


def run(scene, out: str, comm=None, petsc_args=(), progress: bool | None = None,
        restart: str | None = None) -> dict:
    """Run a validated scene; write ``out/particles.h5``, ``.xdmf``, ``stats.csv`` and
    ``checkpoint.h5``.

    Collective over ``comm`` (default: the world). ``restart`` starts from a checkpoint:
    in its own directory the run continues there (frames appended, ``stats.csv`` kept up
    to the checkpoint's step); in another ``out`` it is a branch, a new run directory
    whose first frame is the checkpoint's state, the checkpoint's directory untouched.
    Either way the steps are those of the uninterrupted run (bit for bit at the same rank
    count). Returns a summary (steps, time, wall seconds, particle count, dimension and more).

    Raises
    ------
    Preempted
        After SIGTERM/SIGUSR1: the run went on to the next sync step (at most
        ``fluid.preconditioner_reuse - 1`` steps later) and wrote a checkpoint there.
    NumericalError
        NaN/inf, a particle out of the domain, a failed solve: the frames and checkpoint
        already written are kept.
    """
    from parsph import checkpoint, faults
    from parsph.errors import Preempted
    from parsph.io import FrameWriter, StatsWriter, xdmf_writer
    from parsph.log import Progress
    from parsph.probes import ProbeOutput

    comm = comm or world()
    wall0 = time.perf_counter()
    ctx, specs, stages, ck = _build(scene, out, comm, petsc_args, restart)
    continuing = ck is not None and same_directory(restart, out)
    particles, dim, d = ctx.particles, ctx.dim, ctx.d
    n_total = int(global_sum(comm, particles.n_owned))
    if ck is None:
        origin = ""
    else:
        origin = (f"; {'restarted' if continuing else f'branched from {restart}'} at "
                  f"t = {ctx.time:.6g} s, step {ctx.step}")
    log.info("scene '%s': %d particles on %d rank(s), stages: %s%s", scene.name, n_total,
             comm.size, ", ".join(s.name for s in specs), origin)
    h5 = os.path.join(out, "particles.h5")
    xdmf = os.path.join(out, "particles.xdmf")
    ck_path = os.path.join(out, checkpoint.FILE_NAME)
    frame_fields = ("id", "x", "v", "phase", "eps_p", "p", "porosity", "rho") + tuple(
        f for s in stages for f in getattr(s, "output_fields", ()))
    attrs = {"scene": scene.name, "particle_size": d, "ranks": comm.size,
             "scene_source": scene.source}
    end = scene.run.end_time
    every = scene.output.every
    ck_every = scene.output.checkpoint_every
    # the output schedule follows the time reached (output.every and checkpoint_every may
    # differ in a restarted run): frames and checkpoints due at or before it are done
    next_frame = _next_time(ctx.time, every) if ck is not None else every
    next_ck = _next_time(ctx.time, ck_every) if ck_every > 0 else math.inf
    last_frame_step = int(ck.meta["last_frame_step"]) if continuing else -1

    def write_frame():
        t0 = time.perf_counter()
        fields = {k: particles[k][: particles.n_owned] for k in frame_fields if k in particles}
        writer.write_frame(ctx.step, ctx.time, fields)  # rank 0 also rewrites the XDMF
        ctx.timers["output"] = ctx.timers.get("output", 0.0) + time.perf_counter() - t0

    def write_checkpoint():
        meta = {"scene": scene.name, "scene_physics": checkpoint.physics_hash(scene),
                "scene_physics_keys": checkpoint.physics_keys(scene),
                "dim": dim, "time": ctx.time, "step": ctx.step, "next_frame": next_frame,
                "last_frame_step": last_frame_step, "next_checkpoint": next_ck,
                "elastic_energy": last["ee"]}
        states = {s.name: s.state() for s in stages if hasattr(s, "state")}
        checkpoint.write(ck_path, comm, particles, ctx.rcb, meta, states,
                         fault=faults.checkpoint_fault(ctx.step), rcb_ref=ctx.rcb_ref,
                         rcb_wall=ctx.rcb_wall)

    def at_sync_step():
        return ctx.step % ctx.sync_every == 0

    def finished():
        return ctx.time >= end - 1e-12 * end and at_sync_step()

    show = scene.output.progress if progress is None else progress
    bar = Progress(end, enabled=show and comm.rank == 0)
    mode = "a" if continuing else "w"
    if continuing and comm.rank == 0:
        _truncate_stats(os.path.join(out, "stats.csv"), ctx.step)
    with FrameWriter(h5, comm, dim, attrs=attrs, on_frame=xdmf_writer(xdmf), mode=mode) as writer, \
            StatsWriter(os.path.join(out, "stats.csv"), stats_columns(stages),
                        enabled=comm.rank == 0, mode=mode) as stats, _StopRequest() as stop, \
            ProbeOutput(ctx, continuing) as probes:
        if continuing:
            writer.drop_frames_after(ctx.step)  # left by a run killed after the checkpoint
        else:
            write_frame()  # frame 0: the initial state, or the checkpoint's (a branch)
            last_frame_step = ctx.step
        probes.sample_due(ctx)  # t = 0 or a branch's start (a restart goes on at the next)
        # the energy budget of each step (stats.csv energy_bound, energy_ratio) needs the
        # kinetic and elastic energy before it: of the initial state, or the checkpoint's
        last = {"ke": kinetic_energy(ctx)[0],
                "ee": float(ck.meta.get("elastic_energy", 0.0)) if ck is not None else 0.0}
        max_steps = scene.run.max_steps
        stopping = False
        while scene.run.mode != "geometry" and not finished():
            if max_steps and ctx.step >= max_steps:
                break
            for name in ctx.timers:
                ctx.timers[name] = 0.0
            dt = _time_step(ctx, stages, end)
            for s in stages:
                if hasattr(s, "step"):
                    _timed(ctx, s.name, s.step, ctx, dt)
            ctx.time += dt
            ctx.step += 1
            faults.inject_nan(ctx)
            _check_state(ctx)
            # a sync step: every stray particle moves to its owner and the next solves
            # set up afresh, as after a restart from here
            ctx.sync_point = at_sync_step()
            refresh(ctx)
            if ctx.sync_point:
                _renew_preconditioners(stages)
            for s in stages:
                if hasattr(s, "after_refresh"):
                    _timed(ctx, s.name, s.after_refresh, ctx)
            if ctx.time >= next_frame - 1e-9 * every:
                write_frame()
                last_frame_step = ctx.step
                next_frame = _next_time(ctx.time, every)
            probes.sample_due(ctx)
            row = _stats_row(ctx, dt, stages)
            g = max(float(np.linalg.norm(ctx.body_acceleration(t)))
                    for t in (ctx.time - dt, ctx.time))
            ee = float(row.get("elastic_energy") or 0.0)
            row["energy_bound"], row["energy_ratio"] = energy_budget(
                last["ke"], row["kinetic_energy"], last["ee"], ee, row.pop("mass"), g, dt,
                float(row.get("density_work") or 0.0))
            last.update(ke=row["kinetic_energy"], ee=ee)
            stats.write(row)
            bar.update(ctx.time, ctx.step)
            if ctx.time >= next_ck - 1e-9 * ck_every and at_sync_step():
                next_ck = _next_time(ctx.time, ck_every)
                write_checkpoint()
            stopping = stopping or global_any(comm, stop.signal is not None)
            if stopping and at_sync_step():
                write_checkpoint()
                _finish(ctx, stages)
                bar.close()
                raise Preempted(f"stopped by a signal at step {ctx.step}, t = {ctx.time:.6g} s; "
                                f"continue with: parsph run {scene.source} --restart {ck_path}")
        if ctx.step != last_frame_step:
            write_frame()
            last_frame_step = ctx.step
        write_checkpoint()
        _finish(ctx, stages)
    bar.close()
    memory = global_sum(comm, particles.nbytes() + ctx.indptr.nbytes + ctx.indices.nbytes)
    pairs = global_sum(comm, len(ctx.indices))
    wall = time.perf_counter() - wall0
    log.info("done: %d steps to t = %.6g s in %.2f s wall; output in %s", ctx.step, ctx.time,
             wall, out)
    return {"steps": ctx.step, "time": ctx.time, "wall_s": wall, "particles": n_total,
            "dim": ctx.dim, "out": out,
            "bytes_per_particle": memory / max(n_total, 1),
            "neighbours_per_particle": pairs / max(n_total, 1)}


def _finish(ctx, stages) -> None:
    """Stages' end-of-run output (e.g. triaxial.csv from stats.csv, flushed row by row)."""
    for s in stages:
        if hasattr(s, "finish"):
            s.finish(ctx)


def _truncate_stats(path: str, step: int) -> None:
    """Drop stats rows after ``step`` (left by a run killed after its last checkpoint)."""
    if not os.path.exists(path):
        return
    with open(path) as fh:
        lines = fh.readlines()
    keep = lines[:1] + [ln for ln in lines[1:] if ln.split(",", 1)[0].strip().isdigit()
                        and int(ln.split(",", 1)[0]) <= step]
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        fh.writelines(keep)
    os.replace(tmp, path)
