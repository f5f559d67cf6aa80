r"""Bingham rheology with eddy viscosity: eqs. (38)-(41) of the paper.

Strain rate (Violeau & Issa 2007), eq. (39), with the sign made explicit:

.. math::

    \dot\gamma_i^2 = -\frac{1}{2} \sum_j m_j \frac{\rho_i + \rho_j}{\rho_i \rho_j}
    \frac{\mathbf{r}_{ij} \cdot \nabla W_{ij}}{r_{ij}^2} |\mathbf{v}_i - \mathbf{v}_j|^2 .

The printed eq. (39) has no minus sign; since :math:`\mathbf{r}_{ij} \cdot \nabla W_{ij}
\le 0` it would give a negative square. With the minus sign a simple shear
:math:`v_x = \dot\gamma y` gives back :math:`\dot\gamma` on a full lattice.

Bingham viscosity with the Mohr-Coulomb yield stress and the cap, eq. (40):

.. math::

    \tau_y = c + \max(p, 0) \tan\phi', \qquad
    \nu'_f = \begin{cases} \nu_{fMAX}, & \dot\gamma < \tau_y / (\rho_0 (\nu_{fMAX} - \nu_{f0})) \\
    \nu_{f0} + \tau_y / (\dot\gamma \rho_0), & \text{otherwise,} \end{cases}

(the two branches meet continuously at the threshold) and the Smagorinsky eddy
viscosity, eq. (41), :math:`\nu_{edd} = (C_s \Delta)^2 \dot\gamma`, added only when the
material asks for it. Boundary (wall) neighbours enter the strain rate with their own
velocity (the prescribed wall velocity) when the wall is no-slip, and not at all when
it is free-slip.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.core.kernel import constants, delta, fac_grad_k

__all__ = ["fluid_strain_rate", "strain_rate", "viscosity"]


@njit(cache=True, error_model="numpy")
def _strain_rate(x, v, m, rho, fluid, slip, indptr, indices, h, dim, out):
    n = indptr.shape[0] - 1
    k = constants(h, dim)
    for i in range(n):
        if not fluid[i]:
            out[i] = 0.0
            continue
        acc = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if not fluid[j] and slip[j]:
                continue
            r2 = delta(x, i, j, dim)[3]
            dv2 = delta(v, i, j, dim)[3]
            f = fac_grad_k(math.sqrt(r2), k)  # r.grad W / r^2
            acc -= 0.5 * m[j] * (rho[i] + rho[j]) / (rho[i] * rho[j]) * f * dv2
        out[i] = math.sqrt(max(acc, 0.0))
    return out


def strain_rate(x, v, m, rho, fluid, slip, indptr, indices, h, dim):
    r"""Strain rate :math:`\dot\gamma` (1/s) of the owned rows, eq. (39).

    Parameters
    ----------
    x, v : numpy.ndarray, shape (N, dim)
        Positions (m) and velocities (m/s) of all rows (owned, then halo).
    m, rho : numpy.ndarray, shape (N,)
        Masses (kg) and densities (kg/m^3) of all rows.
    fluid, slip : numpy.ndarray of uint8, shape (N,)
        1 for fluid rows; 1 for free-slip boundary rows (skipped).
    indptr, indices : CSR neighbour lists of the owned rows (self excluded).
    h : float
        Smoothing length (m).
    dim : int
        2 or 3.

    Returns
    -------
    numpy.ndarray, shape (n_owned,)
        :math:`\dot\gamma_i \ge 0`; 0 for non-fluid rows.
    """
    out = np.empty(len(indptr) - 1)
    return _strain_rate(x, v, m, rho, fluid, slip, indptr, indices, float(h), int(dim), out)


def fluid_strain_rate(x, v, v_ghost, m, rho, fluid, solid, slip, indptr, indices, h, dim,
                      material, table):
    """:func:`strain_rate` of the owned rows where a viscosity reads it, zeros elsewhere.

    Only the Bingham viscosity (40) and the eddy viscosity (41) depend on the strain
    rate; while no owned fluid row has such a material (water, or a landslide before
    any soil fluidises) it is not computed (21 ms of a 0.57 s step of the 3D coupled
    tank at 1.1e5 particles). Wall rows enter with their no-slip ghost velocity of the
    last viscous solve (Adami et al. 2012), fluid and solid rows (``solid > 0``) with
    their velocity."""
    n = len(indptr) - 1
    rows = material[:n][fluid[:n] == 1]
    if not (table["bingham"][rows] | table["eddy"][rows]).any():
        return np.zeros(n)
    vel = np.where(((fluid == 1) | (solid > 0))[:, None], v, v_ghost)
    return strain_rate(x, vel, m, rho, fluid, slip, indptr, indices, h, dim)


@njit(cache=True, error_model="numpy")
def _viscosity(gamma, p, fluid, material, nu0, nu_max, cohesion, tan_phi, bingham, eddy,
               rho0, les, out):
    for i in range(gamma.shape[0]):
        if not fluid[i]:
            out[i] = 0.0
            continue
        k = material[i]
        g = gamma[i]
        nu = nu0[k]
        if bingham[k]:
            tau_y = cohesion[k] + max(p[i], 0.0) * tan_phi[k]
            if g * rho0[k] * (nu_max[k] - nu0[k]) <= tau_y:
                nu = nu_max[k]
            else:
                nu = nu0[k] + tau_y / (g * rho0[k])
        if eddy[k]:
            nu += les * les * g
        out[i] = nu
    return out


def viscosity(gamma, p, fluid, material, table, les_length):
    r"""Kinematic viscosity :math:`\nu_f` (m^2/s) of the owned rows, eqs. (40)-(41).

    Parameters
    ----------
    gamma : numpy.ndarray, shape (n,)
        Strain rate (1/s), eq. (39).
    p : numpy.ndarray, shape (n,)
        Pressure (Pa) of the previous step (the yield stress uses ``max(p, 0)``).
    fluid : numpy.ndarray of uint8, shape (n,)
    material : numpy.ndarray of int16, shape (n,)
        Index into the material table (valid where ``fluid``).
    table : dict of numpy.ndarray
        Per material: ``nu0``, ``nu_max``, ``cohesion`` (Pa), ``tan_phi``, ``bingham``,
        ``eddy`` (uint8) and ``rho0`` (kg/m^3); see :func:`material_table`.
    les_length : float
        :math:`C_s \Delta` (m) of eq. (41).

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    out = np.empty(len(gamma))
    return _viscosity(gamma, p, fluid, material, table["nu0"], table["nu_max"],
                      table["cohesion"], table["tan_phi"], table["bingham"], table["eddy"],
                      table["rho0"], float(les_length), out)


def material_table(materials) -> dict:
    """Per-material arrays of the rheology parameters (index = material index).

    Non-fluid materials get zeros. ``Newtonian``: constant ``viscosity``; ``Bingham``:
    ``viscosity`` (nu_f0), ``viscosity_max``, ``cohesion``, ``friction_angle``.
    """
    n = max(len(materials), 1)
    t = {k: np.zeros(n) for k in ("nu0", "nu_max", "cohesion", "tan_phi", "rho0")}
    t.update({k: np.zeros(n, dtype=np.uint8) for k in ("bingham", "eddy")})
    for k, mat in enumerate(materials):
        if mat.model not in ("newtonian", "bingham"):
            continue
        t["rho0"][k] = mat.density
        t["nu0"][k] = mat.viscosity
        t["eddy"][k] = bool(mat.eddy_viscosity)
        if mat.model == "bingham":
            t["bingham"][k] = 1
            t["nu_max"][k] = mat.viscosity_max
            t["cohesion"][k] = mat.cohesion
            t["tan_phi"][k] = math.tan(math.radians(mat.friction_angle))
    return t
