r"""Probes: fields sampled at points, along lines and over boxes, on any rank count.

A point or line probe with ``measure = "interpolate"`` gives at each station
:math:`\mathbf x_s` the Shepard-normalised SPH interpolation (Shepard 1968; Liu & Liu
2003, eq. (4.33)) over the contributing particles :math:`j` (the probe's ``phases``)

.. math::

    \langle f \rangle(\mathbf x_s) = \frac{\sum_j V_j f_j W(\mathbf x_s - \mathbf x_j, h)}
                                          {\sum_j V_j W(\mathbf x_s - \mathbf x_j, h)},

with the cubic spline :math:`W` of :mod:`parsph.core.kernel` and the particle volume
:math:`V_j = d^D` (times :math:`\det\mathbf F_j` for a solid particle); the sums
themselves give the density by summation :math:`\sum_j m_j W` (eq. (33) at the point)
and the volume fraction :math:`\sum_j V_j W`. With ``measure = "depth"`` the kernel is
replaced by its integral along the vertical (the last axis),
:math:`\hat W(\rho) = \int W(\sqrt{\rho^2 + z^2}, h)\,dz` with :math:`\rho` the horizontal
distance, over the particles whose centre lies above the station: :math:`\sum_j V_j \hat
W` is the volume of material per unit horizontal area above the station, the thickness
of its column (exactly :math:`H` for a lattice layer of thickness :math:`H`, smoothed
over :math:`2h` horizontally), and the normalised sums are depth averages. Box probes
integrate over the contributing particles inside the box.

Notes
-----
Parallel: each rank sums the contributions of its **owned** particles to every station
(a particle is owned by one rank, so nothing is counted twice and no halo is read),
with the cell-linked list of :func:`parsph.core.neighbours.build_csr` run on the stations as
query rows among the owned particles near them. The partial sums of every probe due at
a step go into one buffer and one ``Allreduce`` gives every rank the totals: no
particle is gathered anywhere. Periodic axes are handled by images of the stations
within :math:`2h` of a periodic boundary (particles are wrapped into the box). The
result depends on the rank count only through the order of the floating-point sums.

References
----------
Shepard, D. (1968). A two-dimensional interpolation function for irregularly-spaced
data. Proc. 23rd ACM National Conference, 517-524.
Liu, G. R. and Liu, M. B. (2003). Smoothed Particle Hydrodynamics: a meshfree particle
method. World Scientific.
"""
from __future__ import annotations

import itertools
import math
import time

import numpy as np
from numba import njit

from decomposition.reduce import global_sum
from parsph.core.kernel import support_radius, w
from parsph.scene.materials import PHASE_FLUID, PHASE_SOLID
from parsph.core.neighbours import build_csr
from parsph.scene.params_probes import AVERAGES, PHASES, fields_of, stations

#: Gauss-Legendre rule of each of the two pieces of the vertical integral of W.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_AXES = "xyz"
#: Stress components written for a ``stress`` field: name suffix -> (row, column) of sigma.
_STRESS = {2: ("xx", "yy", "zz", "xy"), 3: ("xx", "yy", "zz", "xy", "xz", "yz")}
#: Box sums: volume-, mass- and count-type columns before the velocity and energy.
_BOX_SUMS = ("count", "mass", "volume", "fluid_volume", "solid_volume", "fluidised_volume")


# --------------------------------------------------------------------------- kernels

@njit(cache=True, error_model="numpy", inline="always")
def projected_w(rho, h, dim, gx, gw):
    r"""Vertical integral :math:`\hat W(\rho) = \int_{-\infty}^{\infty}
    W(\sqrt{\rho^2 + z^2}, h)\,dz` of the ``dim``-dimensional cubic spline (1/m^(dim-1)).

    Gauss-Legendre on the two pieces of the spline (:math:`q < 1`, :math:`1 \le q < 2`);
    :math:`\int \hat W\,dA = 1` over the horizontal (dim - 1 axes).
    """
    rmax = 2.0 * h
    if rho >= rmax:
        return 0.0
    z1 = math.sqrt(max(h * h - rho * rho, 0.0))
    z2 = math.sqrt(rmax * rmax - rho * rho)
    total = 0.0
    for piece in range(2):
        a = 0.0 if piece == 0 else z1
        b = z1 if piece == 0 else z2
        half = 0.5 * (b - a)
        mid = 0.5 * (a + b)
        for k in range(gx.shape[0]):
            z = mid + half * gx[k]
            total += gw[k] * half * w(math.sqrt(rho * rho + z * z), h, dim)
    return 2.0 * total


@njit(cache=True, error_model="numpy")
def _interpolate(x, nq, station, indptr, indices, vals, h, dim, acc):
    """acc[station[q]] += W(x_q - x_j) vals[j - nq] over the particle neighbours j of
    query row q (rows >= nq of ``x`` are particles, rows < nq station images)."""
    nc = vals.shape[1]
    for q in range(nq):
        s = station[q]
        for k in range(indptr[q], indptr[q + 1]):
            j = indices[k]
            if j < nq:
                continue
            r2 = 0.0
            for a in range(dim):
                dx = x[q, a] - x[j, a]
                r2 += dx * dx
            wk = w(math.sqrt(r2), h, dim)
            for c in range(nc):
                acc[s, c] += wk * vals[j - nq, c]


@njit(cache=True, error_model="numpy")
def _column(xh, zq, zp, nq, station, indptr, indices, vals, h, dim, gx, gw, acc):
    """acc[station[q]] += W_hat(rho) vals[j - nq] over the particles j within 2h
    horizontally (``xh``: the horizontal coordinates) whose centre is above ``zq[q]``."""
    nc = vals.shape[1]
    nh = xh.shape[1]
    for q in range(nq):
        s = station[q]
        for k in range(indptr[q], indptr[q + 1]):
            j = indices[k]
            if j < nq or zp[j - nq] <= zq[q]:
                continue
            r2 = 0.0
            for a in range(nh):
                dx = xh[q, a] - xh[j, a]
                r2 += dx * dx
            wk = projected_w(math.sqrt(r2), h, dim, gx, gw)
            for c in range(nc):
                acc[s, c] += wk * vals[j - nq, c]


def projected_w_array(rho, h, dim):
    """Vectorised :func:`projected_w` (tests, plots)."""
    rho = np.asarray(rho, dtype=float)
    return np.array([_projected_one(float(r), float(h), int(dim), _GL_X, _GL_W)
                     for r in rho.reshape(-1)]).reshape(rho.shape)


@njit(cache=True, error_model="numpy")
def _projected_one(rho, h, dim, gx, gw):
    return projected_w(rho, h, dim, gx, gw)


# --------------------------------------------------------------------------- set-up

def column_names(name: str, dim: int) -> list[str]:
    """The CSV field names of one requested field (vectors and tensors per component)."""
    if name == "v":
        return [f"v_{a}" for a in _AXES[:dim]]
    if name == "stress":
        return [f"sigma_{c}" for c in _STRESS[dim]]
    return [name]


class _Item:
    """One probe: its stations (with periodic images), fields and schedule."""

    def __init__(self, probe, scene, box, h):
        self.probe = probe
        self.name = probe.name
        self.kind = probe.type if probe.type == "box" else probe.measure
        self.fields = fields_of(probe, scene)
        dim = scene.domain.dim
        self.dim = dim
        self.columns = [c for f in self.fields for c in column_names(f, dim)]
        self.every = probe.every or scene.output.probe_every or scene.output.every
        self.next = 0.0
        self.phases = np.array([PHASES.index(p) for p in probe.phases], dtype=np.uint8)
        self.stations = stations(probe)
        if self.kind == "box":
            self.lo, self.hi = np.array(probe.lo, float), np.array(probe.hi, float)
            self.size = len(_BOX_SUMS) + dim + 3
            return
        axes = range(dim - 1) if self.kind == "depth" else range(dim)
        self.query, self.station_of = _images(self.stations, box, support_radius(h), axes)
        # accumulator columns: V, m, then V f of each averaged component
        self.avg = [c for f in self.fields if f in AVERAGES for c in column_names(f, dim)]
        self.size = len(self.stations) * (2 + len(self.avg))

    def rewind(self, t: float, fresh: bool) -> None:
        """Schedule from time ``t``: due now (a fresh run), else at the next multiple of
        ``every`` after ``t``, as an uninterrupted run would be (see :func:`advance`)."""
        self.next = 0.0 if fresh else advance(t, self.every)


def advance(t: float, every: float) -> float:
    """The sample time after a sample at ``t``: the first multiple of ``every`` beyond it
    (a sample is due at the first step at or after its time, so ``t`` may pass it)."""
    return every * (math.floor(t / every + 1e-9) + 1)


def _images(points, box, reach, axes):
    """Stations and their periodic images within ``reach`` of a periodic boundary, with
    the station index of each row."""
    rows, owner = [points], [np.arange(len(points))]
    periodic = [a for a in axes if box.periodic[a]]
    lo, hi, length = np.array(box.lo), np.array(box.hi), np.array(box.hi) - np.array(box.lo)
    for shift in itertools.product((-1, 0, 1), repeat=len(periodic)):
        if not any(shift):
            continue
        keep = np.ones(len(points), dtype=bool)
        moved = points.copy()
        for a, s in zip(periodic, shift):
            # a station near hi sees particles near lo through the image at x - L
            near = points[:, a] > hi[a] - reach if s < 0 else points[:, a] < lo[a] + reach
            keep &= near
            moved[:, a] += s * length[a]
        rows.append(moved[keep])
        owner.append(np.flatnonzero(keep))
    return np.concatenate(rows), np.concatenate(owner).astype(np.int64)


# --------------------------------------------------------------------------- sampling

class Sampler:
    """The probes of a scene and one collective sample of any subset of them.

    Parameters
    ----------
    scene : Scene
        Its ``probes`` (validated) and ``domain``.
    box : decomposition.box.Box
        The domain (periodic axes).
    h : float
        Smoothing length (m).
    """

    def __init__(self, scene, box, h):
        self.dim = scene.domain.dim
        self.d = scene.domain.particle_size
        self.h = h
        self.items = [_Item(p, scene, box, h) for p in scene.probes]

    def due(self, t: float) -> list[int]:
        """Indices of the probes due at time ``t`` (the same on every rank)."""
        return [i for i, it in enumerate(self.items) if t >= it.next - 1e-9 * it.every]

    def sample(self, comm, particles, which) -> list[np.ndarray]:
        """Collective: the values of probes ``which`` from the owned particles.

        Returns
        -------
        list of ndarray
            Per probe, ``(n_stations, n_columns)`` in the order of its ``columns``
            (NaN where an average has no contributing particle).
        """
        data = _particle_data(particles, self.dim, self.d)
        parts = [self._partial(self.items[i], data) for i in which]
        total = global_sum(comm, np.concatenate([np.ravel(a) for a in parts] + [np.zeros(0)]))
        out, at = [], 0
        for i, part in zip(which, parts):
            out.append(self._finish(self.items[i], total[at:at + part.size].reshape(part.shape)))
            at += part.size
        return out

    # -- partial sums of this rank's owned particles
    def _partial(self, it, data):
        mine = np.isin(data["phase"], it.phases)
        if it.kind == "box":
            return _box_sums(it, data, mine, self.dim)
        n_st = len(it.stations)
        acc = np.zeros((n_st, 2 + len(it.avg)))
        x = data["x"]
        reach = support_radius(self.h)
        if it.kind == "depth":
            xq, xp = it.query[:, :-1], x[:, :-1]
            mine &= data["x"][:, -1] > it.query[:, -1].min()
        else:
            xq, xp = it.query, x
        mine &= np.all((xp >= xq.min(axis=0) - reach) & (xp <= xq.max(axis=0) + reach), axis=1)
        sel = np.flatnonzero(mine)
        if len(sel) == 0:
            return acc
        vals = np.empty((len(sel), 2 + len(it.avg)))
        vals[:, 0] = data["V"][sel]
        vals[:, 1] = data["m"][sel]
        for c, name in enumerate(it.avg):
            vals[:, 2 + c] = data["V"][sel] * data[name][sel]
        nq = len(it.query)
        pts = np.ascontiguousarray(np.concatenate([xq, xp[sel]]))
        indptr, indices = build_csr(pts, nq, reach)
        if it.kind == "depth":
            _column(pts, np.ascontiguousarray(it.query[:, -1]),
                    np.ascontiguousarray(x[sel, -1]), nq, it.station_of, indptr, indices, vals,
                    self.h, self.dim, _GL_X, _GL_W, acc)
        else:
            _interpolate(pts, nq, it.station_of, indptr, indices, vals, self.h, self.dim, acc)
        return acc

    def _finish(self, it, total):
        if it.kind == "box":
            return _box_values(it, total, self.dim)
        vol, mass = total[:, 0], total[:, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            avg = np.where(vol[:, None] > 0.0, total[:, 2:] / vol[:, None], np.nan)
        cols = []
        for f in it.fields:
            if f in ("volume_fraction", "depth"):
                cols.append(vol[:, None])
            elif f == "rho":
                cols.append(mass[:, None])
            else:
                names = column_names(f, self.dim)
                first = it.avg.index(names[0])
                cols.append(avg[:, first:first + len(names)])
        return np.concatenate(cols, axis=1)


def _particle_data(particles, dim, d) -> dict:
    """Per owned particle: position, mass, volume and every averaged field's components."""
    p = particles
    n = p.n_owned
    phase = p["phase"][:n]
    solid = phase == PHASE_SOLID
    vol = np.full(n, d ** dim)
    if "F" in p and solid.any():
        vol[solid] *= np.linalg.det(p["F"][:n][solid])
    v = p["v"][:n]
    zero = np.zeros(n)
    data = {"x": p["x"][:n], "m": p["m"][:n], "V": vol, "phase": phase,
            "p": p["p"][:n], "speed": np.sqrt((v * v).sum(axis=1)),
            "eps_p": p["eps_p"][:n], "porosity": p["porosity"][:n],
            "nu": np.where(phase == PHASE_FLUID, p["nu"][:n], 0.0) if "nu" in p else zero,
            "fluid_fraction": (phase == PHASE_FLUID).astype(float),
            "solid_fraction": solid.astype(float),
            "fluidised_fraction": (p["fluidised"][:n] == 1).astype(float)
            if "fluidised" in p else zero}
    for a in range(dim):
        data[f"v_{_AXES[a]}"] = v[:, a]
    sigma = -data["p"][:, None, None] * np.eye(3)
    if "tau" in p and solid.any():
        jac = vol[solid] / d ** dim
        sigma[solid] = p["tau"][:n][solid] / jac[:, None, None]
    index = {"x": 0, "y": 1, "z": 2}
    for c in _STRESS[dim]:
        data[f"sigma_{c}"] = sigma[:, index[c[0]], index[c[1]]]
    return data


def _box_sums(it, data, mine, dim):
    x = data["x"]
    inside = mine & np.all((x >= it.lo) & (x <= it.hi), axis=1)
    m, vol = data["m"][inside], data["V"][inside]
    v = np.stack([data[f"v_{_AXES[a]}"][inside] for a in range(dim)], axis=1)
    phase = data["phase"][inside]
    sums = [float(inside.sum()), m.sum(), vol.sum(), vol[phase == PHASE_FLUID].sum(),
            vol[phase == PHASE_SOLID].sum(),
            (vol * data["fluidised_fraction"][inside]).sum()]
    sums += list((m[:, None] * v).sum(axis=0))
    sums += [0.5 * (m * (v * v).sum(axis=1)).sum(), (vol * data["p"][inside]).sum(),
             (vol * data["eps_p"][inside]).sum()]
    return np.array([sums])


def _box_values(it, total, dim):
    t = total[0]
    named = dict(zip(_BOX_SUMS, t))
    mass, vol = named["mass"], named["volume"]
    nan = float("nan")
    mom = t[len(_BOX_SUMS):len(_BOX_SUMS) + dim]
    rest = t[len(_BOX_SUMS) + dim:]
    named["v"] = mom / mass if mass > 0 else np.full(dim, nan)
    named["kinetic_energy"] = rest[0]
    named["p"] = rest[1] / vol if vol > 0 else nan
    named["eps_p"] = rest[2] / vol if vol > 0 else nan
    return np.concatenate([np.atleast_1d(named[f]) for f in it.fields])[None, :]


# --------------------------------------------------------------------------- the run's probes

class ProbeOutput:
    """The probes of a run: schedule, collective samples, ``DIR/probes.csv`` on rank 0.

    Inert for a scene without probes (a new run then drops the probe files an earlier
    run left in ``DIR``). Samples are taken at the first step at or after each multiple
    of a probe's ``every`` (the steps are never cut to meet them); after a restart the
    schedule goes on from the checkpoint's time and the file is continued without
    duplicate rows (:class:`parsph.io.probes.ProbeWriter`) when ``continuing`` (a
    restart in its own directory); a branch into another directory starts its own.
    """

    def __init__(self, ctx, continuing):
        from decomposition import collective
        from parsph.io.probes import ProbeWriter, remove_stale

        scene, comm = ctx.scene, ctx.comm
        self.sampler = Sampler(scene, ctx.box, ctx.h) if scene.probes else None
        self.writer = None
        with collective(comm):
            if self.sampler is None:
                if comm.rank == 0 and not continuing:
                    remove_stale(ctx.out)
                return
            for it in self.sampler.items:
                it.rewind(ctx.time, fresh=not continuing)
            if comm.rank == 0:
                self.writer = ProbeWriter(ctx.out, self.sampler.items, ctx.dim,
                                          resume_time=ctx.time if continuing else None)

    def sample_due(self, ctx) -> None:
        """Collective: sample the probes due at ``ctx.time`` (every rank calls this)."""
        if self.sampler is None:
            return
        which = self.sampler.due(ctx.time)
        if not which:
            return
        t0 = time.perf_counter()
        with ctx.all_fields():  # the solid's volume and stress (F, tau)
            values = self.sampler.sample(ctx.comm, ctx.particles, which)
        for i, val in zip(which, values):
            it = self.sampler.items[i]
            if self.writer is not None:
                self.writer.write(ctx.time, it.name, it.columns, val)
            it.next = advance(ctx.time, it.every)
        ctx.timers["output"] = ctx.timers.get("output", 0.0) + time.perf_counter() - t0

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
