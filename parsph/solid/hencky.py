r"""Hencky hyperelasticity on the logarithmic strain (paper section 3.2).

Equations of the paper implemented here (with the corrections of DESIGN.md):

- eq. (15): logarithmic (Hencky) strain :math:`\epsilon = \tfrac12 \ln \mathbf B`,
  :math:`\mathbf B = \mathbf F \mathbf F^T`;
- eq. (16): Kirchhoff stress :math:`\tau = \mathbf C_{el} : \epsilon
  = K \operatorname{tr}(\epsilon)\mathbf I + 2\mu \operatorname{dev}(\epsilon)`;
  Cauchy stress :math:`\sigma = \tau / J`;
- eqs. (20)-(24): elastic trial state from the increment :math:`\Delta\mathbf F`:
  :math:`\mathbf B^\beta = \exp(2\epsilon^\beta)` (eq. (22) as corrected; the extracted
  text prints "2 exp"), :math:`\mathbf B^{trial} = \Delta\mathbf F\, \mathbf B^\beta\,
  \Delta\mathbf F^T` (eq. (23) as corrected; the transpose was lost),
  :math:`\epsilon^{trial} = \tfrac12 \ln \mathbf B^{trial}`;
- eq. (26): logarithmic elastic strain back from the returned stress,
  :math:`\epsilon = [(1+\nu)\tau - \nu \operatorname{tr}(\tau)\mathbf I]/E` (the identity
  is implied in the paper);
- eq. (27): nominal stress :math:`\mathbf P = \mathbf F^{-1} \tau`. This is the
  *nominal* stress (the transpose of the first Piola-Kirchhoff stress
  :math:`\tau \mathbf F^{-T}`), the form used with :math:`\nabla_0 \cdot \mathbf P`
  in eq. (13).

Because tau is an isotropic linear function of the logarithmic strain, the return maps
of Appendix A/B act on tau exactly as the infinitesimal ones act on sigma (eqs. (17)-(18)).

Sign convention: tension positive. Units: stresses and moduli in Pa, strains
dimensionless.
"""
import math

import numpy as np
from numba import njit

from parsph.core.tensor import _congruence6, _eig6, _recon6, _store6, _sym6, det3


@njit(cache=True, error_model="numpy")
def lame_from_young(E, nu):
    """Bulk and shear moduli ``(K, mu)`` from Young's modulus E (Pa) and Poisson's ratio nu."""
    return E / (3.0 * (1.0 - 2.0 * nu)), E / (2.0 * (1.0 + nu))


@njit(cache=True, error_model="numpy")
def hencky_tau_into(eps, K, mu, out):
    """:func:`hencky_tau` writing into ``out`` (3, 3)."""
    tr = eps[0, 0] + eps[1, 1] + eps[2, 2]
    lam = K * tr - 2.0 * mu * tr / 3.0
    for i in range(3):
        for j in range(3):
            out[i, j] = mu * (eps[i, j] + eps[j, i])
        out[i, i] += lam


@njit(cache=True, error_model="numpy")
def hencky_tau(eps, K, mu):
    r"""Kirchhoff stress of the Hencky model, eq. (16).

    Parameters
    ----------
    eps : ndarray, shape (3, 3)
        Logarithmic elastic strain (symmetric).
    K, mu : float
        Bulk and shear moduli (Pa).

    Returns
    -------
    tau : ndarray, shape (3, 3)
        :math:`K \operatorname{tr}(\epsilon)\mathbf I + 2\mu\operatorname{dev}(\epsilon)`
        (Pa, tension positive).
    """
    out = np.empty((3, 3))
    hencky_tau_into(eps, K, mu, out)
    return out


@njit(cache=True, error_model="numpy")
def trial_state_into(dF, eps_e_prev, out):
    """:func:`trial_state` writing into ``out`` (3, 3); allocation-free."""
    e = _eig6(*_sym6(eps_e_prev))
    b = _recon6(math.exp(2.0 * e[0]), math.exp(2.0 * e[1]), math.exp(2.0 * e[2]), e)
    c = _congruence6(dF, b)
    e = _eig6(*c)
    _store6(_recon6(0.5 * math.log(e[0]), 0.5 * math.log(e[1]), 0.5 * math.log(e[2]), e), out)


@njit(cache=True, error_model="numpy")
def trial_state(dF, eps_e_prev):
    r"""Elastic trial logarithmic strain, eqs. (22)-(24) (corrected).

    Parameters
    ----------
    dF : ndarray, shape (3, 3)
        Increment of the deformation gradient, eq. (21), with ``det dF > 0``
        (2D plane strain: ``dF[2, 2] = 1``, ``dF[i, 2] = dF[2, i] = 0``).
    eps_e_prev : ndarray, shape (3, 3)
        Logarithmic elastic strain of the previous step.

    Returns
    -------
    eps_trial : ndarray, shape (3, 3)
        :math:`\tfrac12\ln(\Delta\mathbf F \exp(2\epsilon^\beta)\Delta\mathbf F^T)`.

    Notes
    -----
    Under a rigid rotation ``dF = R`` the result is exactly ``R eps R^T`` up to round-off,
    so the Hencky stress is objective without any rotation correction.
    """
    out = np.empty((3, 3))
    trial_state_into(dF, eps_e_prev, out)
    return out


@njit(cache=True, error_model="numpy")
def eps_from_tau_into(tau, E, nu, out):
    """:func:`eps_from_tau` writing into ``out`` (3, 3)."""
    tr = tau[0, 0] + tau[1, 1] + tau[2, 2]
    a = (1.0 + nu) / E
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.5 * a * (tau[i, j] + tau[j, i])
        out[i, i] -= nu * tr / E


@njit(cache=True, error_model="numpy")
def eps_from_tau(tau, E, nu):
    r"""Logarithmic elastic strain from the Kirchhoff stress, eq. (26).

    Parameters
    ----------
    tau : ndarray, shape (3, 3)
        Kirchhoff stress (Pa, tension positive), e.g. after the return map.
    E : float
        Young's modulus (Pa).
    nu : float
        Poisson's ratio.

    Returns
    -------
    eps : ndarray, shape (3, 3)
        :math:`[(1+\nu)\tau - \nu\operatorname{tr}(\tau)\mathbf I]/E`, the inverse of
        :func:`hencky_tau` with ``(K, mu) = lame_from_young(E, nu)``.
    """
    out = np.empty((3, 3))
    eps_from_tau_into(tau, E, nu, out)
    return out


@njit(cache=True, error_model="numpy")
def eps_from_tau_kmu(tau, K, mu):
    r"""Eq. (26) written with the bulk and shear moduli: ``tr(tau)/(9K) I + dev(tau)/(2 mu)``."""
    out = np.empty((3, 3))
    tr = tau[0, 0] + tau[1, 1] + tau[2, 2]
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.25 * (tau[i, j] + tau[j, i]) / mu
        out[i, i] += tr / (9.0 * K) - tr / (6.0 * mu)
    return out


@njit(cache=True, error_model="numpy")
def nominal_stress_into(F, tau, out):
    """:func:`nominal_stress` writing into ``out`` (3, 3); returns J = det F."""
    J = det3(F)
    inv = 1.0 / J
    # rows of F^-1 = cofactor^T / J
    c00 = (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]) * inv
    c01 = (F[0, 2] * F[2, 1] - F[0, 1] * F[2, 2]) * inv
    c02 = (F[0, 1] * F[1, 2] - F[0, 2] * F[1, 1]) * inv
    c10 = (F[1, 2] * F[2, 0] - F[1, 0] * F[2, 2]) * inv
    c11 = (F[0, 0] * F[2, 2] - F[0, 2] * F[2, 0]) * inv
    c12 = (F[0, 2] * F[1, 0] - F[0, 0] * F[1, 2]) * inv
    c20 = (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]) * inv
    c21 = (F[0, 1] * F[2, 0] - F[0, 0] * F[2, 1]) * inv
    c22 = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) * inv
    for j in range(3):
        t0 = tau[0, j]
        t1 = tau[1, j]
        t2 = tau[2, j]
        out[0, j] = c00 * t0 + c01 * t1 + c02 * t2
        out[1, j] = c10 * t0 + c11 * t1 + c12 * t2
        out[2, j] = c20 * t0 + c21 * t1 + c22 * t2
    return J


@njit(cache=True, error_model="numpy")
def nominal_stress(F, tau):
    r"""Nominal stress, eq. (27): :math:`\mathbf P = \mathbf F^{-1}\tau`.

    Parameters
    ----------
    F : ndarray, shape (3, 3)
        Deformation gradient (det F > 0).
    tau : ndarray, shape (3, 3)
        Kirchhoff stress (Pa, tension positive).

    Returns
    -------
    P : ndarray, shape (3, 3)
        Nominal stress (Pa per reference area), the transpose of the first
        Piola-Kirchhoff stress ``tau F^-T``.
    """
    out = np.empty((3, 3))
    nominal_stress_into(F, tau, out)
    return out


@njit(cache=True, error_model="numpy")
def cauchy_stress(tau, F):
    r"""Cauchy stress :math:`\sigma = \tau / J`, :math:`J = \det\mathbf F` (after eq. (16))."""
    return tau / det3(F)
