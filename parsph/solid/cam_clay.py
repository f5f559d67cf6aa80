r"""Modified Cam-Clay return map (paper Appendix B, Algorithm 2, eqs. (B.1)-(B.7)).

Soil-mechanics convention **inside this module only**: effective mean stress
:math:`p' = -\operatorname{tr}\tau/3` and the pre-consolidation pressure :math:`p_c`
are compression positive; the stresses passed in and out (tau) are tension positive like
everywhere else. The deviatoric stress :math:`\mathbf s = \operatorname{dev}\tau` and
:math:`q = \sqrt{3/2\,\mathbf s:\mathbf s}` need no conversion.

Yield function (the ellipse through p' = 0 and p' = p_c; the paper's
:math:`p'^2 + p_c p' + (q/M)^2` is the same curve with p' tension positive):

.. math:: f = q^2/M^2 + p'(p' - p_c) \le 0 .

Associative flow: :math:`\Delta\epsilon^p_v = \Delta\gamma\,(2p' - p_c)` (compaction
positive), :math:`\Delta\mathbf e^p = 3\Delta\gamma\,\mathbf s/M^2`.

Pressure-dependent elasticity (swelling line :math:`v = v_\kappa - \kappa\ln p'`):
tangent :math:`K = v p'/\kappa`, :math:`\mu = 3K(1-2\nu)/(2(1+\nu))`, with
:math:`v = 1 + e = 1/(1-n)` the specific volume. The volumetric part is integrated
exactly, :math:`p' = p'^{trial}\exp(-v\Delta\epsilon^p_v/\kappa)` (the paper's
:math:`p' = p'^{trial} - K\Delta\epsilon^p_v` is its linearisation), and
:math:`q = q^{trial}/(1 + 6\mu\Delta\gamma/M^2)` with mu evaluated at the returned p'
(the paper updates K and mu with p' at every Newton iterate).

Hardening along the normal consolidation line, :math:`d\epsilon^p_v = (\lambda-\kappa)\,
dp_c/(v p_c)` integrated exactly (as in Borja & Lee 1990):

.. math:: p_c^{n+1} = p_c^n \exp\!\big(v\,\Delta\epsilon^p_v / (\lambda - \kappa)\big).

The extracted text prints :math:`p_c/(1 - \Delta\epsilon^p_v(\lambda-\kappa))`, which is
dimensionally inconsistent with eq. (B.5): the derivative
:math:`\partial p_c/\partial\Delta\epsilon^p_v = v p_c/(\lambda - \kappa)` used there is
the one of the exponential form, which we use (its first-order expansion is
:math:`p_c/(1 - v\Delta\epsilon^p_v/(\lambda-\kappa))`).

Newton-Raphson on the unknowns :math:`(\Delta\gamma, \Delta\epsilon^p_v)`, starting
from (0, 0) as in Algorithm 2, with the residuals (B.1) :math:`R_1 = f/s^2`
(:math:`s = \max(p_c, p'^{trial})`) and (B.2)
:math:`R_2 = \Delta\epsilon^p_v - \Delta\gamma(2p' - p_c)` and the exact Jacobian of
the update above ((B.4)-(B.7) are its counterparts for frozen moduli and the linearised
pressure update), with a backtracking line search on :math:`R_1^2 + R_2^2`. Converged
when :math:`|R_1| <` tol and :math:`|R_2| <` tol times the size of its terms. Realistic
increments take 3-6 iterations. Should Newton not converge in ``max_iter`` (only for
extreme trial states, q/p' of order 1e3 and more), a safeguarded bisection on
:math:`\Delta\epsilon^p_v` with :math:`\Delta\gamma` eliminated through f = 0 finishes
the job; its iterations are added to the count.

Floor p' >= p_min (default :data:`P_MIN` = 1 Pa): the moduli use
:math:`\max(p', p_{min})`, so nothing divides by zero. A trial state with
:math:`p'^{trial} < p_{min}` (zero confinement or tension, which a soil without
cohesion cannot carry; the ellipse has q = 0 at p' = 0) is returned to the apex of the
ellipse, :math:`\tau = -p_{min}\mathbf I` (tension cut-off), with p_c unchanged and no
plastic volumetric strain attributed to the cut (``d_eps_v_p = d_gamma = 0``,
``iterations = 0``). p_c itself is floored at p_min.

Units: stresses and p_c in Pa; v, kappa, lambda, nu, M dimensionless.
"""
import math

import numpy as np
from numba import njit

from parsph.core.tensor import _congruence6, _eig6, _recon6, _store6, _sym6

M_TABLE1 = 1.0
"""Critical state slope chosen for the Table 1 soil (the paper does not give it):
M = 6 sin(phi')/(3 - sin(phi')) = 1.0 <=> phi' = 25.4 deg in triaxial compression, a
typical value for clays (see docs/constitutive.md)."""

P_MIN = 1.0
"""Default floor on p' (Pa) for the pressure-dependent moduli and tension cut-off."""


@njit(cache=True, error_model="numpy")
def m_from_phi(phi):
    """Critical state slope ``M = 6 sin(phi)/(3 - sin(phi))`` (triaxial compression), phi in rad."""
    s = math.sin(phi)
    return 6.0 * s / (3.0 - s)


@njit(cache=True, error_model="numpy")
def mcc_moduli(p, v, kappa, nu, p_min=P_MIN):
    r"""Pressure-dependent tangent moduli of the swelling line (Algorithm 2).

    Parameters
    ----------
    p : float
        Effective mean stress p' (Pa, compression positive).
    v : float
        Specific volume ``1 + e = 1/(1 - n)``.
    kappa : float
        Slope of the swelling line in (ln p', v).
    nu : float
        Poisson's ratio.
    p_min : float
        Floor on p' (Pa) so that the moduli stay positive as p' -> 0.

    Returns
    -------
    K, mu : float
        :math:`K = v\max(p', p_{min})/\kappa`, :math:`\mu = 3K(1-2\nu)/(2(1+\nu))` (Pa).
    """
    K = v * max(p, p_min) / kappa
    return K, 1.5 * K * (1.0 - 2.0 * nu) / (1.0 + nu)


@njit(cache=True, error_model="numpy")
def mcc_yield(tau, p_c, M):
    """Yield function ``q^2/M^2 + p'(p' - p_c)`` (Pa^2) of a tension-positive stress tau."""
    p = -(tau[0, 0] + tau[1, 1] + tau[2, 2]) / 3.0
    q2 = 0.0
    for i in range(3):
        for j in range(3):
            sij = 0.5 * (tau[i, j] + tau[j, i])
            if i == j:
                sij += p
            q2 += sij * sij
    return 1.5 * q2 / (M * M) + p * (p - p_c)


@njit(cache=True, error_model="numpy")
def mcc_trial(tau_n, dF, v, kappa, nu, p_min=P_MIN):
    r"""Objective elastic trial stress for the pressure-dependent elasticity.

    The increment :math:`\Delta\mathbf F = \Delta\mathbf V\Delta\mathbf R` (left polar
    decomposition) rotates the previous stress and stretches it by the logarithmic
    strain increment :math:`\Delta\epsilon = \ln\Delta\mathbf V
    = \tfrac12\ln(\Delta\mathbf F\Delta\mathbf F^T)` (eqs. (20)-(24) applied to an
    increment):

    .. math::
        p'^{trial} = p'_n \exp(-v\operatorname{tr}\Delta\epsilon/\kappa), \qquad
        \mathbf s^{trial} = \Delta\mathbf R\,\mathbf s_n\Delta\mathbf R^T
        + 2\mu(p'_n)\operatorname{dev}\Delta\epsilon ,

    i.e. :math:`dp' = K(p')\,d\epsilon^e_v` integrated exactly and the shear part with
    the modulus at the start of the step. A rigid rotation only rotates tau.

    Parameters
    ----------
    tau_n : ndarray, shape (3, 3)
        Kirchhoff stress at the start of the step (Pa, tension positive).
    dF : ndarray, shape (3, 3)
        Deformation gradient increment (det > 0), eq. (21).
    v, kappa, nu : float
        Specific volume, swelling slope, Poisson's ratio.
    p_min : float
        Floor on p' (Pa); a stored p' below it starts from p_min.

    Returns
    -------
    tau_trial : ndarray, shape (3, 3)
        Trial Kirchhoff stress (Pa, tension positive) for :func:`mcc_return`.
    """
    out = np.empty((3, 3))
    mcc_trial_into(tau_n, dF, v, kappa, nu, out, p_min)
    return out


@njit(cache=True, error_model="numpy")
def mcc_trial_into(tau_n, dF, v, kappa, nu, out, p_min=P_MIN):
    """:func:`mcc_trial` writing into ``out`` (3, 3); ``out`` may be ``tau_n`` (not ``dF``)."""
    # dV = sqrt(dF dF^T), d_eps = ln dV, dR = dV^-1 dF
    b00 = dF[0, 0] ** 2 + dF[0, 1] ** 2 + dF[0, 2] ** 2
    b11 = dF[1, 0] ** 2 + dF[1, 1] ** 2 + dF[1, 2] ** 2
    b22 = dF[2, 0] ** 2 + dF[2, 1] ** 2 + dF[2, 2] ** 2
    b01 = dF[0, 0] * dF[1, 0] + dF[0, 1] * dF[1, 1] + dF[0, 2] * dF[1, 2]
    b02 = dF[0, 0] * dF[2, 0] + dF[0, 1] * dF[2, 1] + dF[0, 2] * dF[2, 2]
    b12 = dF[1, 0] * dF[2, 0] + dF[1, 1] * dF[2, 1] + dF[1, 2] * dF[2, 2]
    e = _eig6(b00, b11, b22, b01, b02, b12)
    de = _recon6(0.5 * math.log(e[0]), 0.5 * math.log(e[1]), 0.5 * math.log(e[2]), e)
    w = _recon6(1.0 / math.sqrt(e[0]), 1.0 / math.sqrt(e[1]), 1.0 / math.sqrt(e[2]), e)
    w00, w11, w22, w01, w02, w12 = w
    p_n = -(tau_n[0, 0] + tau_n[1, 1] + tau_n[2, 2]) / 3.0
    t = _sym6(tau_n)
    s_n = (t[0] + p_n, t[1] + p_n, t[2] + p_n, t[3], t[4], t[5])
    for i in range(3):  # out <- dR = dV^-1 dF
        if i == 0:
            r0, r1, r2 = w00, w01, w02
        elif i == 1:
            r0, r1, r2 = w01, w11, w12
        else:
            r0, r1, r2 = w02, w12, w22
        for j in range(3):
            out[i, j] = r0 * dF[0, j] + r1 * dF[1, j] + r2 * dF[2, j]
    s_rot = _congruence6(out, s_n)  # dR s_n dR^T
    p_n = max(p_n, p_min)
    _, mu = mcc_moduli(p_n, v, kappa, nu, p_min)
    tr = de[0] + de[1] + de[2]
    p_tr = p_n * math.exp(-v * tr / kappa)
    two_mu = 2.0 * mu
    _store6((s_rot[0] + two_mu * (de[0] - tr / 3.0) - p_tr,
             s_rot[1] + two_mu * (de[1] - tr / 3.0) - p_tr,
             s_rot[2] + two_mu * (de[2] - tr / 3.0) - p_tr,
             s_rot[3] + two_mu * de[3], s_rot[4] + two_mu * de[4], s_rot[5] + two_mu * de[5]),
            out)


@njit(cache=True, error_model="numpy")
def _mcc_state(x, y, p_tr, q_tr, p_c, a, b, cmu, M2, p_min):
    """p', p_c, q, D = 1 + 6 mu x / M^2 and derivatives at (dgamma, d_eps_v_p) = (x, y)."""
    p = p_tr * math.exp(-a * y)
    pc = p_c * math.exp(b * y)
    dp_dy = -a * p
    if p > p_min:
        mu = cmu * a * p
        dmu_dy = cmu * a * dp_dy
    else:
        mu = cmu * a * p_min
        dmu_dy = 0.0
    D = 1.0 + 6.0 * mu * x / M2
    q = q_tr / D
    return p, pc, q, D, dp_dy, b * pc, 6.0 * mu / M2, 6.0 * x * dmu_dy / M2


@njit(cache=True, error_model="numpy")
def _mcc_residual(x, y, p_tr, q_tr, p_c, a, b, cmu, M2, p_min, inv_scale):
    p, pc, q, D, _, _, _, _ = _mcc_state(x, y, p_tr, q_tr, p_c, a, b, cmu, M2, p_min)
    r1 = (q * q / M2 + p * (p - pc)) * inv_scale
    r2 = y - x * (2.0 * p - pc)
    return r1, r2


@njit(cache=True, error_model="numpy")
def _mcc_g(y, p_tr, q_tr, p_c, a, b, cmu, M, p_min):
    """Scalar residual R_2(y) with dgamma eliminated through f = 0; returns (R_2, dgamma)."""
    p = p_tr * math.exp(-a * y)
    pc = p_c * math.exp(b * y)
    if not p < pc:
        return -math.inf, 0.0
    q_t = M * math.sqrt(p * (pc - p))
    mu = cmu * a * max(p, p_min)
    x = (q_tr / q_t - 1.0) * M * M / (6.0 * mu)
    return y - x * (2.0 * p - pc), x


@njit(cache=True, error_model="numpy")
def _mcc_bisect(p_tr, q_tr, p_c, a, b, cmu, M, p_min):
    """Bisection on d_eps_v_p for the return (fall-back of the Newton loop).

    With dgamma eliminated through f = 0, R_2(y) runs from -inf at p' = p_c to +inf
    as y grows, so a bracket always exists. Returns (dgamma, d_eps_v_p, iterations, ok).
    """
    y_lo = math.log(p_tr / p_c) / (a + b)  # p' = p_c on this line
    if q_tr == 0.0:
        return y_lo / (p_tr * math.exp(-a * y_lo)), y_lo, 1, True
    step = 1.0 / a
    y_hi = max(y_lo, 0.0) + step
    it = 0
    g_hi, x_hi = _mcc_g(y_hi, p_tr, q_tr, p_c, a, b, cmu, M, p_min)
    while not g_hi > 0.0 and it < 200:
        y_lo = y_hi
        step *= 2.0
        y_hi += step
        g_hi, x_hi = _mcc_g(y_hi, p_tr, q_tr, p_c, a, b, cmu, M, p_min)
        it += 1
    x_mid = x_hi
    while it < 400:
        y_mid = 0.5 * (y_lo + y_hi)
        if not (y_lo < y_mid < y_hi):
            return x_mid, y_mid, it, True
        g_mid, x_mid = _mcc_g(y_mid, p_tr, q_tr, p_c, a, b, cmu, M, p_min)
        if g_mid > 0.0:
            y_hi = y_mid
        else:
            y_lo = y_mid
        it += 1
    return x_mid, 0.5 * (y_lo + y_hi), it, False


@njit(cache=True, error_model="numpy")
def mcc_return_inplace(tau, p_c, v, kappa, lam, nu, M, p_min=P_MIN, tol=1e-10, max_iter=50):
    """Modified Cam-Clay return map on ``tau`` in place (trial in, returned out).

    See :func:`mcc_return` for the parameters.

    Returns
    -------
    p_c_new, d_eps_v_p, d_gamma : float
    iterations : int
    converged : bool
    """
    p_tr = -(tau[0, 0] + tau[1, 1] + tau[2, 2]) / 3.0
    q2 = 0.0
    for i in range(3):
        for j in range(3):
            sij = 0.5 * (tau[i, j] + tau[j, i])
            if i == j:
                sij += p_tr
            q2 += sij * sij
    q_tr = math.sqrt(1.5 * q2)
    p_c = max(p_c, p_min)
    if p_tr < p_min:  # zero confinement or tension: return to the apex p' = p_min, s = 0
        for i in range(3):
            for j in range(3):
                tau[i, j] = 0.0
            tau[i, i] = -p_min
        return p_c, 0.0, 0.0, 0, True
    M2 = M * M
    scale = max(p_c, p_tr)
    inv_scale = 1.0 / (scale * scale)
    f_tr = q_tr * q_tr / M2 + p_tr * (p_tr - p_c)
    if f_tr * inv_scale <= tol:
        return p_c, 0.0, 0.0, 0, True
    a = v / kappa
    b = v / (lam - kappa)
    cmu = 1.5 * (1.0 - 2.0 * nu) / (1.0 + nu)
    x = 0.0
    y = 0.0
    r1, r2 = _mcc_residual(x, y, p_tr, q_tr, p_c, a, b, cmu, M2, p_min, inv_scale)
    it = 0
    converged = False
    while it < max_iter:
        p, pc, q, D, dp_dy, dpc_dy, dD_dx, dD_dy = _mcc_state(x, y, p_tr, q_tr, p_c, a, b,
                                                              cmu, M2, p_min)
        dq_dx = -q / D * dD_dx
        dq_dy = -q / D * dD_dy
        j11 = 2.0 * q * dq_dx / M2 * inv_scale
        j12 = (2.0 * q * dq_dy / M2 + dp_dy * (2.0 * p - pc) - p * dpc_dy) * inv_scale
        j21 = -(2.0 * p - pc)
        j22 = 1.0 - x * (2.0 * dp_dy - dpc_dy)
        det = j11 * j22 - j12 * j21
        if det == 0.0 or det != det:
            break
        dx = (j22 * r1 - j12 * r2) / det
        dy = (j11 * r2 - j21 * r1) / det
        merit = r1 * r1 + r2 * r2
        step = 1.0
        for _ls in range(30):
            xn = x - step * dx
            yn = y - step * dy
            n1, n2 = _mcc_residual(xn, yn, p_tr, q_tr, p_c, a, b, cmu, M2, p_min, inv_scale)
            if n1 * n1 + n2 * n2 < merit or step < 1e-6:
                break
            step *= 0.5
        x, y, r1, r2 = xn, yn, n1, n2
        it += 1
        p = p_tr * math.exp(-a * y)
        pc = p_c * math.exp(b * y)
        if abs(r1) < tol and abs(r2) <= tol * (abs(y) + abs(x) * (2.0 * p + pc)):
            converged = True
            break
    if not converged:
        # safeguarded fall-back for extreme trial states (q_trial >> p'_trial)
        x, y, it_fb, converged = _mcc_bisect(p_tr, q_tr, p_c, a, b, cmu, M, p_min)
        it += it_fb
    p, pc, q, D, _, _, _, _ = _mcc_state(x, y, p_tr, q_tr, p_c, a, b, cmu, M2, p_min)
    fac = 1.0 / D
    for i in range(3):
        for j in range(3):
            tau[i, j] *= fac
    shift = fac * p_tr - p  # tau = s/D - p I  with  tau_trial = s - p_tr I
    for i in range(3):
        tau[i, i] += shift
    return pc, y, x, it, converged


@njit(cache=True, error_model="numpy")
def mcc_return(tau_trial, p_c, v, kappa, lam, nu, M, p_min=P_MIN, tol=1e-10, max_iter=50):
    r"""Modified Cam-Clay elastic-predictor / plastic-corrector, Algorithm 2 (corrected).

    Parameters
    ----------
    tau_trial : ndarray, shape (3, 3)
        Elastic trial Kirchhoff stress (Pa, **tension positive**), e.g. from
        :func:`mcc_trial`. Not modified.
    p_c : float
        Pre-consolidation pressure at the start of the step (Pa, compression positive).
    v : float
        Specific volume ``1 + e = 1/(1 - n)``.
    kappa, lam : float
        Slopes of the swelling and normal consolidation lines in (ln p', v),
        ``lam > kappa > 0``.
    nu : float
        Poisson's ratio.
    M : float
        Slope of the critical state line ``q = M p'``.
    p_min : float
        Floor on p' (Pa), see the module docstring.
    tol : float
        Tolerance on the scaled residuals ``|f|/max(p_c, p'_trial)^2`` and ``|R_2|``.
    max_iter : int
        Maximum number of Newton iterations.

    Returns
    -------
    tau_new : ndarray, shape (3, 3)
        Returned Kirchhoff stress (Pa, tension positive).
    p_c_new : float
        Updated pre-consolidation pressure (Pa, compression positive).
    d_eps_v_p : float
        Plastic volumetric strain increment (compaction positive).
    d_gamma : float
        Plastic multiplier increment (1/Pa).
    iterations : int
        Newton iterations used (0 for an elastic step).
    converged : bool
        False if the Newton loop hit ``max_iter`` (the last iterate is returned).
    """
    tau = tau_trial.copy()
    p_c_new, d_eps_v_p, d_gamma, it, ok = mcc_return_inplace(tau, p_c, v, kappa, lam, nu, M,
                                                             p_min, tol, max_iter)
    return tau, p_c_new, d_eps_v_p, d_gamma, it, ok
