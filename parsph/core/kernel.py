r"""Cubic spline smoothing kernel (Schoenberg 1964; Monaghan 1992, "M4").

The paper (section 2, after eq. (1)) uses the cubic spline with smoothing length
:math:`h = 1.2\,d`, :math:`d` the particle diameter (initial spacing). With
:math:`q = r / h` the kernel is

.. math::

    W(r, h) = \sigma_D
    \begin{cases}
        1 - \tfrac{3}{2} q^2 + \tfrac{3}{4} q^3, & 0 \le q < 1, \\
        \tfrac{1}{4} (2 - q)^3,                  & 1 \le q < 2, \\
        0,                                       & q \ge 2,
    \end{cases}
    \qquad
    \sigma_1 = \frac{2}{3 h},\quad
    \sigma_2 = \frac{10}{7 \pi h^2},\quad
    \sigma_3 = \frac{1}{\pi h^3},

so that :math:`\int W \, dV = 1` and the support radius is :math:`2h`. Its radial
derivative is

.. math::

    \frac{\partial W}{\partial r} = \frac{\sigma_D}{h}
    \begin{cases}
        -3 q + \tfrac{9}{4} q^2,      & 0 \le q < 1, \\
        -\tfrac{3}{4} (2 - q)^2,      & 1 \le q < 2, \\
        0,                            & q \ge 2,
    \end{cases}

and the gradient with respect to :math:`\mathbf{x}_i` of :math:`W(\mathbf{r}_{ij}, h)`,
:math:`\mathbf{r}_{ij} = \mathbf{x}_i - \mathbf{x}_j`, is

.. math::

    \nabla W(\mathbf{r}_{ij}, h) = F(r_{ij}, h)\, \mathbf{r}_{ij}, \qquad
    F = \frac{1}{r} \frac{\partial W}{\partial r},

where :math:`F` (:func:`fac_grad`) is evaluated in the cancelled form
:math:`\sigma_D h^{-2} (-3 + \tfrac{9}{4} q)` for :math:`q < 1`, finite at
:math:`r = 0`; hence :math:`\nabla W(\mathbf{0}) = \mathbf{0}`. This :math:`\nabla W` is
the one entering eqs. (34)-(36) (fluid) and, after correction, the TLSPH gradient of
section 3.

The numba functions take ``dim`` (1, 2 or 3) as an argument. Pair loops use the
``_k`` variants instead, which take the tuple :func:`constants` computed once per loop
(1/h, the normalisation and its ratio to h^2): a divide by h and the normalisation's
power per pair made the fluid's sums 1.4x slower. With :func:`delta` (one pair's
separation in scalars) a loop keeps its accumulators in registers; array accumulators
indexed by a run-time ``dim`` made the same loops 2-5x slower (docs/performance.md).

References
----------
Schoenberg, I. J. (1964). Spline functions and the problem of graduation. Proc. Natl.
Acad. Sci. USA 52, 947-950.
Monaghan, J. J. (1992). Smoothed particle hydrodynamics. Annu. Rev. Astron. Astrophys.
30, 543-574.
Monaghan, J. J. and Lattanzio, J. C. (1985). A refined particle method for astrophysical
problems. Astron. Astrophys. 149, 135-143.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "H_OVER_D",
    "SUPPORT_OVER_H",
    "smoothing_length",
    "support_radius",
    "normalisation",
    "w",
    "dw_dr",
    "fac_grad",
    "w_array",
    "dw_dr_array",
    "fac_grad_array",
    "constants",
    "w_k",
    "fac_grad_k",
    "w_and_fac_grad_k",
    "delta",
]

#: Smoothing length over particle diameter, :math:`h = 1.2 d` (paper, section 2).
H_OVER_D = 1.2

#: Support radius over smoothing length of the cubic spline (:math:`W = 0` for r >= 2h).
SUPPORT_OVER_H = 2.0


def smoothing_length(d: float) -> float:
    """Smoothing length of a particle of diameter (initial spacing) ``d``.

    Parameters
    ----------
    d : float
        Particle diameter / initial lattice spacing, > 0.

    Returns
    -------
    float
        :math:`h = 1.2\\,d` (:data:`H_OVER_D`, paper section 2).
    """
    d = float(d)
    if not (d > 0.0 and math.isfinite(d)):
        raise ValueError(f"particle diameter must be a positive finite number, got {d!r}")
    return H_OVER_D * d


def support_radius(h: float) -> float:
    """Radius beyond which the cubic spline vanishes.

    Parameters
    ----------
    h : float
        Smoothing length, > 0.

    Returns
    -------
    float
        :math:`2h`, the neighbour-search radius.
    """
    h = float(h)
    if not (h > 0.0 and math.isfinite(h)):
        raise ValueError(f"smoothing length must be a positive finite number, got {h!r}")
    return SUPPORT_OVER_H * h


@njit(cache=True, error_model="numpy", inline="always")
def normalisation(h, dim):
    r"""Normalisation constant :math:`\sigma_D` of the cubic spline.

    Parameters
    ----------
    h : float
        Smoothing length.
    dim : int
        Spatial dimension, 1, 2 or 3.

    Returns
    -------
    float
        :math:`2/(3h)` (1D), :math:`10/(7\pi h^2)` (2D), :math:`1/(\pi h^3)` (3D).

    Raises
    ------
    ValueError
        If ``dim`` is not 1, 2 or 3.
    """
    if dim == 3:
        return 1.0 / (math.pi * h * h * h)
    elif dim == 2:
        return 10.0 / (7.0 * math.pi * h * h)
    elif dim == 1:
        return 2.0 / (3.0 * h)
    raise ValueError("kernel dimension must be 1, 2 or 3")


@njit(cache=True, error_model="numpy", inline="always")
def w(r, h, dim):
    r"""Cubic spline kernel value :math:`W(r, h)`.

    Parameters
    ----------
    r : float
        Distance :math:`|\mathbf{r}_{ij}| \ge 0`.
    h : float
        Smoothing length.
    dim : int
        Spatial dimension, 1, 2 or 3.

    Returns
    -------
    float
        Kernel value; 0 for ``r >= 2 h``.
    """
    q = r / h
    if q < 1.0:
        return normalisation(h, dim) * (1.0 - 1.5 * q * q + 0.75 * q * q * q)
    elif q < 2.0:
        t = 2.0 - q
        return normalisation(h, dim) * 0.25 * t * t * t
    return 0.0


@njit(cache=True, error_model="numpy", inline="always")
def dw_dr(r, h, dim):
    r"""Radial derivative :math:`\partial W / \partial r` of the cubic spline.

    Parameters
    ----------
    r : float
        Distance, >= 0.
    h : float
        Smoothing length.
    dim : int
        Spatial dimension, 1, 2 or 3.

    Returns
    -------
    float
        Derivative (<= 0); 0 at ``r = 0`` and for ``r >= 2 h``.
    """
    q = r / h
    if q < 1.0:
        return normalisation(h, dim) / h * (-3.0 * q + 2.25 * q * q)
    elif q < 2.0:
        t = 2.0 - q
        return normalisation(h, dim) / h * (-0.75 * t * t)
    return 0.0


@njit(cache=True, error_model="numpy", inline="always")
def fac_grad(r, h, dim):
    r"""Gradient factor :math:`F = (\partial W/\partial r) / r`.

    :math:`\nabla W(\mathbf{r}_{ij}, h) = F(r_{ij}, h)\,\mathbf{r}_{ij}` with
    :math:`\mathbf{r}_{ij} = \mathbf{x}_i - \mathbf{x}_j` (gradient with respect to
    :math:`\mathbf{x}_i`), as used in eqs. (34)-(36) of the paper.

    Parameters
    ----------
    r : float
        Distance, >= 0.
    h : float
        Smoothing length.
    dim : int
        Spatial dimension, 1, 2 or 3.

    Returns
    -------
    float
        :math:`F`; finite at ``r = 0`` (:math:`-3\sigma_D/h^2`, so the gradient is the
        zero vector there) and 0 for ``r >= 2 h``.
    """
    q = r / h
    if q < 1.0:
        return normalisation(h, dim) / (h * h) * (-3.0 + 2.25 * q)
    elif q < 2.0:
        t = 2.0 - q
        return normalisation(h, dim) * (-0.75 * t * t) / (h * r)
    return 0.0


@njit(cache=True, error_model="numpy")
def _eval_array(r, h, dim, which):
    out = np.empty(r.shape[0])
    for k in range(r.shape[0]):
        if which == 0:
            out[k] = w(r[k], h, dim)
        elif which == 1:
            out[k] = dw_dr(r[k], h, dim)
        else:
            out[k] = fac_grad(r[k], h, dim)
    return out


def _array_call(r, h, dim, which):
    r = np.asarray(r, dtype=np.float64)
    if int(dim) not in (1, 2, 3):
        raise ValueError(f"kernel dimension must be 1, 2 or 3, got {dim!r}")
    flat = np.ascontiguousarray(r.reshape(-1))
    return _eval_array(flat, float(h), int(dim), which).reshape(r.shape)


def w_array(r, h, dim):
    """Vectorised :func:`w` over an array of distances (for set-up, tests and plots).

    Parameters
    ----------
    r : array_like
        Distances, any shape.
    h : float
        Smoothing length.
    dim : int
        Spatial dimension, 1, 2 or 3.

    Returns
    -------
    numpy.ndarray
        Kernel values, same shape as ``r``.
    """
    return _array_call(r, h, dim, 0)


def dw_dr_array(r, h, dim):
    """Vectorised :func:`dw_dr`; same conventions as :func:`w_array`."""
    return _array_call(r, h, dim, 1)


def fac_grad_array(r, h, dim):
    """Vectorised :func:`fac_grad`; same conventions as :func:`w_array`."""
    return _array_call(r, h, dim, 2)


@njit(cache=True, error_model="numpy", inline="always")
def constants(h, dim):
    r"""The per-loop constants of the ``_k`` functions: :math:`(1/h, \sigma_D, \sigma_D/h^2)`."""
    s = normalisation(h, dim)
    return 1.0 / h, s, s / (h * h)


@njit(cache=True, error_model="numpy", inline="always")
def w_k(r, k):
    """:func:`w` with the constants ``k`` of :func:`constants` (no division)."""
    q = r * k[0]
    if q < 1.0:
        return k[1] * (1.0 - 1.5 * q * q + 0.75 * q * q * q)
    elif q < 2.0:
        t = 2.0 - q
        return k[1] * 0.25 * t * t * t
    return 0.0


@njit(cache=True, error_model="numpy", inline="always")
def fac_grad_k(r, k):
    r""":func:`fac_grad` with the constants ``k`` of :func:`constants`: one division, by
    :math:`q`, on the outer branch (:math:`\sigma_D h^{-2} (-\tfrac34 (2 - q)^2) / q`)."""
    q = r * k[0]
    if q < 1.0:
        return k[2] * (-3.0 + 2.25 * q)
    elif q < 2.0:
        t = 2.0 - q
        return k[2] * (-0.75 * t * t) / q
    return 0.0


@njit(cache=True, error_model="numpy", inline="always")
def w_and_fac_grad_k(r, k):
    """``(W, F)`` of one distance, sharing q (density and its gradient in one pass)."""
    q = r * k[0]
    if q < 1.0:
        return k[1] * (1.0 - 1.5 * q * q + 0.75 * q * q * q), k[2] * (-3.0 + 2.25 * q)
    elif q < 2.0:
        t = 2.0 - q
        return k[1] * 0.25 * t * t * t, k[2] * (-0.75 * t * t) / q
    return 0.0, 0.0


@njit(cache=True, error_model="numpy", inline="always")
def delta(x, i, j, dim):
    r"""``(d0, d1, d2, r2)``: :math:`\mathbf x_i - \mathbf x_j` of rows ``i``, ``j`` of an
    (N, dim) array as three scalars (``d2 = 0`` in 2D) and its squared length, summed
    over the axes in order (the neighbour search's test, bit for bit)."""
    d0 = x[i, 0] - x[j, 0]
    d1 = x[i, 1] - x[j, 1]
    d2 = x[i, 2] - x[j, 2] if dim == 3 else 0.0
    return d0, d1, d2, d0 * d0 + d1 * d1 + d2 * d2
