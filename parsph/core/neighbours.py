r"""Cell-linked-list neighbour search producing CSR neighbour lists.

Every SPH sum of the paper (e.g. the density summation, eq. (33), and the fluid terms,
eqs. (34)-(36)) runs over the particles :math:`j` within the kernel support
:math:`|\mathbf{x}_i - \mathbf{x}_j| < 2h` of particle :math:`i`. :func:`build_csr`
finds them for the query rows ``x[:n_query]`` (the owned particles) among all rows of
``x`` (owned followed by halo copies) and returns them in compressed sparse row form:
the neighbours of row ``i`` are ``indices[indptr[i]:indptr[i + 1]]``.

Algorithm
---------
1. Bounding box of ``x``; cubic cells of side ``radius`` (enlarged by a relative
   margin that absorbs floating-point rounding, see :func:`_cell_size`), so that every
   neighbour of a particle lies in one of the :math:`3^D` cells around its own.
   Dimensions below 3 are padded with leading zero coordinates: one 3D code path
   serves 1D, 2D and 3D.
2. Particles are sorted by cell with a counting sort over the dense grid (or, when
   that grid would be too large, a lexicographic sort of the integer cell coordinates)
   and their positions copied in that order ("slots").
3. For a particle, the adjacent cells are pruned to those whose distance from the
   particle (not from its cell) is below the radius; the surviving cells of a column
   along the last axis are contiguous in slot order, so they are scanned as at most
   :math:`3^{D-1}` contiguous slot ranges. On a 3D lattice with radius 2.4 d this
   leaves about 5 candidates per neighbour instead of 7.
4. Count pass (query rows, in slot order, branch-free): ``indptr``. Fill pass: every
   row ``j`` in ascending order appends ``j`` to the rows of its query neighbours
   (pairs are symmetric), so each row comes out sorted ascending without a sort. When
   the rows are in a spatially incoherent order and the lists are large, these
   scattered writes miss the caches; the fill then gathers each query row and sorts
   it instead. Either way the result is the same and does not depend on the internal
   order (deterministic).

Performance depends on the row order of ``x``: rows in a spatially coherent order (as
created on a lattice, or after :func:`cell_order`) are searched 1.5-2x faster than a
random order, and the loops over the lists gain as much or more.

A pair is a neighbour pair when the squared distance, summed over the axes in order,
is strictly below ``radius**2``; a particle is never its own neighbour, while a distinct
row at the same position (a duplicate) is.

Memory is O(N + pairs): the dense grid is used only while it has at most
``16 N + 65536`` cells; beyond that (points spread over a box that is huge compared with
``radius``) the occupied cells are found by binary search in the sorted list of
occupied cells, at the same cell size. Periodicity is not handled here (periodic images
are halo rows).
"""
from __future__ import annotations

import operator

import numpy as np
from numba import njit

__all__ = ["build_csr", "cell_order", "pair_count", "row_lengths", "row_of_pairs"]

#: Dense grids are allowed up to ``_DENSE_PER_PARTICLE * N + _DENSE_MIN`` cells.
_DENSE_PER_PARTICLE = 16
_DENSE_MIN = 1 << 16
#: Cells per axis are capped (coarser cells beyond) so coordinates stay exact int64.
_MAX_CELLS_PER_AXIS = 1 << 50
_INT32_MAX = np.iinfo(np.int32).max
#: Cells are ``radius / _REACH`` wide and the search spans ``_REACH`` cells each way.
#: Finer cells (2, 3) cut the candidates (134, 101 against 262 per particle on a 3D
#: lattice, h = 1.2 d) but cost more in range set-up: not faster when measured.
_REACH = 1
#: The fill pass scatters (rows come out sorted) unless the rows are in a spatially
#: incoherent order and the lists outgrow the caches; then it gathers and sorts each
#: row, which measured 2x faster for 1e6 particles in random order (same result).
_GATHER_MIN_PAIRS = 1 << 24
_GATHER_DISORDER = 0.08


# --------------------------------------------------------------------------- helpers


@njit(cache=True)
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


def _cell_size(radius, extent, reach):
    """Cell side: ``radius / reach`` enlarged by the rounding margin of the grid.

    Cell coordinates ``(x - lo) / cell`` carry a rounding error of about
    ``2 eps (extent / cell + 1)`` cells, and the squared-distance test admits pairs up
    to ``radius (1 + 2 eps)``; enlarging the cell by a relative ``delta`` larger than
    both keeps every neighbour within ``reach`` cells along each axis (and within the
    pruning distance of :func:`_ranges`). Cells are also made coarse enough for at most
    ``_MAX_CELLS_PER_AXIS`` cells per axis.
    """
    eps = np.finfo(np.float64).eps
    delta = max(1e-12, 8.0 * eps * (extent / radius + 2.0))
    return max(radius * (1.0 + delta) / reach, extent / float(_MAX_CELLS_PER_AXIS - 2))


@njit(cache=True)
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


@njit(cache=True)
def _sort_dense(xp, cc, ncell):
    """Counting sort by linear cell id over the dense grid.

    Returns ``order`` (slot -> row), ``rank_of`` (row -> slot), ``xs`` (padded
    positions in slot order) and ``start`` (``ncells + 1``): the slots of linear cell
    ``c`` are ``start[c]:start[c + 1]``.
    """
    n = xp.shape[0]
    n1, n2 = ncell[1], ncell[2]
    ntot = ncell[0] * n1 * n2
    start = np.zeros(ntot + 1, dtype=np.int64)
    cid = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = (cc[i, 0] * n1 + cc[i, 1]) * n2 + cc[i, 2]
        cid[i] = c
        start[c + 1] += 1
    for c in range(ntot):
        start[c + 1] += start[c]
    cursor = start[:-1].copy()
    order = np.empty(n, dtype=np.int32)
    rank_of = np.empty(n, dtype=np.int32)
    xs = np.empty((n, 3))
    for i in range(n):
        s = cursor[cid[i]]
        cursor[cid[i]] = s + 1
        order[s] = i
        rank_of[i] = s
        xs[s, 0] = xp[i, 0]
        xs[s, 1] = xp[i, 1]
        xs[s, 2] = xp[i, 2]
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
    xs = np.ascontiguousarray(xp[order])
    return order.astype(np.int32), rank_of, xs, cells, cell_start


@njit(cache=True)
def _lex_less(cells, u, a, b, c):
    """Whether occupied cell ``u`` precedes the coordinate triple (a, b, c)."""
    if cells[u, 0] != a:
        return cells[u, 0] < a
    if cells[u, 1] != b:
        return cells[u, 1] < b
    return cells[u, 2] < c


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def _count(xs, order, n_query, r2max, lo, inv_cell, ncell, reach, sparse, start, cells,
           cell_start, indptr, act_s, keep, keep_s):
    """First pass, query rows in slot order: ``indptr`` from the neighbour counts.

    ``act_s`` (the running count of active slots, ``act_s[t]`` active slots before slot
    ``t``; empty: every row active): a query row that is not active keeps its list
    (``keep[i] = keep_s[s] = 1``) only when an active row is among its neighbours, and
    gets an empty one otherwise; one whose cells hold no active slot is not searched."""
    n = xs.shape[0]
    w = 2 * reach + 1
    rng = np.empty((w * w, 2), dtype=np.int64)
    gap2 = np.empty((3, w))
    for s in range(n):
        i = order[s]
        if i >= n_query:
            continue
        nr = _ranges(xs, s, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start, gap2,
                     rng)
        x0 = xs[s, 0]
        x1 = xs[s, 1]
        x2 = xs[s, 2]
        cnt = 0
        if act_s.shape[0] == 0 or act_s[s + 1] > act_s[s]:
            for k in range(nr):
                for t in range(rng[k, 0], rng[k, 1]):
                    d0 = xs[t, 0] - x0
                    d1 = xs[t, 1] - x1
                    d2 = xs[t, 2] - x2
                    cnt += d0 * d0 + d1 * d1 + d2 * d2 < r2max
            keep[i] = 1
        else:  # an inactive row: a list only if an active row is within reach
            near = 0
            for k in range(nr):
                near += act_s[rng[k, 1]] - act_s[rng[k, 0]]
            wet = 0
            if near > 0:
                for k in range(nr):
                    for t in range(rng[k, 0], rng[k, 1]):
                        d0 = xs[t, 0] - x0
                        d1 = xs[t, 1] - x1
                        d2 = xs[t, 2] - x2
                        inside = d0 * d0 + d1 * d1 + d2 * d2 < r2max
                        cnt += inside
                        wet += inside & (act_s[t + 1] > act_s[t])
            keep[i] = wet > 0
            cnt = cnt if wet > 0 else 1
        keep_s[s] = keep[i]
        # the particle itself (own cell, distance 0 < r2max) was counted once
        indptr[i + 1] = cnt - 1
    indptr[0] = 0
    for i in range(n_query):
        indptr[i + 1] += indptr[i]


@njit(cache=True)
def _fill(xs, order, rank_of, n_query, r2max, lo, inv_cell, ncell, reach, sparse, start,
          cells, cell_start, indptr, indices, keep, kept):
    """Second pass, all rows ``j`` in ascending order: append ``j`` to its query rows.

    Visiting ``j`` in ascending order fills every row already sorted, with no sort.
    ``kept`` (empty: every query row keeps its list) is the running count of the slots
    whose rows keep their lists: a ``j`` with none in its cells is not searched.
    """
    n = xs.shape[0]
    w = 2 * reach + 1
    rng = np.empty((w * w, 2), dtype=np.int64)
    gap2 = np.empty((3, w))
    cursor = indptr[:-1].copy()
    hits = np.empty(64, dtype=np.int64)
    for j in range(n):
        s = rank_of[j]
        nr = _ranges(xs, s, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start, gap2,
                     rng)
        ncand = 0
        for k in range(nr):
            ncand += rng[k, 1] - rng[k, 0]
        if kept.shape[0]:
            wanted = 0
            for k in range(nr):
                wanted += kept[rng[k, 1]] - kept[rng[k, 0]]
            if wanted == 0:
                continue
        if ncand > hits.shape[0]:
            hits = np.empty(2 * ncand, dtype=np.int64)
        x0 = xs[s, 0]
        x1 = xs[s, 1]
        x2 = xs[s, 2]
        # branch-free compaction of the slots within the radius (self included) ...
        p = 0
        for k in range(nr):
            for t in range(rng[k, 0], rng[k, 1]):
                d0 = xs[t, 0] - x0
                d1 = xs[t, 1] - x1
                d2 = xs[t, 2] - x2
                hits[p] = t
                p += d0 * d0 + d1 * d1 + d2 * d2 < r2max
        # ... then the scatter of j into the rows of the query particles among them
        for q in range(p):
            t = hits[q]
            i = order[t]
            if i < n_query and t != s and keep[i]:
                c = cursor[i]
                if c < indptr[i + 1]:  # never true for a consistent count
                    indices[c] = j
                cursor[i] = c + 1
    # the passes agree by construction (symmetric squared distances, complete ranges);
    # a mismatch would be a bug, reported rather than returned as a corrupt list
    for i in range(n_query):
        if cursor[i] != indptr[i + 1]:
            return False
    return True


@njit(cache=True)
def _fill_gather(xs, order, n_query, r2max, lo, inv_cell, ncell, reach, sparse, start,
                 cells, cell_start, indptr, indices, keep):
    """Second pass, query rows in slot order, each row sorted (insertion sort)."""
    n = xs.shape[0]
    w = 2 * reach + 1
    rng = np.empty((w * w, 2), dtype=np.int64)
    gap2 = np.empty((3, w))
    for s in range(n):
        i = order[s]
        if i >= n_query or not keep[i]:
            continue
        nr = _ranges(xs, s, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start, gap2,
                     rng)
        x0 = xs[s, 0]
        x1 = xs[s, 1]
        x2 = xs[s, 2]
        p0 = indptr[i]
        p1 = indptr[i + 1]
        p = p0
        for k in range(nr):
            for t in range(rng[k, 0], rng[k, 1]):
                d0 = xs[t, 0] - x0
                d1 = xs[t, 1] - x1
                d2 = xs[t, 2] - x2
                if d0 * d0 + d1 * d1 + d2 * d2 < r2max and t != s:
                    if p < p1:
                        indices[p] = order[t]
                    p += 1
        if p != p1:
            return False
        for a in range(p0 + 1, p1):
            v = indices[a]
            b = a - 1
            while b >= p0 and indices[b] > v:
                indices[b + 1] = indices[b]
                b -= 1
            indices[b + 1] = v
    return True


@njit(cache=True)
def _disorder(order):
    """Mean |row difference| of consecutive slots over the row count (0 = coherent)."""
    n = order.shape[0]
    acc = 0.0
    for s in range(1, n):
        acc += abs(order[s] - order[s - 1])
    return acc / max(n - 1, 1) / max(n, 1)


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
    if not np.isfinite(extent):
        raise ValueError("positions span a range too large for float64")
    return x, lo3, hi3, extent


def _binned(x, lo3, hi3, extent, radius):
    """The rows of ``x`` sorted into the cells of the box ``lo3``..``hi3`` (extent
    ``extent``) for ``radius``: ``order`` (slot -> row), ``rank_of`` (row -> slot), ``xs``
    (padded positions in slot order) and ``grid``, the arguments of :func:`_ranges` after
    the position (dense grid, or sorted occupied cells when it would be too large)."""
    reach = _REACH
    cell = _cell_size(radius, extent, reach)
    ncell = (np.floor((hi3 - lo3) / cell) + 1.0).astype(np.int64)
    n_dense = int(ncell[0]) * int(ncell[1]) * int(ncell[2])  # Python ints: exact
    sparse = n_dense > _DENSE_PER_PARTICLE * x.shape[0] + _DENSE_MIN
    inv_cell = 1.0 / cell
    xp, cc = _pad_coords(x, lo3, inv_cell, ncell)
    if sparse:
        order, rank_of, xs, cells, cell_start = _sort_sparse(xp, cc)
        start = np.zeros(1, dtype=np.int64)
    else:
        order, rank_of, xs, start = _sort_dense(xp, cc, ncell)
        cells = np.zeros((1, 3), dtype=np.int64)
        cell_start = np.zeros(1, dtype=np.int64)
    return order, rank_of, xs, (lo3, inv_cell, ncell, reach, sparse, start, cells, cell_start)


def _running_count(flags):
    """``out[t]`` = the number of nonzero ``flags`` before index ``t`` (length N + 1)."""
    out = np.zeros(len(flags) + 1, dtype=np.int64)
    np.cumsum(flags != 0, out=out[1:])
    return out


# --------------------------------------------------------------------------- public


def build_csr(x, n_query, radius, active=None):
    """Neighbour lists of ``x[:n_query]`` among all rows of ``x``, in CSR form.

    Parameters
    ----------
    x : array_like, shape (N, dim)
        Positions, ``dim`` in 1, 2, 3 (owned rows first, then halo rows); converted to
        C-contiguous float64. All entries must be finite.
    n_query : int
        Number of leading rows whose neighbours are wanted, ``0 <= n_query <= N``.
    radius : float
        Search radius (> 0), normally the kernel support ``2 h``
        (:func:`parsph.core.kernel.support_radius`). Pairs with squared distance strictly
        below ``radius**2`` are neighbours.
    active : array_like of bool, shape (N,), optional
        One flag per row of ``x``. A query row that is not active gets its full list
        only when an active row is among its neighbours, and an empty list otherwise
        (an IISPH step reads a boundary row's neighbours only when the fluid touches it:
        dry walls and type-I solids need none). Default: every row active.

    Returns
    -------
    indptr : numpy.ndarray of int64, shape (n_query + 1,)
        Row pointers; ``indptr[0] == 0``, ``indptr[-1] == len(indices)``.
    indices : numpy.ndarray of int32, shape (indptr[-1],)
        Neighbour row numbers into ``x`` (query or halo rows); each row is sorted
        ascending and excludes the row itself.

    Raises
    ------
    ValueError
        On a bad shape, ``n_query`` out of range, a non-positive or non-finite radius,
        non-finite positions or more than 2**31 - 1 rows.

    Notes
    -----
    Cost is O(N) for the binning plus O(number of candidate pairs); memory is O(N +
    pairs). Rows of ``x`` beyond ``n_query`` are searched as neighbours but get no list.
    """
    x, lo3, hi3, extent = _checked_box(x)
    n, dim = x.shape
    n_query = operator.index(n_query)
    if not 0 <= n_query <= n:
        raise ValueError(f"n_query must be within [0, {n}], got {n_query}")
    radius = float(radius)
    if not (radius > 0.0 and np.isfinite(radius)):
        raise ValueError(f"search radius must be a positive finite number, got {radius!r}")
    if n > _INT32_MAX:
        raise ValueError(f"at most {_INT32_MAX} rows are supported (int32 indices), got {n}")
    indptr = np.zeros(n_query + 1, dtype=np.int64)
    r2max = radius * radius
    if n_query == 0 or n < 2 or r2max == 0.0:  # (radius**2 may underflow to 0)
        return indptr, np.empty(0, dtype=np.int32)

    if active is not None:
        active = np.asarray(active)
        if active.shape != (n,):
            raise ValueError(f"active must have one flag per row ({n},), got {active.shape}")
    order, rank_of, xs, grid = _binned(x, lo3, hi3, extent, radius)
    # running counts over the slots (cell order): the active slots (and below, the slots
    # whose rows keep a list) in any range of cells
    act_s = kept = np.zeros(0, dtype=np.int64)
    if active is not None:
        act_s = _running_count(active[order])
    keep = np.zeros(n_query, dtype=np.uint8)
    keep_s = np.zeros(n, dtype=np.uint8)
    _count(xs, order, n_query, r2max, *grid, indptr, act_s, keep, keep_s)
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    if indices.shape[0] > _GATHER_MIN_PAIRS and _disorder(order) > _GATHER_DISORDER:
        ok = _fill_gather(xs, order, n_query, r2max, *grid, indptr, indices, keep)
    else:
        if active is not None:
            kept = _running_count(keep_s)
        ok = _fill(xs, order, rank_of, n_query, r2max, *grid, indptr, indices, keep, kept)
    if not ok:
        raise RuntimeError("neighbour search: count and fill passes disagree (a bug)")
    return indptr, indices


def cell_order(x, cell):
    """Permutation that sorts rows by grid cell (a locality-improving reordering).

    Neighbour search and every loop over neighbour lists are fastest when rows that are
    close in space are close in memory; a caller may reorder its owned rows with this
    permutation from time to time (e.g. ``x = x[perm]`` for every field).

    Parameters
    ----------
    x : array_like, shape (N, dim)
        Finite positions, ``dim`` in 1, 2, 3.
    cell : float
        Cell side (> 0), e.g. the search radius ``2 h``.

    Returns
    -------
    numpy.ndarray of int64, shape (N,)
        ``perm`` such that ``x[perm]`` lists the cells in lexicographic order of their
        integer coordinates, rows within a cell in their original order.
    """
    x, lo3, hi3, extent = _checked_box(x)
    cell = float(cell)
    if not (cell > 0.0 and np.isfinite(cell)):
        raise ValueError(f"cell size must be a positive finite number, got {cell!r}")
    n = x.shape[0]
    if n == 0:
        return np.empty(0, dtype=np.int64)
    cell = max(cell, extent / float(_MAX_CELLS_PER_AXIS - 2))
    ncell = (np.floor((hi3 - lo3) / cell) + 1.0).astype(np.int64)
    _, cc = _pad_coords(x, lo3, 1.0 / cell, ncell)
    return np.lexsort((np.arange(n), cc[:, 2], cc[:, 1], cc[:, 0]))


def pair_count(indptr):
    """Total number of (directed) neighbour pairs of a CSR list.

    Parameters
    ----------
    indptr : numpy.ndarray of int64, shape (n_query + 1,)

    Returns
    -------
    int
        ``indptr[-1] - indptr[0]``.
    """
    return int(indptr[-1] - indptr[0])


def row_lengths(indptr):
    """Number of neighbours of each query row, ``numpy.diff(indptr)``."""
    return np.diff(indptr)


def row_of_pairs(indptr):
    """Query row of every pair ``p`` (the COO row array matching ``indices``).

    Parameters
    ----------
    indptr : numpy.ndarray of int64, shape (n_query + 1,)

    Returns
    -------
    numpy.ndarray of int32, shape (indptr[-1],)
        ``rows[p] = i`` for ``indptr[i] <= p < indptr[i + 1]``.
    """
    return np.repeat(np.arange(len(indptr) - 1, dtype=np.int32), np.diff(indptr))
