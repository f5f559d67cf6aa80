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
   margin that absorbs floating-point rounding, see
   :func:`parsph.core.cells._cell_size`), so that every neighbour of a particle lies in
   one of the :math:`3^D` cells around its own.
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
4. Count pass (every slot in order, each pair tested once from its lower slot and
   counted at both ends, its upper end recorded): ``indptr``. Fill pass, from the
   recorded pairs with no second search: every row ``j`` in ascending order appends
   ``j`` to the rows of its query neighbours (pairs are symmetric), so each row comes
   out sorted ascending without a sort. When the rows are many and in a spatially
   incoherent order, these scattered writes miss the caches; the pairs are then not
   recorded, and the fill searches and sorts each query row instead. Either way the
   result is the same and does not depend on the internal order (deterministic).

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

from parsph.core.cells import (_MAX_CELLS_PER_AXIS, _binned, _checked_box, _pad_coords, _ranges,
                               cell_of, reachable_cells)

__all__ = ["build_csr", "cell_order", "pair_count", "row_lengths", "row_of_pairs"]

_INT32_MAX = np.iinfo(np.int32).max
#: The fill pass scatters the recorded pairs (rows come out sorted) unless the rows are
#: many and in a spatially incoherent order; then it gathers and sorts each row (same
#: result): for 1e6 particles in random order 3.8 s against 4.5-5.1 s.
_GATHER_MIN_ROWS = 1 << 18
_GATHER_DISORDER = 0.08


@njit(cache=True, error_model="numpy")
def _count(xs, order, n_query, r2max, lo, inv_cell, ncell, reach, sparse, start, cells,
           cell_start, indptr, act, near_cells, keep, up_ptr, up):
    """First pass, every slot in order, each pair once (from its lower slot): ``indptr``
    from the neighbour counts.

    ``act`` (one flag per slot, 1 if its row is active; empty: every row active): a
    query row that is not active keeps its list (``keep[i] = 1``) only when an active
    row is among its neighbours, and gets an empty one otherwise. A pair is tested once,
    from its lower slot, and counted at both ends (with the active rows among each end's
    neighbours): the full search from both ends had cost 26 ms where this costs 20 (the
    3D tank of ``jobs/bench_memory.py``, 112,761 particles). Every slot is the lower end
    of some pairs, halo rows too; one in a cell that ``near_cells``
    (:func:`reachable_cells` of the active slots, two cells each way; empty: not known)
    leaves out is farther than two radii from every active row, so none of its pairs has
    an end with a list.

    With ``up_ptr`` of length N + 1 (empty: not recorded) the upper ends of each slot's
    pairs are recorded too: those of slot ``s`` are ``up[up_ptr[s]:up_ptr[s + 1]]``
    (slots, in the order found); ``up`` grows as needed and is returned (the same array
    if it did not).

    ``xs`` is best in column order (:func:`parsph.core.cells._binned`'s): the distance
    test of a range of slots is then one vector loop, apart from the loop that keeps the
    hits."""
    n = xs.shape[0]
    record = up_ptr.shape[0] > 0
    # the hits of a slot go to ``up`` (recorded) or to a scratch array (not)
    buf = up if record else np.empty(64, dtype=np.int32)
    pos = 0
    w = 2 * reach + 1
    rng = np.empty((w * w, 2), dtype=np.int64)
    gap2 = np.empty((3, w))
    masked = act.shape[0] > 0
    # per slot: its neighbours in the low 32 bits, its active neighbours above them (one
    # update a hit where two arrays had two)
    cw = np.zeros(n, dtype=np.int64)
    hit = np.empty(64, dtype=np.uint8)
    for s in range(n):
        if record:
            up_ptr[s] = pos
        if near_cells.shape[0] and not near_cells[cell_of(xs, s, lo, inv_cell, ncell)]:
            continue
        nr = _ranges(xs, s, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start, gap2,
                     rng)
        p0 = pos if record else 0
        need = p0
        for k in range(nr):
            need += max(rng[k, 1] - max(rng[k, 0], s + 1), 0)
        if need > buf.shape[0]:
            buf = _grown(buf, p0, need)
        if need - p0 > hit.shape[0]:
            hit = np.empty(2 * (need - p0), dtype=np.uint8)
        x0 = xs[s, 0]
        x1 = xs[s, 1]
        x2 = xs[s, 2]
        # each range's test in one vector loop, then its hits kept branch-free (every
        # candidate written, the position advanced by the test): a branch on the test (one
        # candidate in four or five is a hit) was mispredicted, and the test and the write
        # in one loop did not vectorise. The count of the 3D dam break of
        # jobs/bench_splishsplash.py took 22.4 ms with the branch, 17.5 in one loop, 12.4
        q = p0
        for k in range(nr):
            a = max(rng[k, 0], s + 1)
            length = rng[k, 1] - a
            if length <= 0:
                continue
            for e in range(length):
                d0 = xs[a + e, 0] - x0
                d1 = xs[a + e, 1] - x1
                d2 = xs[a + e, 2] - x2
                hit[e] = d0 * d0 + d1 * d1 + d2 * d2 < r2max
            for e in range(length):
                buf[q] = a + e
                q += hit[e]
        if masked:
            inc = 1 + (np.int64(act[s]) << 32)
            wv = np.int64(0)
            for e in range(p0, q):
                t = buf[e]
                cw[t] += inc
                wv += act[t]
            cw[s] += wv << 32
        else:
            for e in range(p0, q):
                cw[buf[e]] += 1
        cw[s] += q - p0
        if record:
            pos = q
    if record:
        up_ptr[n] = pos
    for s in range(n):
        i = order[s]
        if i >= n_query:
            continue
        k = 1 if not masked or act[s] or (cw[s] >> 32) > 0 else 0
        keep[i] = k
        indptr[i + 1] = (cw[s] & 0xFFFFFFFF) if k else 0
    indptr[0] = 0
    for i in range(n_query):
        indptr[i + 1] += indptr[i]
    return buf if record else up


@njit(cache=True, error_model="numpy")
def _upper_pairs_estimate(xs, r2max, lo, inv_cell, ncell, reach, sparse, start, cells,
                          cell_start, near_cells, stride):
    """Room for the pairs :func:`_count` records: the upper ends of every ``stride``-th
    slot counted, times ``stride``, plus a margin (its array then grows rarely, and its
    copies had raised the peak resident set of the 3D tank of ``jobs/bench_memory.py``
    at 1e6 particles by 60 bytes per particle)."""
    n = xs.shape[0]
    w = 2 * reach + 1
    rng = np.empty((w * w, 2), dtype=np.int64)
    gap2 = np.empty((3, w))
    c = 0
    for s in range(0, n, stride):
        if near_cells.shape[0] and not near_cells[cell_of(xs, s, lo, inv_cell, ncell)]:
            continue
        nr = _ranges(xs, s, lo, inv_cell, ncell, reach, sparse, start, cells, cell_start, gap2,
                     rng)
        for k in range(nr):
            for t in range(max(rng[k, 0], s + 1), rng[k, 1]):
                d0 = xs[t, 0] - xs[s, 0]
                d1 = xs[t, 1] - xs[s, 1]
                d2 = xs[t, 2] - xs[s, 2]
                c += d0 * d0 + d1 * d1 + d2 * d2 < r2max
    return int(1.1 * c * stride) + 4096


@njit(cache=True, error_model="numpy")
def _grown(a, used, need):
    """A copy of ``a`` with room for ``need`` entries (at least 1.5 times as many), its
    first ``used`` kept."""
    b = np.empty(max(need, a.shape[0] + a.shape[0] // 2), dtype=a.dtype)
    b[:used] = a[:used]
    return b


@njit(cache=True, error_model="numpy")
def _fill_pairs(order, rank_of, n_query, indptr, indices, keep, up_ptr, up, visit):
    """Second pass from the pairs :func:`_count` recorded: all rows ``j`` in ascending
    order (or in the order ``visit``, if not empty) append ``j`` to their query rows.

    The pairs of slot ``s`` are its upper ends ``up[up_ptr[s]:up_ptr[s + 1]]`` and its
    lower ends, the slots that recorded ``s``, gathered here into a second array (the
    transpose), each as the query row whose list it is in (the upper ends are replaced
    so in place, and those without a list dropped: ``up`` is scratch). Visiting ``j`` in
    that order fills every row already in it, with no sort, and no pair is searched twice
    (the search from every row, as the count does it from the lower ends, had cost 31 ms
    beside the count's 21: the 3D dam break of ``jobs/bench_splishsplash.py``, 72,790
    rows, 1.9 M entries)."""
    n = order.shape[0]
    # per slot: the query row whose list it is in, -1 if none
    dest = np.full(n, -1, dtype=np.int32)
    for t in range(n):
        i = order[t]
        if i < n_query and keep[i]:
            dest[t] = i
    # the lower ends with a list only: a pair reaches the list of its lower end s
    # through low[...] of its upper end
    low_ptr = np.zeros(n + 1, dtype=np.int64)
    for s in range(n):
        if dest[s] >= 0:
            for q in range(up_ptr[s], up_ptr[s + 1]):
                low_ptr[up[q] + 1] += 1
    for s in range(n):
        low_ptr[s + 1] += low_ptr[s]
    low = np.empty(low_ptr[n], dtype=np.int32)  # (their rows)
    at = low_ptr[:-1].copy()
    for s in range(n):
        i = dest[s]
        if i >= 0:
            for q in range(up_ptr[s], up_ptr[s + 1]):
                t = up[q]
                low[at[t]] = i
                at[t] += 1
    # the upper ends in place by their rows, those without a list dropped (branch-free);
    # ``at`` becomes the end of each slot's (one load a pair less in the scatter)
    for s in range(n):
        e = up_ptr[s]
        for q in range(up_ptr[s], up_ptr[s + 1]):
            i = dest[up[q]]
            up[e] = i
            e += i >= 0
        at[s] = e
    cursor = indptr[:-1].copy()
    for jj in range(n):
        j = visit[jj] if visit.shape[0] else jj
        s = rank_of[j]
        for q in range(up_ptr[s], at[s]):
            i = up[q]
            c = cursor[i]
            if c < indptr[i + 1]:  # never false for a consistent count
                indices[c] = j
            cursor[i] = c + 1
        for q in range(low_ptr[s], low_ptr[s + 1]):
            i = low[q]
            c = cursor[i]
            if c < indptr[i + 1]:
                indices[c] = j
            cursor[i] = c + 1
    # the passes agree by construction (the fill scatters the pairs the count counted); a
    # mismatch would be a bug, reported rather than returned as a corrupt list
    for i in range(n_query):
        if cursor[i] != indptr[i + 1]:
            return False
    return True


@njit(cache=True, error_model="numpy")
def _fill_gather(xs, order, n_query, r2max, lo, inv_cell, ncell, reach, sparse, start,
                 cells, cell_start, indptr, indices, keep, place):
    """Second pass, query rows in slot order, each row sorted (insertion sort) by index,
    or by ``place`` (the place of each row in the visiting order) if not empty."""
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
        by = place.shape[0] > 0
        for a in range(p0 + 1, p1):
            v = indices[a]
            kv = place[v] if by else v
            b = a - 1
            while b >= p0 and (place[indices[b]] if by else indices[b]) > kv:
                indices[b + 1] = indices[b]
                b -= 1
            indices[b + 1] = v
    return True


@njit(cache=True, error_model="numpy")
def _near_rows(xs, order, n_query, lo, inv_cell, ncell, near_cells, out):
    """``out[i]`` = whether query row ``i`` lies in a cell that ``near_cells`` marks (all
    rows if it is empty: not known)."""
    for s in range(xs.shape[0]):
        i = order[s]
        if i < n_query:
            out[i] = 1 if near_cells.shape[0] == 0 or near_cells[
                cell_of(xs, s, lo, inv_cell, ncell)] else 0


@njit(cache=True, error_model="numpy")
def _disorder(order):
    """Mean |row difference| of consecutive slots over the row count (0 = coherent)."""
    n = order.shape[0]
    acc = 0.0
    for s in range(1, n):
        acc += abs(order[s] - order[s - 1])
    return acc / max(n - 1, 1) / max(n, 1)


# --------------------------------------------------------------------------- public


def build_csr(x, n_query, radius, active=None, near=None, visit=None):
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
    near : numpy.ndarray of uint8, shape (n_query,), optional
        With ``active``: set to 1 for the query rows within two cells (at least two
        radii) of an active row, 0 for the others, the rows the count pass searches
        (the fluid step keeps its wall rows to these between sync steps,
        :func:`parsph.fluid.walls.system_rows`).
    visit : numpy.ndarray of int, shape (N,), optional
        A permutation of the rows: each list comes out in this order instead of
        ascending (:func:`parsph.step.refresh.list_order`: the rows as the systems of
        the fluid number them, whose kernels then need no sort).

    Returns
    -------
    indptr : numpy.ndarray of int64, shape (n_query + 1,)
        Row pointers; ``indptr[0] == 0``, ``indptr[-1] == len(indices)``.
    indices : numpy.ndarray of int32, shape (indptr[-1],)
        Neighbour row numbers into ``x`` (query or halo rows); each row is sorted
        ascending (or in the order ``visit``) and excludes the row itself.

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
    if near is not None:
        near[:n_query] = 1  # (below: where an active row is within reach)
    r2max = radius * radius
    if n_query == 0 or n < 2 or r2max == 0.0:  # (radius**2 may underflow to 0)
        return indptr, np.empty(0, dtype=np.int32)

    if active is not None:
        active = np.asarray(active)
        if active.shape != (n,):
            raise ValueError(f"active must have one flag per row ({n},), got {active.shape}")
    order, rank_of, xs, grid = _binned(x, lo3, hi3, extent, radius)
    # the active flags of the slots (cell order), and the cells within two cells of them:
    # a row elsewhere is not searched (the dry walls and the type-I solids of a coupled
    # scene, about half its rows, had cost a pruned range search each: the lists of the
    # 3D tank of jobs/bench_memory.py, 112,761 particles, took 87 ms, then 78)
    act = np.zeros(0, dtype=np.uint8)
    near_cells = np.zeros(0, dtype=np.uint8)
    if active is not None:
        act = (active[order] != 0).view(np.uint8)
        ncell, reach, sparse, start = grid[2:6]
        near_cells = reachable_cells(active[order], ncell, 2 * reach, sparse, start)
        if near is not None:
            _near_rows(xs, order, n_query, grid[0], grid[1], ncell, near_cells, near)
    visit = np.zeros(0, dtype=np.int64) if visit is None else np.asarray(visit, np.int64)
    if visit.shape[0] not in (0, n):
        raise ValueError(f"visit must hold one entry per row ({n}), got {visit.shape[0]}")
    # the pairs are recorded for the fill, unless the rows are many and in a spatially
    # incoherent order: the fill then gathers and sorts each row (_GATHER_MIN_ROWS)
    gather = n > _GATHER_MIN_ROWS and _disorder(order) > _GATHER_DISORDER
    up_ptr = np.zeros(0 if gather else n + 1, dtype=np.int64)
    up = np.empty(0 if gather else _upper_pairs_estimate(xs, r2max, *grid, near_cells, 32),
                  dtype=np.int32)
    keep = np.zeros(n_query, dtype=np.uint8)
    up = _count(xs, order, n_query, r2max, *grid, indptr, act, near_cells, keep, up_ptr, up)
    act = near_cells = None  # (not held beside the lists)
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    if gather:
        place = np.zeros(0, dtype=np.int64)
        if visit.shape[0]:
            place = np.empty(n, dtype=np.int64)
            place[visit] = np.arange(n)
        ok = _fill_gather(xs, order, n_query, r2max, *grid, indptr, indices, keep, place)
    else:
        ok = _fill_pairs(order, rank_of, n_query, indptr, indices, keep, up_ptr, up, visit)
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


@njit(cache=True, error_model="numpy")
def without_rows(indptr, indices, keep_query, renumber):
    """The lists of :func:`build_csr` with rows left out: only the query rows where
    ``keep_query``, and in each only the neighbours ``j`` with ``renumber[j] >= 0``,
    renumbered to ``renumber[j]``. ``renumber`` must keep the order of the rows that stay
    (then each list stays ascending: the lists :func:`build_csr` gives for the rows that
    stay). Returns ``(indptr, indices, entry, lost)``: ``entry`` flags the old entries
    kept (to filter per-pair arrays), ``lost`` the new query rows that lost a neighbour."""
    nq = indptr.shape[0] - 1
    entry = np.zeros(indices.shape[0], dtype=np.bool_)
    count = 0
    rows = 0
    for i in range(nq):
        if keep_query[i]:
            rows += 1
            for q in range(indptr[i], indptr[i + 1]):
                if renumber[indices[q]] >= 0:
                    entry[q] = True
                    count += 1
    out_ptr = np.zeros(rows + 1, dtype=indptr.dtype)
    out = np.empty(count, dtype=indices.dtype)
    lost = np.zeros(rows, dtype=np.bool_)
    r = 0
    c = 0
    for i in range(nq):
        if not keep_query[i]:
            continue
        for q in range(indptr[i], indptr[i + 1]):
            if entry[q]:
                out[c] = renumber[indices[q]]
                c += 1
            else:
                lost[r] = True
        r += 1
        out_ptr[r] = c
    return out_ptr, out, entry, lost
