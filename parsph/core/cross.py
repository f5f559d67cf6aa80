"""Neighbours across two point sets: for each query point, the target points within reach.

:func:`parsph.core.neighbours.build_csr` finds the neighbours of its query rows among
*all* rows, queries included, and its fill pass visits every row: a search for the wall
particles near a solid (the solid's wall contact) paid for every solid–solid pair and a
pass over the walls too (0.1 s per step of a 3.1e4-particle 3D coupled tank, as much
as the neighbour lists of the whole step). Here only the targets are binned, on the
same cells (:mod:`parsph.core.cells`, the same pruned slot ranges),
and each query scans the target slots around it: the cost is the queries' candidate
targets. A pair is a neighbour pair under the same test as ``build_csr`` (squared
distance, summed over the axes in order, strictly below ``radius**2``), so the lists
hold exactly the target neighbours ``build_csr`` would give, in ascending order.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from parsph.core.cells import (_binned, _checked_box, _pad_coords, _ranges, cell_of,
                               reachable_cells)

__all__ = ["build_cross_csr"]

#: Up to this many query-target pairs the lists come from a direct double loop: the cell
#: search's set-up (bounds, binning, slot ranges, two passes) cost 110 µs of a 2D
#: coupled step's wall contact at 24 solids by 63 walls, where the loop takes a few; at
#: ~1 ns a pair its limit costs less than that set-up.
DIRECT_PAIRS = 1 << 14


def build_cross_csr(xq, xt, radius):
    """Neighbour lists of the query points ``xq`` among the target points ``xt``.

    Parameters
    ----------
    xq, xt : array_like, shape (Nq, dim) and (Nt, dim)
        Query and target positions (the same ``dim``, 1 to 3), finite.
    radius : float
        Search radius (> 0).

    Returns
    -------
    indptr : numpy.ndarray of int64, shape (Nq + 1,)
    indices : numpy.ndarray of int32
        Target rows (into ``xt``) within ``radius`` of each query, ascending.

    Raises
    ------
    ValueError
        On bad shapes, different dimensions, a non-positive radius or non-finite
        positions.
    """
    xq, lq, hq, _ = _checked_box(xq)
    xt, lt, ht, _ = _checked_box(xt)
    if xq.shape[1] != xt.shape[1]:
        raise ValueError(f"query and target points differ in dimension: {xq.shape[1]} and "
                         f"{xt.shape[1]}")
    radius = float(radius)
    if not (radius > 0.0 and np.isfinite(radius)):
        raise ValueError(f"search radius must be a positive finite number, got {radius!r}")
    nq, nt = xq.shape[0], xt.shape[0]
    indptr = np.zeros(nq + 1, dtype=np.int64)
    if nq == 0 or nt == 0:
        return indptr, np.empty(0, dtype=np.int32)
    if nq * nt <= DIRECT_PAIRS:
        return indptr, _direct(xq, xt, radius * radius, indptr)
    # one grid over both sets (a query outside the targets' box still finds its cells)
    lo3, hi3 = np.minimum(lq, lt), np.maximum(hq, ht)
    extent = max(float(hi3[a]) - float(lo3[a]) for a in range(3))
    order, _, xs, grid = _binned(xt, lo3, hi3, extent, radius)
    qp, _ = _pad_coords(xq, lo3, grid[1], grid[2])
    r2max = radius * radius
    # the queries with no target in the cells within reach are not searched: the solids
    # of a coupled scene that touch no wall (most of them) had cost a pruned range search
    # each, twice, 11 of the 16 ms of a 3D tank's wall contact (112,761 particles)
    near = reachable_cells(np.ones(len(xt), dtype=np.uint8), *grid[2:6])
    _cross_pass(qp, xs, order, r2max, *grid, indptr, np.empty(0, dtype=np.int32), near,
                False)
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    _cross_pass(qp, xs, order, r2max, *grid, indptr, indices, near, True)
    return indptr, indices


@njit(cache=True, error_model="numpy")
def _direct(xq, xt, r2max, indptr):
    """Every query against every target, under the cell search's test (squared distance
    summed over the axes in order: the padded axes of :func:`_cross_pass` add exact
    zeros first), in two passes: ``indptr`` counted in place, then the targets of each
    query, ascending, returned."""
    for fill in (False, True):
        if fill:
            indices = np.empty(indptr[-1], dtype=np.int32)
        else:
            indices = np.empty(0, dtype=np.int32)
        for i in range(xq.shape[0]):
            c = indptr[i]
            for t in range(xt.shape[0]):
                r2 = 0.0
                for a in range(xq.shape[1]):
                    d = xt[t, a] - xq[i, a]
                    r2 += d * d
                if r2 < r2max:
                    if fill:
                        indices[c] = t
                    c += 1
            if not fill:
                indptr[i + 1] = c
    return indices


@njit(cache=True, error_model="numpy")
def _cross_pass(qp, xs, order, r2max, lo, inv_cell, ncell, reach, sparse, start, cells,
                cell_start, indptr, indices, near, fill):
    """The count pass (``fill`` False: ``indptr`` from the number of targets within reach
    of each query) or the fill pass (each query's targets, rows of the caller's array,
    sorted ascending into ``indices``) over the same candidate ranges and test. Queries
    in a cell without targets within reach (``near``, :func:`reachable_cells`; empty:
    none known), and in the fill pass those the count found no target for, are not
    searched."""
    w = 2 * reach + 1
    rng = np.empty((w * w, 2), dtype=np.int64)
    gap2 = np.empty((3, w))
    for i in range(qp.shape[0]):
        if (near.shape[0] and not near[cell_of(qp, i, lo, inv_cell, ncell)]) or (
                fill and indptr[i + 1] == indptr[i]):
            if not fill:
                indptr[i + 1] = indptr[i]
            continue
        nr = _ranges(qp, i, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start,
                     gap2, rng)
        c = indptr[i]
        for k in range(nr):
            for t in range(rng[k, 0], rng[k, 1]):
                d0 = xs[t, 0] - qp[i, 0]
                d1 = xs[t, 1] - qp[i, 1]
                d2 = xs[t, 2] - qp[i, 2]
                if d0 * d0 + d1 * d1 + d2 * d2 < r2max:
                    if fill:
                        indices[c] = order[t]
                    c += 1
        if not fill:
            indptr[i + 1] = c
            continue
        # insertion sort of the row (a few tens of entries, nearly sorted by cell)
        for a in range(indptr[i] + 1, c):
            v = indices[a]
            b = a - 1
            while b >= indptr[i] and indices[b] > v:
                indices[b + 1] = indices[b]
                b -= 1
            indices[b + 1] = v
