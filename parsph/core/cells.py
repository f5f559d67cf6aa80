"""The cell grid of the neighbour searches: binning, and the slot ranges within reach.

Steps 1-3 of the algorithm in :mod:`parsph.core.neighbours` (cells of side ``radius``,
a counting sort of the rows into them, and for one particle the pruned cells around it
as contiguous slot ranges), shared by :func:`parsph.core.neighbours.build_csr` and
:func:`parsph.core.cross.build_cross_csr`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Dense grids are allowed up to ``_DENSE_PER_PARTICLE * N + _DENSE_MIN`` cells.
_DENSE_PER_PARTICLE = 16
_DENSE_MIN = 1 << 16
#: Cells per axis are capped (coarser cells beyond) so coordinates stay exact int64.
_MAX_CELLS_PER_AXIS = 1 << 50
#: Cells are ``radius / _REACH`` wide and the search spans ``_REACH`` cells each way.
#: Finer cells (2, 3) cut the candidates (134, 101 against 262 per particle on a 3D
#: lattice, h = 1.2 d) but cost more in range set-up: not faster when measured.
_REACH = 1

_EPS = float(np.finfo(np.float64).eps)  # (np.finfo per call: 5 us of each search)


@njit(cache=True, error_model="numpy")
def _bounds(x):
    """Per-axis minimum and maximum of ``x`` and whether all entries are finite."""
    n, dim = x.shape
    lo = np.empty(dim)
    hi = np.empty(dim)
    for a in range(dim):
        lo[a] = np.inf
        hi[a] = -np.inf
    finite = True
    for i in range(n):
        for a in range(dim):
            v = x[i, a]
            if not np.isfinite(v):
                finite = False
            if v < lo[a]:
                lo[a] = v
            if v > hi[a]:
                hi[a] = v
    return lo, hi, finite


@njit(cache=True, error_model="numpy")
def reachable_cells(flag_s, ncell, reach, sparse, start):
    """Per cell of the dense grid (linear id, as :func:`_ranges` numbers them): 1 when a
    slot with ``flag_s`` set lies in the cells within ``reach`` cells of it along every
    axis, the cells :func:`_ranges` may search; 0 when none does, so a particle in that
    cell finds no flagged neighbour and need not be searched. Empty with the sparse grid
    (every particle is searched)."""
    if sparse:
        return np.zeros(0, dtype=np.uint8)
    occ = np.zeros(ncell[0] * ncell[1] * ncell[2], dtype=np.uint8)
    for c in range(occ.shape[0]):
        for t in range(start[c], start[c + 1]):
            if flag_s[t]:
                occ[c] = 1
                break
    # dilated by reach along the last axis, then the middle, then the first
    for axis in (2, 1, 0):
        occ = _dilated(occ, ncell, reach, axis)
    return occ


@njit(cache=True, error_model="numpy")
def _dilated(occ, ncell, reach, axis):
    """The cell flags ``occ`` of the dense grid spread to the cells within ``reach`` of a
    flagged one along ``axis`` (a new array)."""
    out = np.zeros_like(occ)
    n = ncell[axis]
    stride = 1
    for b in range(axis + 1, 3):
        stride *= ncell[b]
    for c in range(occ.shape[0]):
        if occ[c]:
            k = (c // stride) % n
            for e in range(max(k - reach, 0), min(k + reach, n - 1) + 1):
                out[c + (e - k) * stride] = 1
    return out


@njit(cache=True, error_model="numpy", inline="always")
def cell_of(x, i, lo, inv_cell, ncell):
    """Linear id of the dense-grid cell of the padded position ``x[i]`` (as
    :func:`_pad_coords` and :func:`_ranges` compute it)."""
    c0 = min(max(np.int64((x[i, 0] - lo[0]) * inv_cell), 0), ncell[0] - 1)
    c1 = min(max(np.int64((x[i, 1] - lo[1]) * inv_cell), 0), ncell[1] - 1)
    c2 = min(max(np.int64((x[i, 2] - lo[2]) * inv_cell), 0), ncell[2] - 1)
    return (c0 * ncell[1] + c1) * ncell[2] + c2


def _cell_size(radius, extent, reach):
    """Cell side: ``radius / reach`` enlarged by the rounding margin of the grid.

    Cell coordinates ``(x - lo) / cell`` carry a rounding error of about
    ``2 eps (extent / cell + 1)`` cells, and the squared-distance test admits pairs up
    to ``radius (1 + 2 eps)``; enlarging the cell by a relative ``delta`` larger than
    both keeps every neighbour within ``reach`` cells along each axis (and within the
    pruning distance of :func:`_ranges`). Cells are also made coarse enough for at most
    ``_MAX_CELLS_PER_AXIS`` cells per axis.
    """
    delta = max(1e-12, 8.0 * _EPS * (extent / radius + 2.0))
    return max(radius * (1.0 + delta) / reach, extent / float(_MAX_CELLS_PER_AXIS - 2))


@njit(cache=True, error_model="numpy")
def _pad_coords(x, lo, inv_cell, ncell):
    """Padded (N, 3) positions and clamped integer (N, 3) cell coordinates.

    ``lo`` and ``ncell`` are padded to 3 axes (leading axes: 0 and 1); the cell of a
    position is computed exactly as in :func:`_ranges`.
    """
    n, dim = x.shape
    off = 3 - dim
    xp = np.zeros((n, 3))
    cc = np.zeros((n, 3), dtype=np.int64)
    for i in range(n):
        for a in range(dim):
            xp[i, off + a] = x[i, a]
        for b in range(3):
            c = np.int64((xp[i, b] - lo[b]) * inv_cell)
            cc[i, b] = min(max(c, 0), ncell[b] - 1)
    return xp, cc


@njit(cache=True, error_model="numpy")
def _sort_dense(x, lo, inv_cell, ncell):
    """Counting sort by linear cell id over the dense grid, the positions padded to 3 axes
    and binned as :func:`_pad_coords` does, without its (N, 3) copies (48 bytes per row
    at the peak of a step's neighbour search).

    Returns ``order`` (slot -> row), ``rank_of`` (row -> slot), ``xs`` (padded
    positions in slot order, shape (N, 3) in column order) and ``start`` (``ncells +
    1``): the slots of linear cell ``c`` are ``start[c]:start[c + 1]``.
    """
    n, dim = x.shape
    off = 3 - dim
    n1, n2 = ncell[1], ncell[2]
    ntot = ncell[0] * n1 * n2
    start = np.zeros(ntot + 1, dtype=np.int64)
    cid = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = np.int64(0)
        for b in range(3):
            v = x[i, b - off] if b >= off else 0.0
            cb = min(max(np.int64((v - lo[b]) * inv_cell), 0), ncell[b] - 1)
            c = c * ncell[b] + cb
        cid[i] = c
        start[c + 1] += 1
    for c in range(ntot):
        start[c + 1] += start[c]
    order = np.empty(n, dtype=np.int32)
    rank_of = np.empty(n, dtype=np.int32)
    xs = np.zeros((3, n)).T  # column order: a range's distance test vectorises (_count)
    for i in range(n):
        c = cid[i]
        s = start[c]  # start[c] is the cursor of cell c here, restored below
        start[c] = s + 1
        order[s] = i
        rank_of[i] = s
        for a in range(dim):
            xs[s, off + a] = x[i, a]
    for c in range(ntot, 0, -1):  # each cursor ended at the next cell's start
        start[c] = start[c - 1]
    start[0] = 0
    return order, rank_of, xs, start


def _sort_sparse(xp, cc):
    """Lexicographic sort by cell coordinates (memory O(N) for any box).

    Returns ``order``, ``rank_of``, ``xs`` as :func:`_sort_dense`, the occupied cells'
    coordinates ``cells`` (n_occupied, 3), sorted lexicographically, and
    ``cell_start`` (n_occupied + 1): the slots of occupied cell ``u``.
    """
    n = xp.shape[0]
    order = np.lexsort((cc[:, 2], cc[:, 1], cc[:, 0]))
    sc = cc[order]
    new = np.empty(n, dtype=bool)
    new[0] = True
    np.any(sc[1:] != sc[:-1], axis=1, out=new[1:])
    first = np.flatnonzero(new)
    cells = np.ascontiguousarray(sc[first])
    cell_start = np.append(first, n).astype(np.int64)
    rank_of = np.empty(n, dtype=np.int32)
    rank_of[order] = np.arange(n, dtype=np.int32)
    xs = np.empty((3, n)).T  # in column order, as _sort_dense's
    for a in range(3):
        xs[:, a] = xp[order, a]
    return order.astype(np.int32), rank_of, xs, cells, cell_start


@njit(cache=True, error_model="numpy")
def _lex_less(cells, u, a, b, c):
    """Whether occupied cell ``u`` precedes the coordinate triple (a, b, c)."""
    if cells[u, 0] != a:
        return cells[u, 0] < a
    if cells[u, 1] != b:
        return cells[u, 1] < b
    return cells[u, 2] < c


@njit(cache=True, error_model="numpy")
def _lower_bound(cells, a, b, c):
    """First occupied cell not preceding (a, b, c) (binary search)."""
    lo = 0
    hi = cells.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if _lex_less(cells, mid, a, b, c):
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, error_model="numpy")
def _ranges(xs, s, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start, gap2, rng):
    """Slot ranges holding every possible neighbour of slot ``s``; returns their number.

    The cells within ``reach`` cells of the particle's own cell are pruned to those
    whose distance from the particle is below ``reach`` cells (the search radius plus
    the rounding margin of :func:`_cell_size`); along the last axis the surviving cells
    of a column are contiguous in slot order, giving one range ``rng[k]`` per column.
    ``gap2`` is scratch of shape (3, 2 reach + 1).
    """
    r2c = float(reach * reach)
    c0 = 0
    c1 = 0
    c2 = 0
    for ax in range(3):
        # squared distance, in cell units, from the particle to the cells at offset
        # -reach..reach along axis ``ax``; the cell is computed as in _pad_coords
        g = (xs[s, ax] - lo[ax]) * inv_cell
        c = min(max(np.int64(g), 0), ncell[ax] - 1)
        gap2[ax, reach] = 0.0
        for d in range(1, reach + 1):
            up = (c + d) - g
            up = up if up > 0.0 else 0.0
            dn = g - (c - d + 1)
            dn = dn if dn > 0.0 else 0.0
            gap2[ax, reach + d] = up * up
            gap2[ax, reach - d] = dn * dn
        if ax == 0:
            c0 = c
        elif ax == 1:
            c1 = c
        else:
            c2 = c
    n1 = ncell[1]
    n2 = ncell[2]
    k = 0
    # branch-free pruning: a pruned column gives an empty range, which is not kept
    for a in range(max(c0 - reach, 0), min(c0 + reach, ncell[0] - 1) + 1):
        ga = gap2[0, a - c0 + reach]
        for b in range(max(c1 - reach, 0), min(c1 + reach, n1 - 1) + 1):
            gab = ga + gap2[1, b - c1 + reach]
            n_lo = 0
            n_hi = 0
            for d in range(1, reach + 1):
                n_lo += gab + gap2[2, reach - d] < r2c
                n_hi += gab + gap2[2, reach + d] < r2c
            z_lo = max(c2 - n_lo, 0)
            z_hi = min(c2 + n_hi, n2 - 1) + 1  # exclusive
            if gab >= r2c:
                z_hi = z_lo
            if sparse:
                first = cell_start[_lower_bound(cells, a, b, z_lo)]
                last = cell_start[_lower_bound(cells, a, b, z_hi)]
            else:
                base = (a * n1 + b) * n2
                first = start[base + z_lo]
                last = start[base + z_hi]
            rng[k, 0] = first
            rng[k, 1] = last
            k += last > first
    return k


def _checked_box(x):
    """C-contiguous float64 positions and their padded (3,) bounding box.

    Raises ``ValueError`` on a bad shape, non-finite entries or a span beyond float64.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] not in (1, 2, 3):
        raise ValueError(f"positions must have shape (N, dim) with dim 1, 2 or 3, got {x.shape}")
    dim = x.shape[1]
    lo3 = np.zeros(3)
    hi3 = np.zeros(3)
    if x.shape[0]:
        lo, hi, finite = _bounds(x)
        if not finite:
            raise ValueError("positions contain NaN or infinity")
        lo3[3 - dim:] = lo
        hi3[3 - dim:] = hi
    # Python floats: a span beyond float64 is inf, without numpy's overflow warning
    extent = max(float(hi3[0]) - float(lo3[0]), float(hi3[1]) - float(lo3[1]),
                 float(hi3[2]) - float(lo3[2]))
    if not math.isfinite(extent):
        raise ValueError("positions span a range too large for float64")
    return x, lo3, hi3, extent


def _binned(x, lo3, hi3, extent, radius):
    """The rows of ``x`` sorted into the cells of the box ``lo3``..``hi3`` (extent
    ``extent``) for ``radius``: ``order`` (slot -> row), ``rank_of`` (row -> slot), ``xs``
    (padded positions in slot order) and ``grid``, the arguments of :func:`_ranges` after
    the position (dense grid, or sorted occupied cells when it would be too large)."""
    reach = _REACH
    cell = _cell_size(radius, extent, reach)
    ncell = np.array([math.floor((float(hi3[a]) - float(lo3[a])) / cell) + 1 for a in range(3)],
                     dtype=np.int64)
    n_dense = int(ncell[0]) * int(ncell[1]) * int(ncell[2])  # Python ints: exact
    sparse = n_dense > _DENSE_PER_PARTICLE * x.shape[0] + _DENSE_MIN
    inv_cell = 1.0 / cell
    if sparse:
        order, rank_of, xs, cells, cell_start = _sort_sparse(*_pad_coords(x, lo3, inv_cell,
                                                                          ncell))
        start = np.zeros(1, dtype=np.int64)
    else:
        order, rank_of, xs, start = _sort_dense(x, lo3, inv_cell, ncell)
        cells = np.zeros((1, 3), dtype=np.int64)
        cell_start = np.zeros(1, dtype=np.int64)
    return order, rank_of, xs, (lo3, inv_cell, ncell, reach, sparse, start, cells, cell_start)
