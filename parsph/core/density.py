r"""SPH density summation, eq. (33) of the paper.

.. math::

    \langle \rho \rangle_i = \sum_j m_j W(\mathbf{r}_{ij}, h), \qquad
    \mathbf{r}_{ij} = \mathbf{x}_i - \mathbf{x}_j, \quad (33)

where the sum runs over the neighbours of :math:`i` (CSR lists from
:func:`parsph.core.neighbours.build_csr`, which exclude :math:`i` itself) **and** the self
term :math:`m_i W(0, h)`, with the cubic spline :math:`W` of :mod:`parsph.core.kernel`. In
the fluid phase this is the numerical density :math:`\rho^\beta` entering the source
term of the stabilised pressure Poisson equation, eq. (32).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.core.kernel import normalisation, w

__all__ = ["density_summation"]


@njit(cache=True, error_model="numpy")
def _density(x, m, indptr, indices, h, dim, out):
    n_query = indptr.shape[0] - 1
    w0 = normalisation(h, dim)  # W(0, h)
    for i in range(n_query):
        acc = m[i] * w0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            r2 = 0.0
            for a in range(dim):
                d = x[i, a] - x[j, a]
                r2 += d * d
            acc += m[j] * w(math.sqrt(r2), h, dim)
        out[i] = acc
    return out


def density_summation(x, m, indptr, indices, h, dim, out=None):
    r"""Density of the query particles by kernel summation, eq. (33).

    Parameters
    ----------
    x : numpy.ndarray, shape (N, dim)
        Positions of all rows (owned, then halo), float64.
    m : numpy.ndarray, shape (N,)
        Masses of all rows, float64.
    indptr : numpy.ndarray of int64, shape (n_query + 1,)
        CSR row pointers of the neighbour lists (self excluded).
    indices : numpy.ndarray of int32, shape (indptr[-1],)
        Neighbour rows into ``x``; built with radius :math:`\ge 2h`.
    h : float
        Smoothing length (:math:`1.2\,d`, :func:`parsph.core.kernel.smoothing_length`).
    dim : int
        Spatial dimension, 1, 2 or 3; must equal ``x.shape[1]``.
    out : numpy.ndarray, shape (n_query,), optional
        Output array (float64, C-contiguous) to fill in place.

    Returns
    -------
    numpy.ndarray, shape (n_query,)
        :math:`\rho_i = m_i W(0, h) + \sum_{j \ne i} m_j W(r_{ij}, h)`.

    Notes
    -----
    On a regular lattice of spacing :math:`d` with :math:`m = \rho_0 d^D` and
    :math:`h = 1.2 d`, interior particles get :math:`\rho_0` to about
    :math:`10^{-3}` (the lattice partition of unity of the cubic spline).
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    m = np.ascontiguousarray(m, dtype=np.float64)
    indptr = np.ascontiguousarray(indptr, dtype=np.int64)
    indices = np.ascontiguousarray(indices, dtype=np.int32)
    dim = int(dim)
    if x.ndim != 2 or x.shape[1] != dim or dim not in (1, 2, 3):
        raise ValueError(f"positions must have shape (N, {dim}) with dim 1, 2 or 3, got {x.shape}")
    if m.shape != (x.shape[0],):
        raise ValueError(f"masses must have shape ({x.shape[0]},), got {m.shape}")
    n_query = indptr.shape[0] - 1
    if n_query < 0 or n_query > x.shape[0] or indices.shape[0] != indptr[-1]:
        raise ValueError("inconsistent CSR neighbour lists for these positions")
    if out is None:
        out = np.empty(n_query)
    elif out.shape != (n_query,) or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"out must be a C-contiguous float64 array of shape ({n_query},)")
    return _density(x, m, indptr, indices, float(h), dim, out)
