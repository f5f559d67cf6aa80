"""Numba helper that lets kernels write CSR rows in column order.

The IISPH kernels (``parsph.fluid.viscous.viscous_csr``, ``ppe_csr``) write each matrix
row while they walk a particle's neighbour list; with the lists sorted by global row
here, the columns come out in order, so the CSR block needs neither triplets nor a sort.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["check_block", "count_diagonal", "prepare_block", "row_block_counts",
           "sort_neighbours_by_row", "sparsify",
           "split_diagonal_block", "split_in_place", "unit_diagonal", "scale_rows"]


def sort_neighbours_by_row(indptr, indices, row, inplace=False, ascending=False,
                           order=None):
    """The CSR neighbour lists ``indices`` with each list sorted by the global row
    ``row[j]`` of the neighbours: kernels that emit a row's entries in neighbour order
    then produce sorted CSR rows (a repeated row, a periodic image, is adjacent). A copy,
    or ``indices`` itself sorted with ``inplace`` (a list of the step's pairs less).

    ``ascending``: the caller's lists are in ascending index order (``build_csr``'s),
    or in the order ``order`` of the particles (``build_csr``'s ``visit``; the stretches
    below are then taken along it). The particles then split, by index, into the stretches over which the rows in the
    systems (``row >= 0``) strictly ascend (:func:`_ascending_runs`); a list whose first
    and last entries lie in one stretch has its entries of rows ``>= 0`` in row order
    already and is left as it is (its entries outside the systems, which the kernels
    skip, keep their places instead of going first). On one rank that is every list
    (one stretch: the walls are numbered after the fluid and the solids, as they are
    stored); on several only the lists that reach into the halo, or across the
    particles a rank received, are sorted. The per-list check of the order had cost
    3 ms per step of the 3D dam break of ``jobs/bench_splishsplash.py`` on one rank,
    and 3.0 and 3.8 ms on the two ranks of the 3D tank of ``jobs/bench_memory.py``."""
    out = indices if inplace else indices.copy()
    if ascending:
        run, n_runs = _ascending_runs(row, np.zeros(0, dtype=np.int64) if order is None
                                      else np.asarray(order, dtype=np.int64))
        if n_runs > 1:
            _sort_by_row(indptr, out, row, run)
    else:
        _sort_by_row(indptr, out, row, np.empty(0, dtype=np.int32))
    return out


@njit(cache=True, error_model="numpy")
def _ascending_runs(row, order):
    """``(run, n)``: ``run[k]`` numbers the stretch of indices that ``k`` lies in, over
    each of which the entries ``row >= 0`` strictly ascend (a new stretch begins at
    each entry ``row >= 0`` not above the last one); ``n`` stretches in all. The
    indices are taken in the order ``order`` if it is not empty."""
    run = np.empty(row.shape[0], dtype=np.int32)
    last = -1
    r = 0
    for t in range(row.shape[0]):
        k = order[t] if order.shape[0] else t
        v = row[k]
        if v >= 0:
            if v <= last:
                r += 1
            last = v
        run[k] = r
    return run, r + 1


@njit(cache=True, error_model="numpy", inline="always")
def _rotated(out, start, stop, row, run, scratch):
    """Sort ``out[start:stop]`` (in index order, its first and last entries in different
    stretches of ``run``) by a rotation if it is two stretches whose second lies wholly
    below the first (a rank's own neighbours, then its halo ones from a lower rank);
    returns whether it did."""
    m = start + 1
    while run[out[m]] == run[out[start]]:
        m += 1
    if run[out[m]] != run[out[stop - 1]]:
        return False
    top, bottom = row[out[start]], row[out[stop - 1]]
    if top < 0 or bottom < 0 or bottom >= top:
        return False
    k = 0
    for p in range(m, stop):
        scratch[k] = out[p]
        k += 1
    for p in range(start, m):
        scratch[k] = out[p]
        k += 1
    for p in range(k):
        out[start + p] = scratch[p]
    return True


@njit(cache=True, error_model="numpy")
def _sort_by_row(indptr, out, row, run):
    """Stable sort of each list of ``out`` by ``row``, except the lists whose first
    and last entries have one ``run`` (:func:`_ascending_runs`; empty: none skipped),
    and by a rotation the lists of two runs the second of which lies below the first: a natural merge sort, one pass
    per doubling of its ascending runs, with a scratch of the longest list (in L1).

    A list is mostly in order, but not always in few moves: on the rank whose halo rows
    hold lower global rows than its own (rank 1 of 2), a list by the cut is its owned
    neighbours then its halo ones, and an insertion sort moved every halo entry past
    every owned one. That rank's sort took 6.1 ms per step of a 3D tank of 112,761
    particles where the other's took 3.0 ms (docs/scaling.md)."""
    n = indptr.shape[0] - 1
    longest = 0
    for i in range(n):
        longest = max(longest, indptr[i + 1] - indptr[i])
    ka = np.empty(longest, dtype=row.dtype)
    kb = np.empty(longest, dtype=row.dtype)
    va = np.empty(longest, dtype=out.dtype)
    vb = np.empty(longest, dtype=out.dtype)
    for i in range(n):
        start, stop = indptr[i], indptr[i + 1]
        length = stop - start
        if length == 0 or (run.shape[0] and run[out[start]] == run[out[stop - 1]]):
            continue
        if run.shape[0] and _rotated(out, start, stop, row, run, va):
            continue
        ordered = True
        for p in range(start + 1, stop):
            if row[out[p]] < row[out[p - 1]]:
                ordered = False
                break
        if ordered:
            continue
        for q in range(length):
            va[q] = out[start + q]
            ka[q] = row[va[q]]
        runs = 2
        while runs > 1:  # merge neighbouring ascending runs of (ka, va) into (kb, vb)
            runs = 0
            q = 0
            while q < length:
                m = q + 1
                while m < length and ka[m - 1] <= ka[m]:
                    m += 1
                r = m + 1 if m < length else m
                while r < length and ka[r - 1] <= ka[r]:
                    r += 1
                a, b, t = q, m, q
                while a < m and b < r:
                    if ka[b] < ka[a]:  # ties from the left run: stable
                        kb[t] = ka[b]
                        vb[t] = va[b]
                        b += 1
                    else:
                        kb[t] = ka[a]
                        vb[t] = va[a]
                        a += 1
                    t += 1
                while a < m:
                    kb[t] = ka[a]
                    vb[t] = va[a]
                    a += 1
                    t += 1
                while b < r:
                    kb[t] = ka[b]
                    vb[t] = va[b]
                    b += 1
                    t += 1
                runs += 1
                q = r
            ka, kb = kb, ka
            va, vb = vb, va
        for q in range(length):
            out[start + q] = va[q]


@njit(cache=True, error_model="numpy")
def check_block(cols, vals):
    """``(smallest column, largest column, number of non-finite values)`` of a CSR block
    in one branch-free pass each (numpy's ``min``, ``max`` and ``isfinite().all()`` read
    it three times and write a mask)."""
    lo = cols[0] if cols.shape[0] else 0
    hi = lo
    for k in range(cols.shape[0]):
        lo = min(lo, cols[k])
        hi = max(hi, cols[k])
    bad = 0
    for k in range(vals.shape[0]):
        v = vals[k]
        bad += v - v != 0.0  # NaN or infinite
    return lo, hi, bad


@njit(cache=True, error_model="numpy")
def count_diagonal(cols, first, stop):
    """Entries of a CSR block with their column in ``[first, stop)``: the size of the
    diagonal part :func:`split_diagonal_block` writes (the rest is the off-diagonal)."""
    p = 0
    for k in range(cols.shape[0]):
        c = cols[k]
        p += first <= c < stop
    return p


@njit(cache=True, error_model="numpy")
def row_block_counts(indptr, cols, first, stop, d, o):
    """Per row of a CSR block, its entries with the column in ``[first, stop)`` (into
    ``d``) and the others (into ``o``): the preallocation of a hypre matrix."""
    for i in range(indptr.shape[0] - 1):
        n_d = 0
        for k in range(indptr[i], indptr[i + 1]):
            c = cols[k]
            n_d += first <= c < stop
        d[i] = n_d
        o[i] = indptr[i + 1] - indptr[i] - n_d


@njit(cache=True, error_model="numpy")
def split_diagonal_block(indptr, cols, vals, first, stop, di, dj, dv, oi, oj, ov, pattern):
    """Split the CSR block of a rank's rows into its diagonal part (columns in
    ``[first, stop)``, renumbered from 0) and its off-diagonal part (global columns), as
    ``MatCreateMPIAIJWithSplitArrays`` takes them, writing ``di, oi`` (``n + 1``) and
    ``dj, dv`` and ``oj, ov`` (room for each part: :func:`count_diagonal`), each
    row's columns in their input order, and a copy of ``cols`` into ``pattern`` (the
    pattern the caller keeps; PETSc renumbers ``oj`` in place). Returns the diagonal and
    off-diagonal entry counts ``(p, q)``: the blocks are ``(di, dj[:p], dv[:p])`` and
    ``(oi, oj[:q], ov[:q])``. ``di, dj, dv, pattern`` may be ``indptr, cols, vals, cols``
    themselves (:func:`split_in_place`): an entry only moves forward, and each row's
    start is read before its slot is written.

    The caller passes arrays it reuses (``LinearSystem`` keeps one set): pages of
    fresh arrays are faulted in on every step, which on a VM cost up to 10 us per 4 kB
    page (a fresh 64 MB copy took 155 ms where the same copy into a used buffer took 3 ms).
    """
    n = indptr.shape[0] - 1
    start = indptr[0]
    di[0] = 0
    oi[0] = 0
    p = 0
    q = 0
    for i in range(n):
        end = indptr[i + 1]
        for k in range(start, end):
            c = cols[k]
            pattern[k] = c
            if first <= c < stop:
                dj[p] = c - first
                dv[p] = vals[k]
                p += 1
            else:
                oj[q] = c
                ov[q] = vals[k]
                q += 1
        start = end
        di[i + 1] = p
        oi[i + 1] = q
    return p, q


@njit(cache=True, error_model="numpy")
def split_in_place(indptr, cols, vals, first, stop, oi, oj, ov):
    """:func:`split_diagonal_block` with the diagonal part written over the block itself:
    ``indptr`` becomes its row pointers and the front of ``cols`` (renumbered from 0)
    and ``vals`` its entries. The off-diagonal part goes to ``oi, oj, ov`` (room for it:
    :func:`count_diagonal`). Returns the two counts ``(p, q)``."""
    return split_diagonal_block(indptr, cols, vals, first, stop, indptr, cols, vals, oi, oj,
                                ov, cols)


@njit(cache=True, error_model="numpy", inline="always")
def _keep_large(oj, ov, u, end, below, cut, out_cols, out_vals, k, dropped):
    """:func:`sparsify`'s off-diagonal entries ``u, u + 1, ...`` before ``end`` whose
    column is below ``below``: those of magnitude ``cut`` or more written at ``k`` on,
    the others summed into ``dropped``. Returns ``(u, k, dropped)`` past them."""
    while u < end and oj[u] < below:
        if abs(ov[u]) >= cut:
            out_cols[k] = oj[u]
            out_vals[k] = ov[u]
            k += 1
        else:
            dropped += ov[u]
        u += 1
    return u, k, dropped


@njit(cache=True, error_model="numpy")
def sparsify(di, dj, dv, oi, oj, ov, first, theta, out_ptr, out_cols, out_vals):
    """A sparser copy of a CSR block (rows ``first, first + 1, ...``) for a
    preconditioner, from its two parts as :func:`prepare_block` leaves them: the
    diagonal part ``di, dj, dv`` (columns from ``first``: ``dj + first`` is global) and
    the off-diagonal part ``oi, oj, ov`` (global columns; all of ``oi`` zero on one rank,
    where the block is its diagonal part). Each row keeps its diagonal and the
    off-diagonal entries of at least ``theta`` times its largest off-diagonal magnitude;
    the others are added to its diagonal, so every row sum stays as it was (a
    Laplacian's constants stay its null space). Writes whole rows in global column
    order (the parts merged) to ``out_*`` (room for the block); returns the entries
    written."""
    n = di.shape[0] - 1
    out_ptr[0] = 0
    k = 0
    for r in range(n):
        big = 0.0
        for q in range(di[r], di[r + 1]):
            if dj[q] != r:
                big = max(big, abs(dv[q]))
        for q in range(oi[r], oi[r + 1]):
            big = max(big, abs(ov[q]))
        cut = theta * big
        dropped = 0.0
        at = -1
        # the off-diagonal entries below the diagonal part go first
        u, k, dropped = _keep_large(oj, ov, oi[r], oi[r + 1], first, cut, out_cols, out_vals,
                                    k, dropped)
        for q in range(di[r], di[r + 1]):
            if dj[q] == r or abs(dv[q]) >= cut:
                if dj[q] == r:
                    at = k
                out_cols[k] = dj[q] + first
                out_vals[k] = dv[q]
                k += 1
            else:
                dropped += dv[q]
        _, k, dropped = _keep_large(oj, ov, u, oi[r + 1], np.iinfo(oj.dtype).max, cut,
                                    out_cols, out_vals, k, dropped)
        if at >= 0:
            out_vals[at] += dropped
        out_ptr[r + 1] = k
    return k


@njit(cache=True, error_model="numpy")
def prepare_block(indptr, cols, vals, first, stop, unit, oi, oj, ov):
    """In one pass over a CSR block of a rank's rows (rows ``first, first + 1, ...``,
    global columns sorted in each row): with ``unit``, each row scaled in place to a
    unit diagonal (as :func:`unit_diagonal`); the checks of :func:`check_block`; and
    with ``oi`` not empty (several ranks), the split into the diagonal part, written
    over the block (columns renumbered from 0), and the off-diagonal part ``oi, oj,
    ov`` (room: :func:`count_diagonal`), as :func:`split_in_place`.

    Returns ``(scale, lo, hi, bad, p, q)``: the row scale (ones without ``unit``),
    the smallest and largest column and the number of non-finite values (after the
    scaling), and the diagonal and off-diagonal entry counts (``q = 0`` unsplit).

    A row's columns being sorted, its diagonal entry and the ends of its diagonal part
    are found by bisection and its smallest and largest columns are its ends; each
    stretch is then moved by a plain loop, in place until the first off-diagonal
    entry; the non-finite values are counted in a short pass of their own (a test per
    entry inside those loops had kept them at 5 ms). Four passes (the scaling, the
    checks, the count and the split) had cost 5.7 ms per step of the PPE block of a 3D
    tank of 1e5 particles on the slower of 2 ranks; this one takes 3.5 ms."""
    n = indptr.shape[0] - 1
    scale = np.ones(n)
    split = oi.shape[0] > 0
    lo = cols[0] if cols.shape[0] else 0
    hi = lo
    p = 0
    q = 0
    start = indptr[0]
    if split:
        oi[0] = 0
    for r in range(n):
        end = indptr[r + 1]
        s = 1.0
        if unit:  # the diagonal by bisection of the sorted row
            k = _first_at_least(cols, start, end, first + r)
            if k < end and cols[k] == first + r and vals[k] > 0.0:
                s = 1.0 / vals[k]
                scale[r] = s
        if end > start:
            lo = min(lo, cols[start])
            hi = max(hi, cols[end - 1])
        if not split:
            for k in range(start, end):
                v = vals[k] * s
                vals[k] = v
        else:
            a, b = start, end  # the diagonal part [a, b): mostly the whole row
            if end > start and cols[start] < first:
                a = _first_at_least(cols, start, end, first)
            if end > a and cols[end - 1] >= stop:
                b = _first_at_least(cols, a, end, stop)
            for k in range(start, a):
                v = vals[k] * s
                oj[q] = cols[k]
                ov[q] = v
                q += 1
            if p == a:  # nothing to move yet: in place
                for k in range(a, b):
                    v = vals[k] * s
                    cols[k] -= first
                    vals[k] = v
            else:  # an entry only moves forward (p < a); views let the loop run plain
                m = b - a
                to_c, to_v, from_c, from_v = cols[p:p + m], vals[p:p + m], cols[a:b], vals[a:b]
                for t in range(m):
                    v = from_v[t] * s
                    to_c[t] = from_c[t] - first
                    to_v[t] = v
            p += b - a
            for k in range(b, end):
                v = vals[k] * s
                oj[q] = cols[k]
                ov[q] = v
                q += 1
            indptr[r + 1] = p
            oi[r + 1] = q
        start = end
    if not split:
        p = indptr[n]
    bad = 0
    for k in range(p):
        bad += not np.isfinite(vals[k])
    for k in range(q):
        bad += not np.isfinite(ov[k])
    return scale, lo, hi, bad, p, q


@njit(cache=True, error_model="numpy", inline="always")
def _first_at_least(cols, start, end, c):
    """The first ``k`` in ``[start, end)`` with ``cols[k] >= c`` (``end`` if none) of an
    ascending stretch ``cols[start:end]``."""
    lo, hi = start, end
    while lo < hi:
        mid = (lo + hi) // 2
        if cols[mid] < c:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, error_model="numpy")
def unit_diagonal(indptr, cols, vals, first):
    """Scale each row of a CSR block (rows ``first, first + 1, ...``, global columns) in
    place so that its diagonal is 1; returns the scale ``1 / diagonal`` of every row
    (1 where the diagonal is missing or not positive: such a row is left as it is).

    Row scaling changes neither the solution nor, to first order, the preconditioned
    residual of a left-preconditioned Krylov method; it keeps rows whose magnitude
    changes by orders from one matrix to the next (a wall row in barely any contact
    with the fluid) from spoiling a preconditioner set up on the last matrix."""
    n = indptr.shape[0] - 1
    none = np.empty(0, dtype=indptr.dtype)
    return prepare_block(indptr, cols, vals, first, first + n, True, none,
                         np.empty(0, dtype=cols.dtype), np.empty(0))[0]


@njit(cache=True, error_model="numpy")
def scale_rows(indptr, vals, scale):
    """Multiply row ``r`` of a CSR block by ``scale[r]`` in place."""
    for r in range(indptr.shape[0] - 1):
        for k in range(indptr[r], indptr[r + 1]):
            vals[k] *= scale[r]
