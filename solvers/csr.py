"""Numba helper that lets kernels write CSR rows in column order.

The IISPH kernels (``parsph.fluid.assembly.viscous_csr``, ``ppe_csr``) write each matrix
row while they walk a particle's neighbour list; with the lists sorted by global row
here, the columns come out in order, so the CSR block needs neither triplets nor a sort.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["sort_neighbours_by_row", "split_diagonal_block"]


@njit(cache=True)
def sort_neighbours_by_row(indptr, indices, row):
    """A copy of the CSR neighbour lists ``indices`` with each list sorted by the global
    row ``row[j]`` of the neighbours: kernels that emit a row's entries in neighbour
    order then produce sorted CSR rows (a repeated row, a periodic image, is adjacent)."""
    out = indices.copy()
    for i in range(indptr.shape[0] - 1):
        start, stop = indptr[i], indptr[i + 1]
        for p in range(start + 1, stop):
            j = out[p]
            key = row[j]
            q = p - 1
            while q >= start and row[out[q]] > key:
                out[q + 1] = out[q]
                q -= 1
            out[q + 1] = j
    return out


@njit(cache=True)
def split_diagonal_block(indptr, cols, vals, first, stop):
    """The CSR block of a rank's rows split into its diagonal part (columns in
    ``[first, stop)``, renumbered from 0) and its off-diagonal part (global columns), as
    ``MatCreateMPIAIJWithSplitArrays`` takes them: ``(di, dj, dv), (oi, oj, ov)``, fresh
    arrays, each row's columns in their input order."""
    n = indptr.shape[0] - 1
    nd = 0
    for k in range(indptr[n]):
        if first <= cols[k] < stop:
            nd += 1
    no = indptr[n] - nd
    di = np.empty(n + 1, indptr.dtype)
    dj = np.empty(nd, cols.dtype)
    dv = np.empty(nd)
    oi = np.empty(n + 1, indptr.dtype)
    oj = np.empty(no, cols.dtype)
    ov = np.empty(no)
    di[0] = 0
    oi[0] = 0
    p = 0
    q = 0
    for i in range(n):
        for k in range(indptr[i], indptr[i + 1]):
            c = cols[k]
            if first <= c < stop:
                dj[p] = c - first
                dv[p] = vals[k]
                p += 1
            else:
                oj[q] = c
                ov[q] = vals[k]
                q += 1
        di[i + 1] = p
        oi[i + 1] = q
    return (di, dj, dv), (oi, oj, ov)
