"""Numba helper that lets kernels write CSR rows in column order.

The IISPH kernels (``parsph.fluid.assembly.viscous_csr``, ``ppe_csr``) write each matrix
row while they walk a particle's neighbour list; with the lists sorted by global row
here, the columns come out in order, so the CSR block needs neither triplets nor a sort.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["sort_neighbours_by_row"]


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
