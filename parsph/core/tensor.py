r"""3x3 tensor helpers (numba, one material point): the constitutive models, the fluid's
corrected gradient.

The finite-strain models of the paper (section 3.2) need, per particle and step, the
tensor logarithm of the trial left Cauchy-Green tensor, eq. (24), and the tensor
exponential of the previous logarithmic strain, eq. (22). Both are isotropic functions
of a symmetric matrix and are evaluated through its spectral decomposition
:math:`\mathbf A = \sum_k \lambda_k \mathbf v_k \otimes \mathbf v_k`,
:math:`f(\mathbf A) = \sum_k f(\lambda_k)\, \mathbf v_k \otimes \mathbf v_k`.

Eigen-decomposition
-------------------
Closed form (fastest measured, see PERF-NOTES), made robust for repeated eigenvalues:

1. shift by the mean, :math:`\mathbf D = \mathbf A - \tfrac13 \operatorname{tr}\mathbf A\,
   \mathbf I` (then remove the round-off trace of D, which matters when A is close to
   a multiple of I, e.g. B near I), and scale D by its largest entry (no over/underflow,
   accuracy relative to the deviator, not to the mean);
2. trigonometric formula (Smith 1961) for the *single* eigenvalue farthest from the
   other two only (the largest if :math:`\det \ge 0`, else the smallest): it is always
   separated from the others by at least :math:`\sqrt3\,p`, so it is well conditioned,
   whereas the trigonometric values of a (nearly) double pair lose half the digits;
3. its eigenvector from the largest cross product of two rows of
   :math:`\mathbf D - \lambda \mathbf I`;
4. the remaining pair from one exact Jacobi rotation of the 2x2 projection of
   :math:`\mathbf D` on the orthogonal complement (Eberly 2014, "A robust eigensolver for
   3x3 symmetric matrices"): repeated eigenvalues need no special case and the
   eigenvectors are orthonormal by construction;
5. residual check :math:`\max_k|\mathbf D\mathbf v_k-\lambda_k\mathbf v_k|`; if it is
   above ``1e-10`` (relative) the cyclic Jacobi method is used instead.

All kernels use scalars and tuples internally (no heap allocation); the public
``*_into`` variants write into caller arrays, the others return new arrays.
"""
import math

import numpy as np
from numba import njit

_TWO_PI_3 = 2.0 * math.pi / 3.0
_RESIDUAL_TOL = 1e-10


@njit(cache=True, error_model="numpy")
def _sym6(A):
    """Symmetric part of a 3x3 array as the tuple (a00, a11, a22, a01, a02, a12)."""
    return (A[0, 0], A[1, 1], A[2, 2],
            0.5 * (A[0, 1] + A[1, 0]), 0.5 * (A[0, 2] + A[2, 0]), 0.5 * (A[1, 2] + A[2, 1]))


@njit(cache=True, error_model="numpy")
def _jacobi6(a00, a11, a22, a01, a02, a12):
    """Cyclic Jacobi eigen-solver (fall-back); same tuple layout as :func:`_eig6`."""
    a = np.empty((3, 3))
    a[0, 0] = a00
    a[1, 1] = a11
    a[2, 2] = a22
    a[0, 1] = a[1, 0] = a01
    a[0, 2] = a[2, 0] = a02
    a[1, 2] = a[2, 1] = a12
    v = np.eye(3)
    for _sweep in range(50):
        off = a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2
        diag = a[0, 0] ** 2 + a[1, 1] ** 2 + a[2, 2] ** 2
        if not off > 1e-36 * diag:
            break
        for p in range(2):
            for q in range(p + 1, 3):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(3):  # A <- A J
                    akp = a[k, p]
                    akq = a[k, q]
                    a[k, p] = c * akp - s * akq
                    a[k, q] = s * akp + c * akq
                for k in range(3):  # A <- J^T A
                    apk = a[p, k]
                    aqk = a[q, k]
                    a[p, k] = c * apk - s * aqk
                    a[q, k] = s * apk + c * aqk
                for k in range(3):  # V <- V J
                    vkp = v[k, p]
                    vkq = v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    return _sorted(a[0, 0], a[1, 1], a[2, 2],
                   v[0, 0], v[1, 0], v[2, 0], v[0, 1], v[1, 1], v[2, 1], v[0, 2], v[1, 2], v[2, 2])


@njit(cache=True, error_model="numpy")
def _sorted(l0, l1, l2, x0, y0, z0, x1, y1, z1, x2, y2, z2):
    """Sort three eigenpairs by ascending eigenvalue (vectors follow their values)."""
    if l0 > l1:
        l0, l1 = l1, l0
        x0, y0, z0, x1, y1, z1 = x1, y1, z1, x0, y0, z0
    if l1 > l2:
        l1, l2 = l2, l1
        x1, y1, z1, x2, y2, z2 = x2, y2, z2, x1, y1, z1
    if l0 > l1:
        l0, l1 = l1, l0
        x0, y0, z0, x1, y1, z1 = x1, y1, z1, x0, y0, z0
    return (l0, l1, l2, x0, y0, z0, x1, y1, z1, x2, y2, z2)


@njit(cache=True, error_model="numpy")
def _eig6(a00, a11, a22, a01, a02, a12):
    """Eigen-decomposition of a symmetric 3x3 matrix given by its 6 components.

    Returns the 12-tuple ``(l0, l1, l2, v0x, v0y, v0z, v1x, v1y, v1z, v2x, v2y, v2z)``
    with ascending eigenvalues and orthonormal eigenvectors ``v_k``.
    """
    m = (a00 + a11 + a22) / 3.0
    d00 = a00 - m
    d11 = a11 - m
    d22 = a22 - m
    t = (d00 + d11 + d22) / 3.0  # round-off of the mean, large relative to a small deviator
    m += t
    d00 -= t
    d11 -= t
    d22 -= t
    s = max(abs(d00), abs(d11), abs(d22), abs(a01), abs(a02), abs(a12))
    if not s > 1e-300:  # isotropic (or NaN: the Jacobi path propagates it)
        if s == s:
            return (m, m, m, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        return _jacobi6(a00, a11, a22, a01, a02, a12)
    inv = 1.0 / s
    b00 = d00 * inv
    b11 = d11 * inv
    b22 = d22 * inv
    b01 = a01 * inv
    b02 = a02 * inv
    b12 = a12 * inv
    # 1) the isolated eigenvalue of B (trigonometric form, Smith 1961)
    pp = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (b01 * b01 + b02 * b02 + b12 * b12)) / 6.0
    p = math.sqrt(pp)
    detb = (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
            + b02 * (b01 * b12 - b11 * b02))
    r = 0.5 * detb / (pp * p)
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    if r >= 0.0:
        lam = 2.0 * p * math.cos(phi)
    else:
        lam = 2.0 * p * math.cos(phi + _TWO_PI_3)
    # 2) its eigenvector: largest cross product of two rows of (B - lam I)
    r0x, r0y, r0z = b00 - lam, b01, b02
    r1x, r1y, r1z = b01, b11 - lam, b12
    r2x, r2y, r2z = b02, b12, b22 - lam
    c01x = r0y * r1z - r0z * r1y
    c01y = r0z * r1x - r0x * r1z
    c01z = r0x * r1y - r0y * r1x
    c02x = r0y * r2z - r0z * r2y
    c02y = r0z * r2x - r0x * r2z
    c02z = r0x * r2y - r0y * r2x
    c12x = r1y * r2z - r1z * r2y
    c12y = r1z * r2x - r1x * r2z
    c12z = r1x * r2y - r1y * r2x
    n01 = c01x * c01x + c01y * c01y + c01z * c01z
    n02 = c02x * c02x + c02y * c02y + c02z * c02z
    n12 = c12x * c12x + c12y * c12y + c12z * c12z
    if n01 >= n02 and n01 >= n12:
        vx, vy, vz, nn = c01x, c01y, c01z, n01
    elif n02 >= n12:
        vx, vy, vz, nn = c02x, c02y, c02z, n02
    else:
        vx, vy, vz, nn = c12x, c12y, c12z, n12
    if not nn > 0.0:
        return _jacobi6(a00, a11, a22, a01, a02, a12)
    inv_n = 1.0 / math.sqrt(nn)
    vx *= inv_n
    vy *= inv_n
    vz *= inv_n
    # 3) orthonormal basis (u, w) of the complement of v
    if abs(vx) > abs(vy):
        inv_n = 1.0 / math.sqrt(vx * vx + vz * vz)
        ux, uy, uz = -vz * inv_n, 0.0, vx * inv_n
    else:
        inv_n = 1.0 / math.sqrt(vy * vy + vz * vz)
        ux, uy, uz = 0.0, vz * inv_n, -vy * inv_n
    wx = vy * uz - vz * uy
    wy = vz * ux - vx * uz
    wz = vx * uy - vy * ux
    # 4) 2x2 projection [[a, b], [b, c]] of B on (u, w) and one exact Jacobi rotation
    bux = b00 * ux + b01 * uy + b02 * uz
    buy = b01 * ux + b11 * uy + b12 * uz
    buz = b02 * ux + b12 * uy + b22 * uz
    bwx = b00 * wx + b01 * wy + b02 * wz
    bwy = b01 * wx + b11 * wy + b12 * wz
    bwz = b02 * wx + b12 * wy + b22 * wz
    pa = ux * bux + uy * buy + uz * buz
    pb = wx * bux + wy * buy + wz * buz
    pc = wx * bwx + wy * bwy + wz * bwz
    if pb == 0.0:
        cs, sn, t = 1.0, 0.0, 0.0
    else:
        theta = (pc - pa) / (2.0 * pb)
        t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
        if theta < 0.0:
            t = -t
        cs = 1.0 / math.sqrt(t * t + 1.0)
        sn = t * cs
    l1 = pa - t * pb
    l2 = pc + t * pb
    e1x, e1y, e1z = cs * ux - sn * wx, cs * uy - sn * wy, cs * uz - sn * wz
    e2x, e2y, e2z = sn * ux + cs * wx, sn * uy + cs * wy, sn * uz + cs * wz
    # Rayleigh quotient for the isolated eigenvalue (more accurate than lam)
    l0 = (vx * (b00 * vx + b01 * vy + b02 * vz) + vy * (b01 * vx + b11 * vy + b12 * vz)
          + vz * (b02 * vx + b12 * vy + b22 * vz))
    # 5) residual check, relative to max|B_ij| = 1
    res = 0.0
    for k in range(3):
        if k == 0:
            lk, xk, yk, zk = l0, vx, vy, vz
        elif k == 1:
            lk, xk, yk, zk = l1, e1x, e1y, e1z
        else:
            lk, xk, yk, zk = l2, e2x, e2y, e2z
        res = max(res, abs(b00 * xk + b01 * yk + b02 * zk - lk * xk),
                  abs(b01 * xk + b11 * yk + b12 * zk - lk * yk),
                  abs(b02 * xk + b12 * yk + b22 * zk - lk * zk))
    if not res < _RESIDUAL_TOL:
        return _jacobi6(a00, a11, a22, a01, a02, a12)
    return _sorted(m + s * l0, m + s * l1, m + s * l2,
                   vx, vy, vz, e1x, e1y, e1z, e2x, e2y, e2z)


@njit(cache=True, error_model="numpy")
def _recon6(f0, f1, f2, e):
    """Components (s00, s11, s22, s01, s02, s12) of sum_k f_k v_k v_k^T for ``e = _eig6(...)``."""
    x0, y0, z0, x1, y1, z1, x2, y2, z2 = e[3], e[4], e[5], e[6], e[7], e[8], e[9], e[10], e[11]
    return (f0 * x0 * x0 + f1 * x1 * x1 + f2 * x2 * x2,
            f0 * y0 * y0 + f1 * y1 * y1 + f2 * y2 * y2,
            f0 * z0 * z0 + f1 * z1 * z1 + f2 * z2 * z2,
            f0 * x0 * y0 + f1 * x1 * y1 + f2 * x2 * y2,
            f0 * x0 * z0 + f1 * x1 * z1 + f2 * x2 * z2,
            f0 * y0 * z0 + f1 * y1 * z1 + f2 * y2 * z2)


@njit(cache=True, error_model="numpy")
def _store6(s, out):
    """Write 6 symmetric components into a 3x3 array."""
    out[0, 0] = s[0]
    out[1, 1] = s[1]
    out[2, 2] = s[2]
    out[0, 1] = out[1, 0] = s[3]
    out[0, 2] = out[2, 0] = s[4]
    out[1, 2] = out[2, 1] = s[5]


@njit(cache=True, error_model="numpy")
def _congruence6(F, s):
    """Components of the symmetric product F S F^T, S given by 6 components."""
    s00, s11, s22, s01, s02, s12 = s
    # T = F S
    t00 = F[0, 0] * s00 + F[0, 1] * s01 + F[0, 2] * s02
    t01 = F[0, 0] * s01 + F[0, 1] * s11 + F[0, 2] * s12
    t02 = F[0, 0] * s02 + F[0, 1] * s12 + F[0, 2] * s22
    t10 = F[1, 0] * s00 + F[1, 1] * s01 + F[1, 2] * s02
    t11 = F[1, 0] * s01 + F[1, 1] * s11 + F[1, 2] * s12
    t12 = F[1, 0] * s02 + F[1, 1] * s12 + F[1, 2] * s22
    t20 = F[2, 0] * s00 + F[2, 1] * s01 + F[2, 2] * s02
    t21 = F[2, 0] * s01 + F[2, 1] * s11 + F[2, 2] * s12
    t22 = F[2, 0] * s02 + F[2, 1] * s12 + F[2, 2] * s22
    return (t00 * F[0, 0] + t01 * F[0, 1] + t02 * F[0, 2],
            t10 * F[1, 0] + t11 * F[1, 1] + t12 * F[1, 2],
            t20 * F[2, 0] + t21 * F[2, 1] + t22 * F[2, 2],
            t00 * F[1, 0] + t01 * F[1, 1] + t02 * F[1, 2],
            t00 * F[2, 0] + t01 * F[2, 1] + t02 * F[2, 2],
            t10 * F[2, 0] + t11 * F[2, 1] + t12 * F[2, 2])


@njit(cache=True, error_model="numpy")
def eigh3(A):
    """Eigen-decomposition of a symmetric 3x3 matrix.

    Parameters
    ----------
    A : ndarray, shape (3, 3)
        Symmetric matrix (only its symmetric part is used).

    Returns
    -------
    w : ndarray, shape (3,)
        Eigenvalues in ascending order (as :func:`numpy.linalg.eigh`).
    V : ndarray, shape (3, 3)
        Orthonormal eigenvectors as columns, ``A @ V[:, k] == w[k] * V[:, k]``.

    Notes
    -----
    Closed form with a Jacobi fall-back; see the module docstring.
    """
    w = np.empty(3)
    V = np.empty((3, 3))
    eigh3_into(A, w, V)
    return w, V


@njit(cache=True, error_model="numpy")
def eigh3_into(A, w, V):
    """:func:`eigh3` writing into ``w`` (3,) and ``V`` (3, 3); returns nothing."""
    e = _eig6(*_sym6(A))
    for k in range(3):
        w[k] = e[k]
        V[0, k] = e[3 + 3 * k]
        V[1, k] = e[4 + 3 * k]
        V[2, k] = e[5 + 3 * k]


@njit(cache=True, error_model="numpy")
def eigh3_jacobi(A):
    """Eigen-decomposition by cyclic Jacobi rotations (the fall-back path), as :func:`eigh3`."""
    e = _jacobi6(*_sym6(A))
    w = np.empty(3)
    V = np.empty((3, 3))
    for k in range(3):
        w[k] = e[k]
        V[0, k] = e[3 + 3 * k]
        V[1, k] = e[4 + 3 * k]
        V[2, k] = e[5 + 3 * k]
    return w, V


@njit(cache=True, error_model="numpy")
def logm_spd_into(A, out):
    """Tensor logarithm of a symmetric positive-definite 3x3 matrix, into ``out``.

    Non-positive eigenvalues give ``nan``/``-inf`` entries (the caller checks J > 0).
    """
    e = _eig6(*_sym6(A))
    _store6(_recon6(math.log(e[0]), math.log(e[1]), math.log(e[2]), e), out)


@njit(cache=True, error_model="numpy")
def logm_spd(A):
    """Tensor logarithm ``ln A`` of a symmetric positive-definite 3x3 matrix (eq. (15)).

    Parameters
    ----------
    A : ndarray, shape (3, 3)
        Symmetric positive-definite matrix, e.g. the left Cauchy-Green tensor B.

    Returns
    -------
    ndarray, shape (3, 3)
        Symmetric matrix L with ``expm(L) == A``.
    """
    out = np.empty((3, 3))
    logm_spd_into(A, out)
    return out


@njit(cache=True, error_model="numpy")
def expm_sym_into(A, out, scale=1.0):
    """Tensor exponential ``exp(scale * A)`` of a symmetric 3x3 matrix, into ``out``."""
    e = _eig6(*_sym6(A))
    _store6(_recon6(math.exp(scale * e[0]), math.exp(scale * e[1]), math.exp(scale * e[2]), e), out)


@njit(cache=True, error_model="numpy")
def expm_sym(A, scale=1.0):
    """Tensor exponential ``exp(scale * A)`` of a symmetric 3x3 matrix (eq. (22)).

    Parameters
    ----------
    A : ndarray, shape (3, 3)
        Symmetric matrix, e.g. a logarithmic strain.
    scale : float
        Factor applied before the exponential (``2`` gives B = exp(2 eps)).

    Returns
    -------
    ndarray, shape (3, 3)
        Symmetric positive-definite matrix.
    """
    out = np.empty((3, 3))
    expm_sym_into(A, out, scale)
    return out


@njit(cache=True, error_model="numpy")
def det3(A):
    """Determinant of a 3x3 matrix (e.g. J = det F)."""
    return (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
            - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
            + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))


@njit(cache=True, error_model="numpy")
def inv3_into(A, out):
    """Inverse of a 3x3 matrix by cofactors, into ``out``; returns the determinant.

    A singular matrix gives ``inf``/``nan`` entries; the caller checks the determinant.
    """
    d = det3(A)
    inv = 1.0 / d
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]
    c02 = A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]
    c10 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c11 = A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]
    c12 = A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]
    c20 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    c21 = A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]
    c22 = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    out[0, 0] = c00 * inv
    out[0, 1] = c01 * inv
    out[0, 2] = c02 * inv
    out[1, 0] = c10 * inv
    out[1, 1] = c11 * inv
    out[1, 2] = c12 * inv
    out[2, 0] = c20 * inv
    out[2, 1] = c21 * inv
    out[2, 2] = c22 * inv
    return d


@njit(cache=True, error_model="numpy")
def inv3(A):
    """Inverse of a 3x3 matrix (cofactors); see :func:`inv3_into`."""
    out = np.empty((3, 3))
    inv3_into(A, out)
    return out


@njit(cache=True, error_model="numpy")
def mean_j2(A):
    """Mean stress and second deviatoric invariant of a (symmetric) 3x3 stress.

    Returns
    -------
    p : float
        ``tr(A) / 3`` with the sign of ``A`` (tension positive for tau/sigma).
    J2 : float
        ``s:s / 2`` with ``s = A - p I``.
    """
    p = (A[0, 0] + A[1, 1] + A[2, 2]) / 3.0
    s00 = A[0, 0] - p
    s11 = A[1, 1] - p
    s22 = A[2, 2] - p
    s01 = 0.5 * (A[0, 1] + A[1, 0])
    s02 = 0.5 * (A[0, 2] + A[2, 0])
    s12 = 0.5 * (A[1, 2] + A[2, 1])
    j2 = 0.5 * (s00 * s00 + s11 * s11 + s22 * s22) + s01 * s01 + s02 * s02 + s12 * s12
    return p, j2
