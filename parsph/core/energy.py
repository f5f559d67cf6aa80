r"""The work the inputs of a step do on the particles: the body force (gravity and the
earthquake) and the Dirichlet constraints (docs/energy.md).

Both phases march by symplectic Euler (eqs. (7)-(8)): :math:`\mathbf v^{\beta+1} =
\mathbf v^\beta + h\,(\mathbf b + \mathbf a)`, :math:`\mathbf x^{\beta+1} = \mathbf
x^\beta + h\,\mathbf v^{\beta+1}`. The kinetic energy's change of a particle is then exactly
:math:`m\,\Delta\mathbf v\cdot\bar{\mathbf v}` with :math:`\bar{\mathbf v} = (\mathbf
v^\beta + \mathbf v^{\beta+1})/2`, so each impulse :math:`\mathbf I` of the step (the body
force's :math:`m h \mathbf b`, a constraint's, the stress's, the pressure's) does the work
:math:`\mathbf I\cdot\bar{\mathbf v}`, and these add up to the kinetic energy's change to
round-off. The body force's is

.. math:: W_b = m h\,\mathbf b\cdot\bar{\mathbf v}
        = m\,\mathbf b\cdot(\Delta\mathbf x - \tfrac12 h\,\Delta\mathbf v),

the potential energy's drop :math:`m\,\mathbf b\cdot\Delta\mathbf x` less half an impulse:
with :math:`m\,\mathbf b\cdot\Delta\mathbf x` alone a free fall would lose
:math:`\tfrac12 m |\mathbf g|^2 h^2` of energy in every step. Written with velocities it
needs no positions, so a particle wrapped across a periodic boundary does no spurious work.
"""
from __future__ import annotations

from numba import njit


@njit(cache=True, error_model="numpy")
def step_work(m, v0, v1, sel, n, h, b, impulse):
    r"""``(body, constraint)`` work (J; J/m in 2D) over a (sub-)step of length ``h`` (s)
    on the rows ``i < n`` with ``sel[i]``: :math:`\sum m_i h\,\mathbf b\cdot\bar{\mathbf
    v}_i` and :math:`\sum \mathbf I_i\cdot\bar{\mathbf v}_i`, :math:`\bar{\mathbf v}_i =
    (\mathbf v^0_i + \mathbf v^1_i)/2` (module docstring).

    Parameters
    ----------
    m : ndarray (N,)
        Masses (kg; kg/m in 2D).
    v0, v1 : ndarray (>= n, dim)
        Velocities at the start and at the end of the step (m/s).
    sel : ndarray (>= n,)
        Rows taking part (nonzero).
    b : ndarray (dim,)
        Body acceleration of the step (m/s²).
    impulse : ndarray (n, dim) or (0, dim)
        The constraints' impulse on each row in the step (N s; none: no rows).
    """
    dim = b.shape[0]
    held = impulse.shape[0] > 0
    body = 0.0
    constraint = 0.0
    for i in range(n):
        if not sel[i]:
            continue
        s = 0.0
        c = 0.0
        for a in range(dim):
            mean = 0.5 * (v0[i, a] + v1[i, a])
            s += b[a] * mean
            if held:
                c += impulse[i, a] * mean
        body += m[i] * h * s
        constraint += c
    return body, constraint
