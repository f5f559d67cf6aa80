r"""The phase change's trigger over a window of the reference configuration
(docs/regularisation.md, "The trigger"): the shear strain of the deformation fitted over
the solid within R = :data:`WINDOW_IN_ELL` ℓ of each particle (:func:`window_strain`),
fitted again only when the velocity's spread over the window could have carried it to
the limit (:func:`window_spread`, :class:`WindowTrigger`). The zone that fluidises
around a slip surface is then set by ℓ, not by the particle size d.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from decomposition.reduce import global_any
from parsph.core.tensor import eigh3, inv3_into
from parsph.scene.materials import WINDOW_IN_ELL


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


def rows_near(X, points, R, box) -> np.ndarray:
    """The rows of ``X`` (n, dim) within R of one of ``points`` (m, dim), periodic axes of
    ``box`` by the minimum image (R below half a periodic length: only the nearest image
    of a point can reach a row), as a boolean mask; in O(n + m + pairs near) time and
    memory (:func:`mark_near`)."""
    n, dim = X.shape
    near = np.zeros(n, dtype=np.bool_)
    if not n or not len(points):
        return near
    shifts = box.image_shifts()
    P = (np.asarray(points, dtype=np.float64)[None, :, :] + shifts[:, None, :]).reshape(-1, dim)
    order, start, lo, cell, ncell, _ = bin_window(X, np.ones(n, dtype=bool), R, dim)
    mark_near(np.ascontiguousarray(X, dtype=np.float64), np.ascontiguousarray(P), float(R),
              dim, order, start, lo, cell, ncell, near)
    return near


@njit(cache=True)
def mark_near(X, P, R, dim, order, start, lo, cell, ncell, near):
    """Set ``near[r]`` for every row r of ``X`` (n, dim) within R of a point of ``P``
    (m, dim), through :func:`bin_window`'s cells of ``X`` (``order``, ``start``, ``lo``,
    ``cell``, ``ncell``): each point visits only the cells its ball reaches, so the cost is
    that of the rows near the points, not n x m, and nothing of size n x m is made."""
    R2 = R * R * (1.0 + 1e-12)
    a = np.zeros(3, dtype=np.int64)
    b = np.zeros(3, dtype=np.int64)
    for k in range(P.shape[0]):
        empty = False
        for ax in range(3):
            if ax < dim:
                a[ax] = max(int(np.floor((P[k, ax] - R - lo[ax]) / cell)), 0)
                b[ax] = min(int(np.floor((P[k, ax] + R - lo[ax]) / cell)), ncell[ax] - 1)
                empty = empty or a[ax] > b[ax]
            else:
                a[ax] = 0
                b[ax] = 0
        if empty:
            continue
        for i in range(a[0], b[0] + 1):
            for j in range(a[1], b[1] + 1):
                for c in range((i * ncell[1] + j) * ncell[2] + a[2],
                               (i * ncell[1] + j) * ncell[2] + b[2] + 1):
                    for s in range(start[c], start[c + 1]):
                        r = order[s]
                        if near[r]:
                            continue
                        d2 = 0.0
                        for ax in range(dim):
                            dx = X[r, ax] - P[k, ax]
                            d2 += dx * dx
                        if d2 < R2:
                            near[r] = True


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


@njit(cache=True, error_model="numpy")
def window_spread(order, start, ncell, per, vs, dim, cell_of, out):
    r"""The spread of the velocity over each owned row's window, into ``out``: a bound
    on :math:`|\mathbf v_j - \mathbf v_i|` over its targets, the norm of the range
    (largest less smallest) of each velocity component over the
    :math:`(2\,\mathrm{per} + 1)^3` cells around the row's cell ``cell_of`` (which hold
    its window, :func:`bin_window`); ``vs`` the targets' velocities in cell order. A
    body that translates has no spread, whatever its speed."""
    ncells = start.shape[0] - 1
    lo = np.full((ncells, 3), np.inf)
    hi = np.full((ncells, 3), -np.inf)
    for c in range(ncells):
        for q in range(start[c], start[c + 1]):
            for a in range(dim):
                lo[c, a] = min(lo[c, a], vs[q, a])
                hi[c, a] = max(hi[c, a], vs[q, a])
    # the range over the cells within per of each cell: a running min / max along
    # each axis in turn
    n0, n1, n2 = ncell[0], ncell[1], ncell[2]
    stride = (n1 * n2, n2, 1)
    size = (n0, n1, n2)
    tlo = np.empty_like(lo)
    thi = np.empty_like(hi)
    for axis in range(3):
        if size[axis] == 1:
            continue
        for c in range(ncells):
            k = (c // stride[axis]) % size[axis]
            for a in range(dim):
                tlo[c, a] = lo[c, a]
                thi[c, a] = hi[c, a]
            for o in range(max(k - per, 0), min(k + per, size[axis] - 1) + 1):
                e = c + (o - k) * stride[axis]
                for a in range(dim):
                    tlo[c, a] = min(tlo[c, a], lo[e, a])
                    thi[c, a] = max(thi[c, a], hi[e, a])
        lo, tlo = tlo, lo
        hi, thi = thi, hi
    for i in range(cell_of.shape[0]):
        c = cell_of[i]
        s = 0.0
        for a in range(dim):
            if hi[c, a] > lo[c, a]:
                s += (hi[c, a] - lo[c, a]) ** 2
        out[i] = math.sqrt(s)


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

    A row's window is evaluated again only when it could have reached the limit. Between
    two steps the positions move by ``dt v``, so the fit's B changes by at most
    ``dt s`` times the sum of ``w |X_ij|`` over the window, ``s`` the spread of the
    velocity over the window (:func:`window_spread`: the norm of each component's
    range over the cells that hold it, a bound on ``|v_j - v_i|``); the fit's strain by
    at most ``2 f gain`` times that (:func:`window_strain`: its gain, a factor 2 for
    the logarithm). Each row sums ``dt s`` over the steps since its evaluation
    (``trigger_reach``, m), and is due once ``value + 2 f gain reach`` reaches
    ``limit``: the trigger fires at the step it would with an evaluation every step.
    A part of the slope that slides as a block is not due however fast it goes (its
    spread is small); with the solid's largest speed as the bound (the rule before),
    nine in ten rows of the sliding slab had been fitted every eight steps. The
    window's velocities and positions cross the ranks each step where some rank has a
    candidate. Per-row state (solid fields, so views, migration and checkpoints carry
    it): ``eps_trigger`` (the value at the row's last evaluation), ``trigger_time``
    (when), ``trigger_rate`` (``2 f gain``), ``trigger_reach`` (infinite until a first
    evaluation, so a checkpoint without it evaluates every candidate once).

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
    FIELDS = ("eps_trigger", "trigger_time", "trigger_rate", "trigger_reach")
    #: Their initial values where not zero.
    FILL = {"trigger_reach": np.inf}

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
        # each owned row's cell, as window_strain finds it
        _, _, lo, cell, ncell, _ = self.cells
        idx = np.zeros((n, 3), dtype=np.int64)
        idx[:, : vctx.dim] = np.floor((self.X[:n, : vctx.dim] - lo[: vctx.dim]) / cell)
        idx = np.clip(idx, 0, ncell - 1)
        self.cell_of = (idx[:, 0] * ncell[1] + idx[:, 1]) * ncell[2] + idx[:, 2]

    def targets_left(self, vctx, X_left) -> None:
        """The owned rows whose window held one of the solid rows that left it (their
        reference positions ``X_left``, (m, dim), every rank's; the positions the window
        was fitted from, ``x_settled`` after a geostatic stage) are due at the next step:
        their fit lost targets without moving. Call after :meth:`build`."""
        p, n = vctx.particles, vctx.particles.n_owned
        if not len(X_left) or not n:
            return
        p["trigger_reach"][:n][rows_near(self.X[:n], X_left, self.R, vctx.box)] = np.inf

    def strain(self, vctx, limit, t, dt, out) -> None:
        """Collective: the trigger strain of the owned solid rows into ``out`` (n_owned):
        the window strain of the candidates (:data:`CANDIDATE`) at their last evaluation,
        their own accumulated plastic strain where R = 0, else 0. ``t`` the time (s),
        ``dt`` the step that led there (s): the rows' reach grows by ``dt`` times the
        spread of the velocity over their window (the class docstring)."""
        p, n = vctx.particles, vctx.particles.n_owned
        material = np.maximum(p["material"][:n], 0)
        R_row = self.radius_of[material]
        eps = p["eps_p"][:n]
        if "eps_p_geostatic" in p:  # the geostatic stage's does not count
            eps = eps - p["eps_p_geostatic"][:n]
        value, t_e, rate, reach = (p[k][:n] for k in self.FIELDS)
        cand = self.sel[:n] & (R_row > 0.0) & (eps > self.CANDIDATE * limit)
        if global_any(vctx.comm, cand.any()):  # the window's velocities: collective
            moved = self.halo.exchange({"v": p["v"][:n], "x": p["x"][:n]}, shift_fields=("x",))
            v = np.concatenate([p["v"][:n], moved["v"]])
            spread = np.zeros(n)
            order, start, _, _, ncell, per = self.cells
            window_spread(order, start, ncell, per, np.ascontiguousarray(v[order]), vctx.dim,
                          self.cell_of, spread)
            reach += dt * spread
        with np.errstate(invalid="ignore"):  # rate 0 (never fitted) times reach inf
            due = cand & (np.isinf(reach) | (value + rate * reach >= limit))
        rows = np.flatnonzero(due)
        if len(rows):
            x = np.ascontiguousarray(np.concatenate([p["x"][:n], moved["x"]]))
            val = np.zeros(len(rows))
            gain = np.zeros(len(rows))
            window_strain(rows, self.X, x, *self.cells, self.Xs,
                          np.ascontiguousarray(x[self.cells[0]]), self.R, vctx.dim, val, gain)
            f = self.factor_of[material[rows]]
            value[rows] = f * val
            t_e[rows] = t
            rate[rows] = 2.0 * f * gain
            reach[rows] = 0.0
        out[:] = np.where(self.sel[:n] & (R_row <= 0.0), eps, np.where(cand, value, 0.0))
