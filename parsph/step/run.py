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

from base import heap
from base.memory import bytes_per_particle, peak_rss_mib
from decomposition import collective, world
from decomposition.box import Box
from decomposition.reduce import allgather, global_any, global_sum
from parsph.core.context import Context
from parsph.core.kernel import smoothing_length, support_radius
from parsph.core.particles import ParticleSet
from parsph.errors import ParsphError
from parsph.scene.budget import check_budget
from parsph.scene.geometry import body_fill, fill_warnings, generate, geometry_warnings
from parsph.step.pipeline import layout, needs_petsc, plan, uses_petsc
from parsph.step.refresh import check_state, refresh, timed
from parsph.step.stats import EnergyBalance, kinetic_energy, stats_columns, stats_row

log = logging.getLogger("parsph")


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


class _Rest:
    """``run.rest_fraction``: the run is at rest once its kinetic energy has stayed below
    that share of its peak for ``run.rest_time`` seconds, counted from the end of the
    earthquake record (the shaking must be over); the state goes into checkpoints, so a
    restarted run stops where the uninterrupted one does."""

    def __init__(self, scene, meta):
        self.fraction, self.duration = scene.run.rest_fraction, scene.run.rest_time
        record = scene.data.get("record")
        self.after = scene.loading.start_time + float(record.t[-1]) if record is not None \
            else 0.0
        since = float(meta.get("rest_since", math.nan))
        self.since = None if math.isnan(since) else since

    def update(self, t: float, ke: float, peak: float) -> None:
        if self.fraction <= 0.0:
            return
        if t >= self.after and peak > 0.0 and ke <= self.fraction * peak:
            self.since = t if self.since is None else self.since
        else:
            self.since = None

    def reached(self, t: float) -> bool:
        return self.since is not None and t - self.since >= self.duration - 1e-12

    def state(self) -> dict:
        return {"rest_since": math.nan if self.since is None else self.since}


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
    from parsph.step import checkpoint

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
        for text in fill_warnings(scene, body_fill(comm, scene, fields)):
            if comm.rank == 0:
                log.warning(text)
    else:
        fields = ck.fields
    particles = ParticleSet(dim, fields)
    # the set's rows are new arrays from the first distribution on (several ranks): held
    # here, the generated ones would stay for the whole run
    del fields
    if ck is not None:
        ck.fields = None
    for name in ("eps_p", "p", "porosity"):  # written to every frame (zeros if unused)
        particles.add_field(name)
    lay = layout(specs)
    ctx = Context(scene=scene, comm=comm, particles=particles, box=box, dim=dim, d=d, h=h,
                  radius=support_radius(h), layout=lay, key="X" if lay == "reference" else "x",
                  materials=list(scene.materials.values()), restarted=ck is not None, out=out,
                  wet_lists=uses_petsc(specs) and {s.name for s in specs} <= {"iisph", "coupled"})
    reuse = scene.fluid.preconditioner_reuse
    # lazy migration keeps the PPE's rows, so its lagged set-up (docs/decomposition.md)
    if reuse > 1 and (lay == "mixed" or (lay == "current" and any(s.name == "iisph"
                                                                  for s in specs))):
        ctx.skin, ctx.migrate_every = 0.5 * d, reuse
    if uses_petsc(specs):  # the PPE's lagged preconditioner is renewed every `reuse` steps
        ctx.sync_every = max(1, reuse)
    if ck is not None:
        ctx.time, ctx.step = float(ck.meta["time"]), int(ck.meta["step"])
        ctx.rcb = ck.rcb  # None at another rank count: re-partitioned below
        ctx.rcb_ref = ck.rcb_ref  # mixed layout: the solids' partition (fixed by X)
        ctx.rcb_wall = ck.rcb_wall  # and the partition of the walls
    if needs_petsc(specs, scene):  # only then is petsc4py imported
        import solvers

        solvers.init(list(petsc_args))
    stages = [spec.load()(ctx) for spec in specs]
    refresh(ctx, force_partition=ctx.rcb is None)
    for s in stages:
        if hasattr(s, "setup"):
            timed(ctx, s.name, s.setup, ctx)
        if ck is not None and hasattr(s, "restore"):
            s.restore(ctx, ck.stage_states.get(s.name, {}))
    for s in stages:
        if hasattr(s, "after_refresh"):
            timed(ctx, s.name, s.after_refresh, ctx)
    check_state(ctx)
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
    from parsph.step import checkpoint
    from parsph.step import faults
    from parsph.errors import Preempted
    from parsph.io import FrameWriter, StatsWriter, xdmf_writer
    from parsph.log import Progress
    from parsph.step.probes import ProbeOutput

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
    settled = None
    if ck is None and scene.run.mode == "physics":  # the soil in equilibrium before t = 0
        for s in stages:
            if hasattr(s, "settle"):
                settled = settled or s.settle(ctx)
        if settled is not None:
            refresh(ctx)
            for s in stages:
                if hasattr(s, "after_refresh"):
                    timed(ctx, s.name, s.after_refresh, ctx)
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
                "elastic_energy": last["ee"], "ambient_energy": last["amb"], **balance.state(),
                **rest.state()}
        states = {s.name: s.state() for s in stages if hasattr(s, "state")}
        heap.release_free_pages(ctx.n_owned)  # (a run's last checkpoint had been its peak)
        checkpoint.write(ck_path, comm, particles, ctx.rcb, meta, states,
                         fault=faults.checkpoint_fault(ctx.step), rcb_ref=ctx.rcb_ref,
                         rcb_wall=ctx.rcb_wall, more=ctx.fields_one_at_a_time())

    def finished():
        return (ctx.time >= end - 1e-12 * end or rest.reached(ctx.time)) and ctx.at_sync_step

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
        # the energy balance (stats.csv mechanical_energy, docs/energy.md) starts from the
        # initial state (a fresh solid is unstrained: no stored energy) or the checkpoint's
        meta = ck.meta if ck is not None else {}
        if settled is not None:  # the stress of the geostatic stage stores energy
            meta = {"elastic_energy": settled["elastic_energy"]}
        last = {"ee": float(meta.get("elastic_energy", 0.0)),
                "amb": float(meta.get("ambient_energy", 0.0))}
        balance = EnergyBalance(kinetic_energy(ctx)[0], last["ee"] + last["amb"], meta)
        rest = _Rest(scene, meta)
        max_steps = scene.run.max_steps
        stopping = False
        while scene.run.mode != "geometry" and not finished():
            if max_steps and ctx.step >= max_steps:
                break
            for name in ctx.timers:
                ctx.timers[name] = 0.0
            ctx.work[:] = 0.0  # the stages' work in this step (the energy balance)
            dt = _time_step(ctx, stages, end)
            for s in stages:
                if hasattr(s, "step"):
                    timed(ctx, s.name, s.step, ctx, dt)
            ctx.time += dt
            ctx.step += 1
            faults.inject_nan(ctx)
            check_state(ctx)
            # a sync step: every stray particle moves to its owner and the next solves
            # set up afresh, as after a restart from here
            ctx.sync_point = ctx.at_sync_step
            refresh(ctx)
            if ctx.sync_point:
                _renew_preconditioners(stages)
            for s in stages:
                if hasattr(s, "after_refresh"):
                    timed(ctx, s.name, s.after_refresh, ctx)
            if ctx.time >= next_frame - 1e-9 * every:
                write_frame()
                last_frame_step = ctx.step
                next_frame = _next_time(ctx.time, every)
            probes.sample_due(ctx)
            row = stats_row(ctx, dt, stages)
            last.update(ee=float(row.get("elastic_energy") or 0.0),
                        amb=float(row.get("ambient_energy") or 0.0))
            balance.update(row, last["ee"] + last["amb"])
            rest.update(ctx.time, row["kinetic_energy"], balance.ke_peak)
            row["elapsed_s"] = time.perf_counter() - wall0
            stats.write(row)
            bar.update(ctx.time, ctx.step)
            if ctx.time >= next_ck - 1e-9 * ck_every and ctx.at_sync_step:
                next_ck = _next_time(ctx.time, ck_every)
                stats.flush()  # a restart from here finds every row up to it
                write_checkpoint()
            stopping = stopping or global_any(comm, stop.signal is not None)
            if stopping and ctx.at_sync_step:
                stats.flush()
                write_checkpoint()
                _finish(ctx, stages)
                bar.close()
                raise Preempted(f"stopped by a signal at step {ctx.step}, t = {ctx.time:.6g} s; "
                                f"continue with: parsph run {scene.source} --restart {ck_path}")
        if rest.reached(ctx.time) and comm.rank == 0:
            log.info("at rest: the kinetic energy has stayed below %g of its peak since t = %.6g s",
                     rest.fraction, rest.since)
        if ctx.step != last_frame_step:
            write_frame()
            last_frame_step = ctx.step
        stats.flush()  # (and for the stages' end-of-run output read from it)
        write_checkpoint()
        _finish(ctx, stages)
    bar.close()
    memory = global_sum(comm, particles.nbytes() + ctx.indptr.nbytes + ctx.indices.nbytes)
    pairs = global_sum(comm, len(ctx.indices))
    wall = time.perf_counter() - wall0
    figures = balance.summary()
    rss = allgather(comm, peak_rss_mib())  # the whole process of each rank, at its peak
    log.info("done: %d steps to t = %.6g s in %.2f s wall; peak memory %s MiB per rank; "
             "output in %s", ctx.step, ctx.time, wall, " / ".join(f"{m:.0f}" for m in rss),
             out)
    log.info("energy balance: largest rise of a step %.3g, over any stretch %.3g, of the "
             "peak kinetic energy (docs/energy.md)", figures["energy_rise_max"],
             figures["energy_gain_max"])
    return {"steps": ctx.step, "time": ctx.time, "wall_s": wall, "particles": n_total,
            "dim": ctx.dim, "out": out, **figures,
            "bytes_per_particle": memory / max(n_total, 1), "peak_rss_mib": rss,
            "bytes_per_particle_peak_rss": bytes_per_particle(rss, n_total),
            "neighbours_per_particle": pairs / max(n_total, 1)}


def _finish(ctx, stages) -> None:
    """Stages' end-of-run output (e.g. triaxial.csv from stats.csv, flushed before it)."""
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
