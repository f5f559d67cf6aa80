r"""TLSPH pair loops over CSR neighbour lists in the reference configuration (section 3.1).

Every loop runs over the owned rows ``i < n`` of a CSR list built from the reference
positions X (fixed for the run) and skips neighbours that are not solid (``sel[j]``
false: walls, fluid). Pair quantities follow PySPH's names: ``RIJ = X_i - X_j``,
``DWIJ = F(|RIJ|) RIJ`` the uncorrected kernel gradient :math:`\nabla W(\mathbf R_{ij}, h)`
with respect to X_i (:func:`parsph.core.kernel.fac_grad`).

Corrected gradient (Randles & Libersky 1996; Bonet & Lok 1999):
:math:`\tilde\nabla W(\mathbf R_{ij}) = \mathbf L_i \nabla W(\mathbf R_{ij})` with
:math:`\mathbf L_i = \mathbf M_i^{-1}`,
:math:`\mathbf M_i = \sum_j V_j (\mathbf X_j - \mathbf X_i)\otimes\nabla W(\mathbf R_{ij})`,
symmetric positive semi-definite and equal to I for a full lattice support. Where M_i is
near-singular (few neighbours, corners, thin bodies) its eigenvalues are clamped from
below at ``floor`` before inversion: the correction is then partial along the poorly
supported direction instead of exploding (see docs/tlsph.md).

The j -> i gradient comes from antisymmetry, :math:`\tilde\nabla W(\mathbf R_{ji}) =
-\mathbf L_j\nabla W(\mathbf R_{ij})`, and L_i is applied once per particle (PERF-NOTES):
the momentum loop reads :math:`\mathbf Q_i = \mathbf L_i^T\mathbf P_i/\rho_i^2` and the
velocity-gradient loop multiplies its sum by :math:`\mathbf L_i^T` at the end.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from parsph.core.kernel import constants, fac_grad
from parsph.core.kernel import w as _w
from parsph.core.tensor import eigh3


@njit(cache=True, error_model="numpy", inline="always")
def _factor(r, h, dim):
    """:func:`parsph.core.kernel.fac_grad` rounded to float32, the value
    :func:`pair_factors` stores (the same in every sum of this module)."""
    return np.float64(np.float32(fac_grad(r, h, dim)))


@njit(cache=True, error_model="numpy")
def correction_matrices(X, vol, sel, n, indptr, indices, h, dim, floor, L):
    r"""Correction matrices :math:`\mathbf L_i` of the kernel gradient (rows ``i < n``).

    Parameters
    ----------
    X : ndarray (N, dim)
        Reference positions (m).
    vol : ndarray (N,)
        Reference volumes :math:`V_j = m_j/\rho_{0j}` (m^dim).
    sel : ndarray (N,) of bool
        Rows taking part (solid particles).
    n : int
        Owned rows.
    indptr, indices : CSR neighbour lists in the reference configuration.
    h : float
        Smoothing length (m).
    dim : int
    floor : float
        Smallest eigenvalue of M kept (relative to 1, the value of a full support).
    L : ndarray (N, 3, 3)
        Output; rows of unselected particles are set to the identity (2D: L[2, 2] = 1).

    Returns
    -------
    int
        Number of particles whose M needed the eigenvalue floor.
    """
    fp = pair_factors(X, sel, n, indptr, indices, h, dim)
    clamped = 0
    A = np.zeros((3, 3))
    for i in range(n):
        clamped += _correction_row(i, X, vol, sel, fp, indptr, indices, dim, floor, L, A)
    return clamped


@njit(cache=True, error_model="numpy")
def correction_rows(rows, X, vol, sel, fp, indptr, indices, dim, floor, L, clamp):
    """:func:`correction_matrices` of the given ``rows`` only (all owned rows at a
    set-up; after a phase change the rows whose lists changed), from the stored pair
    factors ``fp`` (:func:`pair_factors`); ``clamp[i]`` is set to whether row ``i``'s M
    needed the floor."""
    A = np.zeros((3, 3))
    for k in range(rows.shape[0]):
        i = rows[k]
        clamp[i] = _correction_row(i, X, vol, sel, fp, indptr, indices, dim, floor, L, A)


@njit(cache=True, error_model="numpy", inline="always")
def _correction_row(i, X, vol, sel, fp, indptr, indices, dim, floor, L, A):
    """L_i of :func:`correction_matrices` into ``L[i]`` (``A``: 3 x 3 scratch), the
    kernel factor of each pair read from ``fp`` (the value :func:`_factor` gives); 1 if
    M_i needed the floor, else 0."""
    for a in range(3):
        for b in range(3):
            L[i, a, b] = 1.0 if a == b else 0.0
    if not sel[i]:
        return 0
    A[:, :] = 0.0
    if dim == 2:
        A[2, 2] = 1.0
    for p in range(indptr[i], indptr[i + 1]):
        j = indices[p]
        if not sel[j]:
            continue
        f = -np.float64(fp[p]) * vol[j]
        for a in range(dim):
            for b in range(dim):
                A[a, b] += f * (X[i, a] - X[j, a]) * (X[i, b] - X[j, b])
    w, V = eigh3(A)
    for a in range(3):
        for b in range(3):
            s = 0.0
            for k in range(3):
                s += V[a, k] * V[b, k] / max(w[k], floor)
            L[i, a, b] = s
    return 1 if w[0] < floor else 0


@njit(cache=True, error_model="numpy")
def pair_factors(X, sel, n, indptr, indices, h, dim):
    r"""Per pair, :math:`F(|\mathbf R_{ij}|) = W'(R)/R` (:func:`parsph.core.kernel.fac_grad`), 0 for
    pairs with a non-solid end: the reference configuration is fixed, so the kernel is
    evaluated once (PERF-NOTES: as fast as storing the gradient). Stored in float32 (4
    bytes per pair, 90 bytes per particle of the 3D tank of ``jobs/bench_memory.py``): a
    relative rounding of 6e-8, far below the discretisation's error, and the same value
    for both ends of a pair, so the pair forces stay equal and opposite. Every TLSPH sum
    uses this rounded factor (:func:`_factor`), the correction matrices too, so the
    corrected gradients stay exact for linear fields to float64 round-off."""
    out = np.zeros(indices.shape[0], dtype=np.float32)
    for i in range(n):
        if not sel[i]:
            continue
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if not sel[j]:
                continue
            r2 = 0.0
            for a in range(dim):
                r2 += (X[i, a] - X[j, a]) ** 2
            out[p] = _factor(math.sqrt(r2), h, dim)
    return out


@njit(cache=True, error_model="numpy")
def gradient(f, X, vol, L, sel, n, indptr, indices, h, dim, out):
    r"""Corrected SPH gradient of a scalar field, :math:`\sum_j V_j (f_j - f_i)\,
    \mathbf L_i\nabla W(\mathbf R_{ij})` (the form of eq. (14)), into ``out`` (n, dim)."""
    g = np.zeros(3)
    for i in range(n):
        g[:] = 0.0
        if sel[i]:
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                if not sel[j]:
                    continue
                r2 = 0.0
                for a in range(dim):
                    r2 += (X[i, a] - X[j, a]) ** 2
                c = vol[j] * (f[j] - f[i]) * _factor(math.sqrt(r2), h, dim)
                for a in range(dim):
                    g[a] += c * (X[i, a] - X[j, a])
        for a in range(dim):
            s = 0.0
            for b in range(dim):
                s += L[i, a, b] * g[b]
            out[i, a] = s


@njit(cache=True, error_model="numpy")
def stress_divergence(Q, X, m, fp, n, indptr, indices, out):
    r"""Momentum term of eq. (13) with :math:`\rho = \rho_0`, into ``out`` (n, 3).

    :math:`\frac{1}{\rho_0}\langle\nabla_0\cdot\mathbf P\rangle_i
    = \sum_j m_j \nabla W(\mathbf R_{ij})^T (\mathbf Q_i + \mathbf Q_j)` with
    :math:`\mathbf Q = \mathbf L^T\mathbf P/\rho_0^2`: the split gradients of eq. (13),
    :math:`\tilde\nabla W(\mathbf R_{ij})\cdot\mathbf P_i/\rho_i^2 -
    \tilde\nabla W(\mathbf R_{ji})\cdot\mathbf P_j/\rho_j^2`, written with antisymmetry.
    The pair force is antisymmetric in (i, j), so linear momentum is conserved exactly.
    ``fp`` are the pair factors of :func:`pair_factors` (0 for a non-solid pair). Arrays
    are 3D (2D: zero third components), the loop written out for speed (PERF-NOTES).
    """
    for i in range(n):
        o0 = 0.0
        o1 = 0.0
        o2 = 0.0
        x0 = X[i, 0]
        x1 = X[i, 1]
        x2 = X[i, 2]
        q00, q01, q02 = Q[i, 0, 0], Q[i, 0, 1], Q[i, 0, 2]
        q10, q11, q12 = Q[i, 1, 0], Q[i, 1, 1], Q[i, 1, 2]
        q20, q21, q22 = Q[i, 2, 0], Q[i, 2, 1], Q[i, 2, 2]
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            c = m[j] * fp[p]
            r0 = x0 - X[j, 0]
            r1 = x1 - X[j, 1]
            r2 = x2 - X[j, 2]
            o0 += c * (r0 * (q00 + Q[j, 0, 0]) + r1 * (q10 + Q[j, 1, 0]) + r2 * (q20 + Q[j, 2, 0]))
            o1 += c * (r0 * (q01 + Q[j, 0, 1]) + r1 * (q11 + Q[j, 1, 1]) + r2 * (q21 + Q[j, 2, 1]))
            o2 += c * (r0 * (q02 + Q[j, 0, 2]) + r1 * (q12 + Q[j, 1, 2]) + r2 * (q22 + Q[j, 2, 2]))
        out[i, 0] = o0
        out[i, 1] = o1
        out[i, 2] = o2


@njit(cache=True, error_model="numpy")
def laplacian(v, x, m, rho, fp, n, indptr, indices, h, dim, out, coef):
    r"""Velocity Laplacian of eq. (11), into ``out`` (n, 3); each pair's coefficient
    :math:`m_j \frac{8}{\rho_i+\rho_j} F(r_{ij}) / r_{ij}^2` into ``coef`` (one per
    pair of the lists, 0 where the pair is out of the sum) unless it is empty, for
    :func:`laplacian_stored`.

    :math:`\langle\nabla^2\mathbf v\rangle_i = \sum_j m_j \frac{8}{\rho_i+\rho_j}
    \frac{\mathbf v_{ij}\cdot\mathbf r_{ij}}{r_{ij}^2}\nabla W(\mathbf r_{ij})`
    with the *current* relative position r_ij (as printed), over the fixed reference
    neighbour pairs (``fp != 0``) and the uncorrected kernel gradient. With r_ij (not
    R_ij) a rigid rotation gives v_ij . r_ij = 0: JST does not damp rotation. Applied
    to its own output it gives :math:`\nabla^4\mathbf v` of eq. (12).
    """
    k = constants(h, dim)
    store = coef.shape[0] > 0
    for i in range(n):
        o0 = 0.0
        o1 = 0.0
        o2 = 0.0
        x0, x1, x2 = x[i, 0], x[i, 1], x[i, 2]
        v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
        rho_i = rho[i]
        four_i = 4.0 / rho_i
        for p in range(indptr[i], indptr[i + 1]):
            if fp[p] == 0.0:
                if store:
                    coef[p] = 0.0
                continue
            j = indices[p]
            r0 = x0 - x[j, 0]
            r1 = x1 - x[j, 1]
            r2 = x2 - x[j, 2]
            rr = r0 * r0 + r1 * r1 + r2 * r2
            # F(r) / r^2 with one division (the pair's current distance may pass 2h)
            q = math.sqrt(rr) * k[0]
            if q < 1.0:
                f = k[2] * (-3.0 + 2.25 * q) / rr
            elif q < 2.0:
                t = 2.0 - q
                f = k[2] * (-0.75 * t * t) / (q * rr)
            else:
                if store:
                    coef[p] = 0.0
                continue
            vr = (v0 - v[j, 0]) * r0 + (v1 - v[j, 1]) * r1 + (v2 - v[j, 2]) * r2
            # 8 / (rho_i + rho_j) without a division where the densities are equal
            two = four_i if rho[j] == rho_i else 8.0 / (rho_i + rho[j])
            c = m[j] * two * vr * f
            if store:
                coef[p] = m[j] * two * f
            o0 += c * r0
            o1 += c * r1
            o2 += c * r2
        out[i, 0] = o0
        out[i, 1] = o1
        out[i, 2] = o2


@njit(cache=True, error_model="numpy")
def laplacian_stored(v, x, coef, n, indptr, indices, out):
    r""":func:`laplacian` of ``v`` over the pair coefficients ``coef`` it stored for the
    same positions: the :math:`\nabla^4\mathbf v` pass of eq. (12), without a square
    root or a kernel per pair (it had cost as much as the :math:`\nabla^2` pass, 17 ms
    of a 3D coupled step of 112,761 particles). :func:`laplacian`'s result to round-off
    (the product is taken in another order)."""
    for i in range(n):
        o0 = 0.0
        o1 = 0.0
        o2 = 0.0
        x0, x1, x2 = x[i, 0], x[i, 1], x[i, 2]
        v0, v1, v2 = v[i, 0], v[i, 1], v[i, 2]
        for p in range(indptr[i], indptr[i + 1]):
            a = coef[p]
            if a == 0.0:
                continue
            j = indices[p]
            r0 = x0 - x[j, 0]
            r1 = x1 - x[j, 1]
            r2 = x2 - x[j, 2]
            c = a * ((v0 - v[j, 0]) * r0 + (v1 - v[j, 1]) * r1 + (v2 - v[j, 2]) * r2)
            o0 += c * r0
            o1 += c * r1
            o2 += c * r2
        out[i, 0] = o0
        out[i, 1] = o1
        out[i, 2] = o2


@njit(cache=True, error_model="numpy")
def velocity_gradient(v, X, vol, L, fp, n, indptr, indices, out):
    r"""Rate of the deformation gradient, eqs. (6) and (14), into ``out`` (n, 3, 3).

    :math:`\dot{\mathbf F}_i = (\nabla_0\otimes\mathbf v)^T_i = \big[\sum_j V_j
    (\mathbf v_j - \mathbf v_i)\otimes\nabla W(\mathbf R_{ij})\big]\mathbf L_i^T`;
    in 2D the third components are zero (plane strain).
    """
    G = np.zeros((3, 3))
    for i in range(n):
        g00 = g01 = g02 = g10 = g11 = g12 = g20 = g21 = g22 = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            c = vol[j] * fp[p]
            r0 = X[i, 0] - X[j, 0]
            r1 = X[i, 1] - X[j, 1]
            r2 = X[i, 2] - X[j, 2]
            d0 = c * (v[j, 0] - v[i, 0])
            d1 = c * (v[j, 1] - v[i, 1])
            d2 = c * (v[j, 2] - v[i, 2])
            g00 += d0 * r0
            g01 += d0 * r1
            g02 += d0 * r2
            g10 += d1 * r0
            g11 += d1 * r1
            g12 += d1 * r2
            g20 += d2 * r0
            g21 += d2 * r1
            g22 += d2 * r2
        G[0, 0], G[0, 1], G[0, 2] = g00, g01, g02
        G[1, 0], G[1, 1], G[1, 2] = g10, g11, g12
        G[2, 0], G[2, 1], G[2, 2] = g20, g21, g22
        for a in range(3):
            for b in range(3):
                out[i, a, b] = G[a, 0] * L[i, b, 0] + G[a, 1] * L[i, b, 1] + G[a, 2] * L[i, b, 2]


@njit(cache=True, error_model="numpy")
def hourglass(x, X, F, m, vol, modulus, fp, n, indptr, indices, h, dim, alpha, out):
    r"""Hourglass (zero-energy mode) control of Ganzenmueller (2015), added to ``out``.

    For each pair, the separation predicted by each end's deformation gradient,
    :math:`\mathbf F_i\mathbf R_{ji}`, is compared with the actual one
    :math:`\mathbf r_{ji} = \mathbf x_j - \mathbf x_i` along it:
    :math:`\delta^i_{ij} = (\mathbf F_i\mathbf R_{ji} - \mathbf r_{ji})\cdot\hat{\mathbf r}_{ji}`,
    and a pair force :math:`\mathbf f_i = -\tfrac12\alpha\bar E V_i V_j W(R_{ij})/R_{ij}^2
    (\delta^i_{ij} + \delta^j_{ij})\hat{\mathbf r}_{ji}` (antisymmetric: momentum kept)
    restores the linear deformation the corrected gradient cannot see (the alternating
    "zig-zag" modes of TLSPH). :math:`\bar E` is the mean P-wave modulus of the pair.
    ``out`` (n, 3) gets the acceleration f_i / m_i.
    """
    for i in range(n):
        o0 = 0.0
        o1 = 0.0
        o2 = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            if fp[p] == 0.0:
                continue
            j = indices[p]
            R0 = X[j, 0] - X[i, 0]
            R1 = X[j, 1] - X[i, 1]
            R2 = X[j, 2] - X[i, 2]
            r0 = x[j, 0] - x[i, 0]
            r1 = x[j, 1] - x[i, 1]
            r2 = x[j, 2] - x[i, 2]
            rr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            RR = R0 * R0 + R1 * R1 + R2 * R2
            if rr == 0.0:
                continue
            u0 = r0 / rr
            u1 = r1 / rr
            u2 = r2 / rr
            delta = 0.0
            for side in range(2):
                k = i if side == 0 else j
                e0 = F[k, 0, 0] * R0 + F[k, 0, 1] * R1 + F[k, 0, 2] * R2 - r0
                e1 = F[k, 1, 0] * R0 + F[k, 1, 1] * R1 + F[k, 1, 2] * R2 - r1
                e2 = F[k, 2, 0] * R0 + F[k, 2, 1] * R1 + F[k, 2, 2] * R2 - r2
                delta += e0 * u0 + e1 * u1 + e2 * u2
            w = _w(math.sqrt(RR), h, dim)
            c = -0.25 * alpha * (modulus[i] + modulus[j]) * vol[i] * vol[j] * w / RR * delta
            o0 += c * u0
            o1 += c * u1
            o2 += c * u2
        out[i, 0] += o0 / m[i]
        out[i, 1] += o1 / m[i]
        out[i, 2] += o2 / m[i]


@njit(cache=True, error_model="numpy")
def kick(v, acc, lap, lap4, g, extra, sel, n, dt, cpd, eps2, c4, dim):
    r"""Eq. (7) for the solid rows ``i < n``: :math:`\mathbf v_i \mathrel{+}= \Delta t\,
    (\mathbf a_i + c_p d\,(\varepsilon^{(2)}\nabla^2\mathbf v_i - d^2\varepsilon^{(4)}
    \nabla^4\mathbf v_i) + \mathbf g + \mathbf a^{extra}_i)` in one pass, with ``cpd`` =
    :math:`c_p d` and ``c4`` = :math:`d^2\varepsilon^{(4)}`; ``lap`` (``lap4``, ``extra``)
    are read only if they have rows (pass ``np.empty((0, 3))`` for none). The operations
    are those of the numpy expression they replace, in its order (bit for bit)."""
    jst = lap.shape[0] > 0
    fourth = lap4.shape[0] > 0
    more = extra.shape[0] > 0
    for i in range(n):
        if not sel[i]:
            continue
        for a in range(dim):
            s = acc[i, a]
            if jst:
                t = eps2 * lap[i, a]
                if fourth:
                    t = t - c4 * lap4[i, a]
                s = s + cpd * t
            s = s + g[a]
            if more:
                s = s + extra[i, a]
            v[i, a] += dt * s


@njit(cache=True, error_model="numpy")
def drift(x, v, sel, n, dt, dim):
    r""":math:`\mathbf x_i \mathrel{+}= \Delta t\,\mathbf v_i` for the solid rows ``i < n``."""
    for i in range(n):
        if sel[i]:
            for a in range(dim):
                x[i, a] += dt * v[i, a]
