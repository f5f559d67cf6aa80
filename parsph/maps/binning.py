"""Particles into raster cells: footprint volumes in fixed point, the highest top, the top speed.

Each particle stands for the volume ``d³`` (``m = ρ0 d³`` at every lattice point,
the paper's counting, section 6.3) spread over its footprint, the ``d`` x ``d`` square
centred under it. A cell receives the share of the footprint that overlaps it. On a
lattice of spacing ``d`` the footprints tile the plane, so a layer ``n`` particles deep
gives every cell it covers the thickness ``n d`` exactly, whatever the cell size and
however the cells fall against the lattice (binning by centre would give cells of size
``c`` a count that jumps between ``floor(c / d)`` and ``ceil(c / d)`` columns per axis).

The shares are integers: each axis's overlap in units of ``1 / Q`` of the footprint's
width (``Q = 2^16``; the boundaries rounded, the last share taking the rest so that the
shares of a particle sum to exactly ``Q``), a cell's share the product. Sums of integers
do not depend on their order, so a raster is the same bit for bit on any rank count, and
a particle's volume is counted exactly once over the cells it overlaps.
"""
from __future__ import annotations

import numpy as np
from numba import njit

#: Fixed-point units per footprint width along one axis.
Q = 1 << 16
#: Units of a whole footprint (``Q²``): a cell's sum over this is a count of particles.
QQ = Q * Q


@njit(cache=True)
def _axis_shares(a, half, start, cell, out):
    """Shares (units of 1/Q) of the footprint ``[a − half, a + half]`` in the cells
    ``[start + k cell, start + (k + 1) cell)``; returns ``(k0, m)``: the first cell and
    how many of ``out`` were filled."""
    left = a - half
    width = 2.0 * half
    k0 = int(np.floor((left - start) / cell))
    k1 = int(np.floor((a + half - start) / cell))
    prev = 0
    m = 0
    for k in range(k0, k1 + 1):
        if k == k1:
            cum = Q
        else:
            u = (start + (k + 1) * cell - left) / width
            cum = int(np.floor(u * Q + 0.5))
            cum = min(max(cum, prev), Q)
        out[m] = cum - prev
        prev = cum
        m += 1
    return k0, m


@njit(cache=True)
def bin_frame(x, speed, kind, half, west, south, cell, nx, j0, nrows, v_min, fluid_only,
              w_all, w_flow, vmax, top, top_wall):
    """Add particles to the cells of rows ``j0 … j0 + nrows − 1``.

    Parameters
    ----------
    x : (N, 3) float64
        Positions (m); z is up.
    speed : (N,) float64
        |v| (m/s).
    kind : (N,) uint8
        0 wall, 1 solid, 2 fluid (solids and fluids are the material).
    half : float
        Half the footprint's width (d / 2).
    west, south, cell : float
        The grid's south-west corner and cell size (m).
    nx, j0, nrows : int
        Columns; first row and number of rows of this block.
    v_min : float
        Speed above which material is flowing (m/s).
    fluid_only : bool
        Only fluid (fluidised debris) can be flowing.
    w_all, w_flow : (nrows, nx) int64
        Incremented by the shares (units of 1/QQ particle) of the material and of the
        flowing material.
    vmax : (nrows, nx) float64
        Raised to the speed of each material particle that overlaps the cell.
    top, top_wall : (nrows, nx) float64
        Raised to ``z + half`` of every material (wall) particle that overlaps the cell.
    """
    width = int(2.0 * half / cell) + 3
    sx = np.empty(width, dtype=np.int64)
    sy = np.empty(width, dtype=np.int64)
    for p in range(x.shape[0]):
        i0, mi = _axis_shares(x[p, 0], half, west, cell, sx)
        jj0, mj = _axis_shares(x[p, 1], half, south, cell, sy)
        flowing = kind[p] != 0 and speed[p] > v_min and (kind[p] == 2 or not fluid_only)
        ztop = x[p, 2] + half
        for b in range(mj):
            r = jj0 + b - j0
            if r < 0 or r >= nrows or sy[b] == 0:
                continue
            for a in range(mi):
                c = i0 + a
                if c < 0 or c >= nx or sx[a] == 0:
                    continue
                w = sx[a] * sy[b]
                if kind[p] == 0:
                    if ztop > top_wall[r, c]:
                        top_wall[r, c] = ztop
                else:
                    if ztop > top[r, c]:
                        top[r, c] = ztop
                    w_all[r, c] += w
                    if speed[p] > vmax[r, c]:
                        vmax[r, c] = speed[p]
                    if flowing:
                        w_flow[r, c] += w


def row_span(y: np.ndarray, half: float, south: float, cell: float, ny: int):
    """``(jlo, jhi)``: the rows a footprint may overlap (with 1e-9 of a cell to spare
    against the round-off of :func:`bin_frame`), clipped to the grid; ``jlo > jhi`` if
    none."""
    jlo = np.floor((y - half - south) / cell - 1e-9).astype(np.int64)
    jhi = np.floor((y + half - south) / cell + 1e-9).astype(np.int64)
    return np.maximum(jlo, 0), np.minimum(jhi, ny - 1)
