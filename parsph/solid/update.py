r"""Per-particle solid update: F, porosity and the constitutive return (section 3.2).

One numba loop over the owned solid particles (:func:`update_particles`), dispatching on
a material table built once by :func:`material_table`:

- eqs. (20)-(21): :math:`\mathbf F^{\beta+1} = \mathbf F^\beta + \Delta t\,\dot{\mathbf F}`
  (eq. (8)), i.e. :math:`\Delta\mathbf F = \mathbf I + \Delta t\,\dot{\mathbf F}
  (\mathbf F^\beta)^{-1}`;
- eq. (5): :math:`n^{\beta+1} = n^\beta + \Delta t (1-n^\beta)
  \operatorname{tr}(\dot{\mathbf F}(\mathbf F^\beta)^{-1})` -- the SPH sum of eq. (5) is
  exactly this trace of the corrected velocity gradient of eq. (14);
- Hencky (eqs. (22)-(27)), Drucker-Prager (Appendix A) and modified Cam-Clay
  (Appendix B) through the material-point modules; P = F^-1 tau, eq. (27).

Model codes: 0 Hencky, 1 Drucker-Prager, 2 modified Cam-Clay.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.solid.cam_clay import P_MIN, mcc_return_inplace, mcc_trial_into
from parsph.solid.drucker_prager import dp_params, dp_return_coeffs_inplace
from parsph.solid.hencky import (eps_from_tau_kmu, hencky_tau_into, lame_from_young,
                                 nominal_stress_into, trial_state_into)
from parsph.core.tensor import det3, inv3_into
from parsph.scene.materials import CamClay, DruckerPrager, Hencky

HENCKY, DRUCKER_PRAGER, CAM_CLAY = 0, 1, 2
#: Columns of the material table.
COLS = ("model", "K", "mu", "rho0", "c0", "H", "c_r", "xi", "eta", "eta_bar", "kappa",
        "lam", "M", "nu", "porosity_update", "m_nl")
C = {name: k for k, name in enumerate(COLS)}


def material_table(materials, m_nl=None) -> np.ndarray:
    """One row of parameters per material (scene order); unused entries are 0.

    For Cam-Clay K and mu are pressure dependent and computed per particle; the row holds
    nu, kappa, lambda and M. ``m_nl``: the over-non-local factor m of each Drucker-Prager
    material (:mod:`parsph.solid.regularise`; 0 = the paper's local softening).
    """
    tab = np.zeros((max(len(materials), 1), len(COLS)))
    for k, mat in enumerate(materials):
        row = tab[k]
        row[C["rho0"]] = getattr(mat, "reference_density", getattr(mat, "density", 0.0))
        row[C["nu"]] = getattr(mat, "poisson_ratio", 0.0)
        row[C["porosity_update"]] = float(getattr(mat, "update_porosity", False))
        if isinstance(mat, (Hencky, DruckerPrager)):
            K, mu = lame_from_young(mat.young_modulus, mat.poisson_ratio)
            row[C["K"]], row[C["mu"]] = K, mu
            row[C["model"]] = HENCKY
        if isinstance(mat, DruckerPrager):
            row[C["model"]] = DRUCKER_PRAGER
            xi, eta, eta_bar = dp_params(math.radians(mat.friction_angle),
                                         math.radians(mat.dilatancy_angle))
            row[C["c0"]], row[C["H"]], row[C["c_r"]] = (mat.cohesion, mat.hardening,
                                                        mat.residual_cohesion)
            row[C["xi"]], row[C["eta"]], row[C["eta_bar"]] = xi, eta, eta_bar
        if isinstance(mat, CamClay):
            row[C["model"]] = CAM_CLAY
            row[C["kappa"]], row[C["lam"]] = mat.kappa, mat.lam
            row[C["M"]] = mat.critical_state_ratio
            row[C["porosity_update"]] = 1.0  # v = 1/(1-n) drives the Cam-Clay moduli
    if m_nl is not None:
        tab[: len(materials), C["m_nl"]] = m_nl
    return tab



@njit(cache=True, error_model="numpy")
def wave_speed(tab, material, pressure, porosity, sel, n, modulus):
    r"""Largest p-wave speed :math:`c_p = \sqrt{(K + 4\mu/3)/\rho_0}` of eq. (10) (m/s).

    eq. (10) prints the grain density :math:`\rho_s`; the mass density of the skeleton is
    :math:`\rho_0 = (1-n_0)\rho_s` (what the momentum equation divides by), which gives the
    larger, safe wave speed. Cam-Clay: :math:`K = v\max(p', p_{min})/\kappa`. The P-wave
    modulus :math:`K + 4\mu/3` (Pa) of each row goes to ``modulus``.
    """
    cmax = 0.0
    for i in range(n):
        if not sel[i]:
            continue
        row = tab[material[i]]
        if row[0] == CAM_CLAY:
            vs = 1.0 / (1.0 - porosity[i])
            K = vs * max(pressure[i], P_MIN) / row[10]
            mu = 1.5 * K * (1.0 - 2.0 * row[13]) / (1.0 + row[13])
        else:
            K = row[1]
            mu = row[2]
        modulus[i] = K + 4.0 * mu / 3.0
        c = math.sqrt(modulus[i] / row[3])
        cmax = max(cmax, c)
    return cmax


@njit(cache=True, error_model="numpy")
def elastic_energy(tab, material, sel, n, vol, eps_e):
    r"""Stored Hencky energy :math:`\sum V_0 (\mu\,\mathrm{dev}\,\varepsilon :
    \mathrm{dev}\,\varepsilon + \tfrac{K}{2} (\mathrm{tr}\,\varepsilon)^2)` (J, or J/m in
    2D) of the selected Hencky and Drucker-Prager rows, ``eps_e`` the elastic log strain
    (eq. (26)); Cam-Clay's pressure-dependent elasticity is left out."""
    total = 0.0
    for i in range(n):
        if not sel[i]:
            continue
        row = tab[material[i]]
        if row[0] == CAM_CLAY:
            continue
        e = eps_e[i]
        tr = e[0, 0] + e[1, 1] + e[2, 2]
        sq = 0.0
        for a in range(3):
            for b in range(3):
                sq += e[a, b] * e[a, b]
        total += vol[i] * (row[2] * (sq - tr * tr / 3.0) + 0.5 * row[1] * tr * tr)
    return total


@njit(cache=True, error_model="numpy")
def update_particles(tab, material, sel, n, dt, Fdot, F, tau, eps_e, eps_p, p_c,
                     porosity, pressure, failed, dim, shift):
    r"""Advance F, porosity and stress of the owned solid particles by one step.

    A Drucker-Prager soil with an over-non-local factor m > 0
    (:mod:`parsph.solid.regularise`) softens with :math:`\hat\kappa = \kappa^{\beta+1} +
    m(\tilde\kappa^s - \kappa^s)`, s the step of the last non-local solve (``shift``
    holds :math:`\tilde\kappa^s - \kappa^s`): its cohesion is :math:`c_0 + H\hat\kappa`,
    at most :math:`c_0`. With m = 0 nothing changes.

    Parameters
    ----------
    tab : ndarray
        :func:`material_table`.
    material : ndarray of int16
        Material index per row.
    sel : ndarray of bool
        Rows to update (owned solid particles).
    n : int
        Owned rows.
    dt : float
        Time step (s).
    Fdot : ndarray (n, 3, 3)
        Rate of F from :func:`parsph.solid.kernels.velocity_gradient`.
    F, tau, eps_e : ndarray (N, 3, 3)
        Deformation gradient, Kirchhoff stress (Pa), elastic log strain; updated in place
        (the nominal stress follows from F and tau, :func:`stress_terms`).
    eps_p, p_c, porosity, pressure : ndarray (N,)
        Accumulated plastic strain, pre-consolidation pressure (Pa), porosity, and the
        output pressure ``-tr(sigma)/3`` (Pa, compression positive); updated in place.
    failed : ndarray of uint8 (n,)
        Set to 1 for the particles with det F <= 0 or a failed return (left unchanged).
    dim : int
    shift : ndarray (N,)
        :math:`\tilde\kappa - \kappa` at the last non-local solve (read where m > 0;
        any array of N values if no material has m > 0).
    Returns
    -------
    bad : int
        Index of the first particle with det F <= 0 or a failed return, else -1.
    plastic : int
        Number of particles that yielded in this step.
    """
    Finv = np.empty((3, 3))
    dF = np.empty((3, 3))
    Fn = np.empty((3, 3))
    work = np.empty((3, 3))
    bad = -1
    plastic = 0
    for i in range(n):
        if not sel[i]:
            continue
        row = tab[material[i]]
        model = int(row[0])
        inv3_into(F[i], Finv)
        for a in range(3):
            for b in range(3):
                Fn[a, b] = F[i, a, b] + dt * Fdot[i, a, b]
        for a in range(3):
            for b in range(3):
                s = 0.0
                for k in range(3):
                    s += Fdot[i, a, k] * Finv[k, b]
                dF[a, b] = (1.0 if a == b else 0.0) + dt * s
        if dim == 2:
            Fn[2, 2] = 1.0
            dF[2, 2] = 1.0
        J = det3(Fn)
        if not (J > 0.0) or not (det3(dF) > 0.0):
            failed[i] = 1
            if bad < 0:
                bad = i
            continue
        if row[14] > 0.0:  # eq. (5)
            trd = dF[0, 0] + dF[1, 1] + dF[2, 2] - 3.0
            porosity[i] = min(max(porosity[i] + (1.0 - porosity[i]) * trd, 0.0), 0.999)
        for a in range(3):
            for b in range(3):
                F[i, a, b] = Fn[a, b]
        m_nl = row[15]
        if model == CAM_CLAY:
            vs = 1.0 / (1.0 - porosity[i])
            mcc_trial_into(tau[i], dF, vs, row[10], row[13], work)
            pc_new, dev, dgam, it, ok = mcc_return_inplace(work, p_c[i], vs, row[10], row[11],
                                                           row[13], row[12])
            if not ok:
                failed[i] = 1
                if bad < 0:
                    bad = i
            if dgam > 0.0:
                plastic += 1
                # equivalent plastic strain sqrt(2/3 d_eps_p : d_eps_p)
                pm = -(work[0, 0] + work[1, 1] + work[2, 2]) / 3.0
                ss = 0.0
                for a in range(3):
                    for b in range(3):
                        sab = work[a, b] + (pm if a == b else 0.0)
                        ss += sab * sab
                de2 = (3.0 * dgam / (row[12] * row[12])) ** 2 * ss
                eps_p[i] += math.sqrt(2.0 / 3.0 * (de2 + dev * dev / 3.0))
            p_c[i] = pc_new
            tau[i, :, :] = work
        else:
            K = row[1]
            mu = row[2]
            trial_state_into(dF, eps_e[i], work)
            hencky_tau_into(work, K, mu, tau[i])
            if model == DRUCKER_PRAGER:
                c0 = row[4]
                c_max = math.inf
                if m_nl > 0.0:  # softening on the over-non-local strain, c <= c0
                    c0 += row[5] * m_nl * shift[i]
                    c_max = row[4]
                e_new, flag = dp_return_coeffs_inplace(tau[i], eps_p[i], K, mu, c0, row[5],
                                                       row[6], row[7], row[8], row[9], c_max)
                if flag > 0:
                    plastic += 1
                    eps_p[i] = e_new
                    eps_e[i, :, :] = eps_from_tau_kmu(tau[i], K, mu)  # eq. (26)
                else:
                    eps_e[i, :, :] = work
            else:
                eps_e[i, :, :] = work
        pressure[i] = -(tau[i, 0, 0] + tau[i, 1, 1] + tau[i, 2, 2]) / (3.0 * J)
    return bad, plastic


@njit(cache=True, error_model="numpy")
def stress_terms(tau, F, L, rho0_of, material, sel, n, dim, ambient, Q):
    r"""Per-particle :math:`\mathbf Q_i = \mathbf L_i^T(\mathbf P_i - \mathbf P^{amb}_i)
    /\rho_{0i}^2` read by :func:`parsph.solid.kernels.stress_divergence`, with the
    nominal stress :math:`\mathbf P_i = \mathbf F_i^{-1}\boldsymbol\tau_i` of eq. (27)
    (:func:`parsph.solid.hencky.nominal_stress_into`) made here and not kept (72 bytes
    per solid particle in 3D).

    :math:`\mathbf P^{amb} = -p_{amb} J\mathbf F^{-1}` is the nominal stress of a uniform
    external pressure (its divergence vanishes, Piola identity): subtracting it makes
    every free surface carry the traction :math:`-p_{amb}\mathbf n` (triaxial cell
    pressure); ``ambient = 0`` leaves traction-free surfaces.
    """
    Finv = np.empty((3, 3))
    P = np.empty((3, 3))
    for i in range(n):
        if not sel[i]:
            for a in range(dim):
                for b in range(dim):
                    Q[i, a, b] = 0.0
            continue
        nominal_stress_into(F[i], tau[i], P)
        J = 1.0
        if ambient != 0.0:
            J = inv3_into(F[i], Finv)
        r2 = 1.0 / (rho0_of[material[i]] ** 2)
        for a in range(dim):
            for b in range(dim):
                s = 0.0
                for k in range(dim):
                    pk = P[k, b]
                    if ambient != 0.0:
                        pk += ambient * J * Finv[k, b]
                    s += L[i, k, a] * pk
                Q[i, a, b] = s * r2
