"""Wall particles in the fluid step: their slip condition, and which of them are rows.

Every particle carries ``body``, the index of the body or wall it was generated from in
``scene.bodies + scene.walls`` (walls after the bodies); a wall particle's slip is the
``slip`` key of its wall. :func:`system_rows` picks the rows of the step's systems and
:func:`row_order` numbers them.
"""
from __future__ import annotations

import numpy as np
from numba import njit

NO_SLIP, FREE_SLIP = 0, 1


def wall_slip(scene, body, is_wall) -> np.ndarray:
    """Slip flag (uint8, 1 = free-slip) of every row; 0 for rows that are not walls.

    Parameters
    ----------
    scene : parsph.scene.loader.Scene
    body : numpy.ndarray of int, shape (N,)
        Body/wall index of every row (the ``body`` field).
    is_wall : numpy.ndarray of bool, shape (N,)

    Returns
    -------
    numpy.ndarray of uint8, shape (N,)
    """
    free = np.array([w.slip == "free_slip" for w in scene.walls] + [False], dtype=np.uint8)
    slip = np.zeros(len(body), dtype=np.uint8)
    wall = np.asarray(body)[is_wall] - len(scene.bodies)
    slip[is_wall] = free[np.where((wall >= 0) & (wall < len(scene.walls)), wall, -1)]
    return slip


def system_rows(ctx, fluid, is_wall) -> np.ndarray:
    """The owned rows of the fluid step's systems (bool, shape (n_owned,)): the fluid rows,
    the boundary rows with a fluid neighbour and the walls of the band.

    A wall row without a fluid neighbour is an identity row (p = 0, v = v_wall). Every
    wall had been such a row, so that the rows stayed the same particles while the fluid
    ran along a wall and the PPE's AMG set-up could be lagged; in the 3D dam break of
    ``jobs/bench_splishsplash.py`` that made 48,456 of its 72,790 rows. The band is the
    walls within two cells (at least two radii) of a fluid row at a sync step
    (``build_csr``'s ``near``, kept in the ``ppe_band`` field, which moves with the
    particles) until the next one: the fluid wets a wall outside it only by crossing a
    radius within those steps, and then the rows change and the set-up is made afresh,
    as after any change of the rows. The walls left out get p = 0, as their identity
    rows gave."""
    p, n = ctx.particles, ctx.n_owned
    band = p["ppe_band"]
    if ctx.at_sync_step:
        near = ctx.near_fluid
        band[:n] = is_wall & (near[:n] == 1) if near is not None and len(near) >= n \
            else is_wall
    return _system_rows(fluid, band, is_wall, ctx.indptr, ctx.indices, p["p"], p["p_ppe"])


@njit(cache=True, error_model="numpy")
def _system_rows(fluid, band, is_wall, indptr, indices, p, p_ppe):
    """:func:`system_rows` in one pass: the owned rows that are fluid, in the band or
    have a fluid neighbour; the walls left out get p = 0 (numpy's six passes had cost
    15 us of a 2D coupled step's fixed cost)."""
    n = indptr.shape[0] - 1
    act = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        a = fluid[i] != 0 or band[i] != 0
        if not a:
            for q in range(indptr[i], indptr[i + 1]):
                if fluid[indices[q]]:
                    a = True
                    break
        act[i] = a
        if is_wall[i] and not a:
            p[i] = 0.0
            p_ppe[i] = 0.0
    return act


def row_order(act, wall) -> np.ndarray:
    """The owned particles of the systems (``act``) in the order of their rows: fluid
    and solid rows first, then the wall rows, each in particle order.

    BoomerAMG's Gauss-Seidel smoother and its coarsening depend on the row order. A
    wall row only extrapolates the fluid's pressure (Adami et al. 2012); swept after
    the fluid rows it takes their new values. Numbered in particle order instead, the
    walls a rank received with its particles fall between fluid rows: on 2 ranks the
    2.0e5-particle dam break took 12 PPE iterations where 1 rank took 10; with the
    walls last both take 10 (docs/solvers.md)."""
    return _row_order(act, wall)


@njit(cache=True, error_model="numpy")
def _row_order(act, wall):
    """:func:`row_order` in two passes over the rows."""
    n = act.shape[0]
    count = 0
    for i in range(n):
        count += act[i]
    order = np.empty(count, dtype=np.int64)
    k = 0
    for last in (False, True):
        for i in range(n):
            if act[i] and wall[i] == last:
                order[k] = i
                k += 1
    return order
