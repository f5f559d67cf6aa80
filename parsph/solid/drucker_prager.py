r"""Drucker-Prager return map with linear cohesion softening (paper Appendix A, Algorithm 1).

Works on the Kirchhoff stress tau: with the Hencky model the finite-strain return is the
infinitesimal one (eqs. (17)-(18)). Convention: tau and the mean stress
:math:`p = \operatorname{tr}\tau/3` are **tension positive** (the paper's
:math:`p'` with the continuum sign), so compression (p < 0) increases the strength:

.. math::
    \Phi(\tau, c) = \sqrt{J_2(\mathbf s)} + \eta\, p - \xi\, c , \qquad
    G = \sqrt{J_2(\mathbf s)} + \bar\eta\, p \ \text{(flow potential)},

with the cone through the outer edges of the Mohr-Coulomb pyramid (compression
meridian; de Souza Neto et al. 2008, Drucker-Prager approximations of Mohr-Coulomb):

.. math::
    \xi = \frac{6\cos\phi'}{\sqrt3(3-\sin\phi')}, \quad
    \eta = \frac{6\sin\phi'}{\sqrt3(3-\sin\phi')}, \quad
    \bar\eta = \frac{6\sin\psi}{\sqrt3(3-\sin\psi)} .

Corrections to eq. (A.1) of the extracted text: ``6cc`` is a slip (xi multiplies c in
Phi), and eq. (A.1)'s ``2 sin`` is the coefficient of :math:`I_1 = 3p`; written with the
mean stress p the factor is 6, which puts the apex at :math:`p = c\cot\phi'` and makes
Phi vanish on the Mohr-Coulomb envelope in triaxial compression (tested).

Hardening (softening for H < 0, Tables 2 and 3): :math:`c(\bar\epsilon^p) =
\max(c_0 + H\bar\epsilon^p, c_r)`; once c has reached the residual c_r the hardening
modulus in the return is 0. The accumulated plastic strain increases by
:math:`\xi\Delta\gamma` on the cone (de Souza Neto et al. 2008, Box 8.9); it drives the
phase change (section 3.3).

Return to the smooth cone (Algorithm 1 (a), denominator corrected as in DESIGN.md):

.. math::
    \Delta\gamma = \Phi^{trial} / (\mu + K\eta\bar\eta + \xi^2 H), \quad
    \mathbf s = (1 - \mu\Delta\gamma/\sqrt{J_2^{trial}})\,\mathbf s^{trial}, \quad
    p = p^{trial} - K\bar\eta\Delta\gamma .

Return to the apex (Algorithm 1 (b)) when :math:`\sqrt{J_2^{trial}} - \mu\Delta\gamma < 0`:
s = 0 and :math:`p = \xi c/\eta` with the volumetric plastic strain
:math:`\Delta\epsilon_v^p = (p^{trial} - p)/K` and
:math:`\Delta\bar\epsilon^p = \alpha\,\Delta\epsilon_v^p`:

- :math:`\bar\eta > 0` (dilatant): :math:`\alpha = \xi/\bar\eta`, the non-associative
  apex return of de Souza Neto et al. (2008), Box 8.9;
- :math:`\bar\eta = 0` (psi = 0, Tables 2 and 3): that return is degenerate (the flow
  has no volumetric part, so no finite multiplier reaches the apex). We treat it
  deliberately as a **tension cut-off**: the stress goes to the apex point and
  :math:`\alpha = \xi/\eta`, the apex branch as printed in Algorithm 1. A soil pulled
  apart beyond its tensile strength thus accumulates plastic strain and can fluidise.

With softening (H < 0) the cone can shrink past a trial mean stress during the step
(:math:`p^{trial} < \xi c_n/\eta` and yet no smooth-cone solution). The return then
goes in two stages, which is the exact solution of the piecewise-linear consistency
condition: deviatoric flow :math:`\Delta\gamma = \sqrt{J_2^{trial}}/\mu` removes s
(and adds :math:`\xi\Delta\gamma` to the plastic strain), then the volumetric apex
return above from the softened cone (its excess is then >= 0). The accumulated plastic
strain never decreases.

Units: stresses, K, mu, c, H in Pa; angles in radians; strains dimensionless.
"""
import math

from numba import njit

from parsph.core.tensor import mean_j2

_SQRT3 = math.sqrt(3.0)
_YIELD_RTOL = 1e-12
ELASTIC, SMOOTH_CONE, APEX = 0, 1, 2
"""Values of the ``plastic`` flag returned by :func:`dp_return`."""


@njit(cache=True, error_model="numpy")
def dp_params(phi, psi):
    """Cone coefficients ``(xi, eta, eta_bar)`` from the friction and dilatancy angles.

    Parameters
    ----------
    phi : float
        Friction angle phi' (rad).
    psi : float
        Dilatancy angle (rad), ``0 <= psi <= phi``.

    Returns
    -------
    xi, eta, eta_bar : float
        Outer (compression) cone of Mohr-Coulomb written with the mean stress p, see the
        module docstring (eq. (A.1) corrected).
    """
    sphi = math.sin(phi)
    spsi = math.sin(psi)
    xi = 6.0 * math.cos(phi) / (_SQRT3 * (3.0 - sphi))
    eta = 6.0 * sphi / (_SQRT3 * (3.0 - sphi))
    eta_bar = 6.0 * spsi / (_SQRT3 * (3.0 - spsi))
    return xi, eta, eta_bar


@njit(cache=True, error_model="numpy")
def dp_cohesion(eps_p, c0, H, c_r):
    """Cohesion ``max(c0 + H eps_p, c_r)`` (Pa) after an accumulated plastic strain eps_p."""
    return max(c0 + H * eps_p, c_r)


@njit(cache=True, error_model="numpy")
def dp_yield(tau, c, phi):
    r"""Yield function :math:`\Phi = \sqrt{J_2} + \eta p - \xi c` (Pa), eq. (A.1).

    Parameters
    ----------
    tau : ndarray, shape (3, 3)
        Kirchhoff (or Cauchy) stress, tension positive (Pa).
    c : float
        Current cohesion (Pa).
    phi : float
        Friction angle (rad).

    Returns
    -------
    float
        Phi <= 0 inside the elastic domain.
    """
    xi, eta, _ = dp_params(phi, 0.0)
    p, j2 = mean_j2(tau)
    return math.sqrt(j2) + eta * p - xi * c


@njit(cache=True, error_model="numpy", inline="always")
def _cohesion(c0, H, c_r, c_max, eps):
    """Cohesion ``c0 + H eps`` within ``[c_r, c_max]`` and its slope there (0 where a
    bound holds)."""
    c = c0 + H * eps
    if c <= c_r:
        return c_r, 0.0
    if c >= c_max:
        return c_max, 0.0
    return c, H


@njit(cache=True, error_model="numpy")
def dp_return_coeffs_inplace(tau, eps_p, K, mu, c0, H, c_r, xi, eta, eta_bar,
                             c_max=math.inf):
    """Drucker-Prager return map on ``tau`` in place, with precomputed cone coefficients.

    Same as :func:`dp_return` but takes ``(xi, eta, eta_bar)`` from :func:`dp_params`
    (computed once per material) and overwrites ``tau`` (trial in, returned out).
    ``c_max``: the cohesion never exceeds it (the initial cohesion of a soil whose
    softening sees a non-local plastic strain, :mod:`parsph.solid.regularise`, where
    ``c0`` is shifted by its non-local correction).

    Returns
    -------
    eps_p_new : float
        Accumulated plastic strain after the step.
    plastic : int
        0 elastic, 1 smooth cone, 2 apex.
    """
    p_tr, j2 = mean_j2(tau)
    sq = math.sqrt(j2)
    # cohesion and its slope at the start of the step
    c_n, h_n = _cohesion(c0, H, c_r, c_max, eps_p)
    phi_tr = sq + eta * p_tr - xi * c_n
    scale = sq + abs(eta * p_tr) + xi * c_n
    if phi_tr <= _YIELD_RTOL * scale:
        return eps_p, ELASTIC
    # (a) smooth cone
    kee = K * eta * eta_bar
    den = mu + kee + xi * xi * h_n
    if not den > 0.0:
        raise ValueError("Drucker-Prager: mu + K eta eta_bar + xi^2 H <= 0; "
                         "the softening modulus H is too negative for these moduli")
    dgam = phi_tr / den
    if h_n < 0.0 and c_n + h_n * xi * dgam < c_r:
        # the cohesion reaches c_r during the step: solve on the residual branch
        dgam = (sq + eta * p_tr - xi * c_r) / (mu + kee)
    if (sq > 0.0 and sq - mu * dgam >= 0.0) or eta <= 0.0:  # eta = 0: von Mises, no apex
        fac = max(0.0, 1.0 - mu * dgam / sq) if sq > 0.0 else 0.0
        p_new = p_tr - K * eta_bar * dgam
        for i in range(3):
            for j in range(3):
                tau[i, j] *= fac
        dp = p_new - fac * p_tr
        for i in range(3):
            tau[i, i] += dp
        return eps_p + xi * dgam, SMOOTH_CONE
    # (b) apex (non-associative Box 8.9 if eta_bar > 0, tension cut-off if eta_bar == 0)
    beta = xi / eta
    alpha = xi / eta_bar if eta_bar > 0.0 else beta
    eps_1 = eps_p
    if p_tr < beta * c_n:
        # only with softening: the cone shrinks past the trial mean stress during the
        # step. First remove the deviator by deviatoric flow (dgamma = sqrt(J2)/mu), then
        # return the volumetric excess left over the softened apex (>= 0, see docs).
        dgam = sq / mu
        p_tr -= K * eta_bar * dgam
        eps_1 = eps_p + xi * dgam
        c_n, h_n = _cohesion(c0, H, c_r, c_max, eps_1)
    den = K + alpha * beta * h_n
    if not den > 0.0:
        raise ValueError("Drucker-Prager apex: K + alpha beta H <= 0; "
                         "the softening modulus H is too negative for these moduli")
    dev = (p_tr - beta * c_n) / den
    if h_n < 0.0 and c_n + h_n * alpha * dev < c_r:
        dev = (p_tr - beta * c_r) / K
    dev = max(dev, 0.0)
    p_new = p_tr - K * dev
    for i in range(3):
        for j in range(3):
            tau[i, j] = 0.0
        tau[i, i] = p_new
    return eps_1 + alpha * dev, APEX


@njit(cache=True, error_model="numpy")
def dp_return(tau_trial, eps_p, K, mu, c0, H, c_r, phi, psi):
    r"""Drucker-Prager elastic-predictor / plastic-corrector, Algorithm 1 (corrected).

    Parameters
    ----------
    tau_trial : ndarray, shape (3, 3)
        Elastic trial Kirchhoff stress (Pa, tension positive), e.g.
        ``hencky_tau(trial_state(dF, eps_e), K, mu)``. Not modified.
    eps_p : float
        Accumulated plastic strain at the start of the step (>= 0).
    K, mu : float
        Bulk and shear moduli (Pa).
    c0 : float
        Initial cohesion (Pa).
    H : float
        Linear hardening modulus of the cohesion (Pa per unit plastic strain);
        negative for softening (Tables 2 and 3). Requires
        ``mu + K eta eta_bar + xi**2 H > 0`` and ``K + alpha beta H > 0``.
    c_r : float
        Residual cohesion (Pa), ``0 <= c_r <= c0``: c never drops below it.
    phi, psi : float
        Friction and dilatancy angles (rad), ``0 <= psi <= phi``.

    Returns
    -------
    tau_new : ndarray, shape (3, 3)
        Returned Kirchhoff stress (Pa, tension positive); on the yield surface of
        ``c = dp_cohesion(eps_p_new, c0, H, c_r)`` when plastic.
    eps_p_new : float
        Accumulated plastic strain after the step.
    plastic : int
        0 elastic, 1 smooth cone, 2 apex (see the module docstring for the psi = 0
        tension cut-off).

    Notes
    -----
    The caller recovers the elastic log strain with eq. (26), ``eps_from_tau``.
    """
    xi, eta, eta_bar = dp_params(phi, psi)
    tau = tau_trial.copy()
    eps_p_new, plastic = dp_return_coeffs_inplace(tau, eps_p, K, mu, c0, H, c_r, xi, eta, eta_bar)
    return tau, eps_p_new, plastic
