"""The numbers of ``summary.json``: volumes, areas, the Fahrböschung (crown to toe), the peak speed.

Everything is computed from each rank's rows and combined so that the result does not
depend on the rank count: the sums per row are gathered to rank 0 and added there in
row order (``math.fsum``); the crown and the toe are picked among every rank's
candidates by value, ties by the lowest row, then column. Horizontal distances along a
periodic axis are to the nearest periodic image.
"""
from __future__ import annotations

import math

import numpy as np

from decomposition.reduce import allgather, broadcast, gather_to_root

#: Columns of the per-row sums (each times the cell area and the cells' periodic weights).
_SUMS = ("eroded", "deposited", "inside_end", "area_eroded", "area_deposited",
         "ex", "ey", "ez", "ev", "dx", "dy", "dz", "dv")


#: Rows summed at once (bounds the temporaries to ROWS x nx x 13 values).
ROWS = 256


def _row_sums(grid, j0, erosion, deposit, inside, top0, topend, h_min):
    """(rows, len(_SUMS)) partial sums of this rank's rows (module docstring)."""
    parts = [_row_sums_block(grid, j0 + a, erosion[a:a + ROWS], deposit[a:a + ROWS],
                             inside[a:a + ROWS], top0[a:a + ROWS], topend[a:a + ROWS], h_min)
             for a in range(0, erosion.shape[0], ROWS)]
    return np.concatenate(parts, axis=0) if parts else np.zeros((0, len(_SUMS)))


def _row_sums_block(grid, j0, erosion, deposit, inside, top0, topend, h_min):
    nrows, nx = erosion.shape
    wx = grid.cell_weights("x", 0, nx)[None, :]
    wy = grid.cell_weights("y", j0, nrows)[:, None]
    w = wx * wy * grid.cell ** 2
    xc = (grid.x0 + np.arange(nx) * grid.cell)[None, :]
    yc = (grid.y0 + (j0 + np.arange(nrows)) * grid.cell)[:, None]
    src = (erosion > 0) & (erosion >= h_min)
    dep = (deposit > 0) & (deposit >= h_min)
    ev = np.where(src, erosion, 0.0) * w  # volumes of the cells that count
    dv = np.where(dep, deposit, 0.0) * w
    with np.errstate(invalid="ignore"):
        ez = np.where(src, ev * (top0 - 0.5 * erosion), 0.0)
        dz = np.where(dep, dv * (topend - 0.5 * deposit), 0.0)
    cols = [erosion * w, deposit * w, inside * w, src * w, dep * w,
            ev * xc, ev * yc, ez, ev, dv * xc, dv * yc, dz, dv]
    return np.stack([c.sum(axis=1) for c in cols], axis=1)


def _pick(candidates, larger=True):
    """The best ``(value, j, i, ...)`` of every rank's candidate (None: none there):
    the largest value, ties by the lowest (j, i)."""
    found = [c for c in candidates if c is not None]
    if not found:
        return None
    sign = -1.0 if larger else 1.0
    return min(found, key=lambda c: (sign * c[0], c[1], c[2]))


def _wrap(delta, period):
    """Differences along an axis: the nearest periodic image's on a periodic axis."""
    if period is None:
        return delta
    length = period[1] - period[0]
    return delta - length * np.round(delta / length)


def _local_best(mask, value, j0):
    """``(value, j, i)`` of the largest ``value`` where ``mask`` (first in row-major
    order on ties), or None."""
    if not mask.any():
        return None
    v = np.where(mask, value, -np.inf)
    k = int(np.argmax(v))
    r, i = divmod(k, v.shape[1])
    return float(v[r, i]), j0 + r, i


def summarise(comm, grid, j0, erosion, deposit, inside, top0, topend, h_min) -> dict:
    """Collective: the map-based numbers of ``summary.json`` (module docstring).

    Parameters
    ----------
    grid : MapGrid
    j0 : int
        This rank's first row.
    erosion, deposit, inside : (rows, nx) float64
        Erosion depth, deposit thickness and the material's thickness at the end (m).
    top0, topend : (rows, nx) float64
        Initial and final surface (highest particle top, m; NaN where none).
    h_min : float
        Thickness from which a cell counts as eroded or deposited (m).
    """
    rows = gather_to_root(comm, _row_sums(grid, j0, erosion, deposit, inside, top0, topend,
                                          h_min))
    sums = None
    if comm.rank == 0:
        table = np.concatenate(rows, axis=0)
        sums = {name: math.fsum(table[:, k]) for k, name in enumerate(_SUMS)}
    sums = broadcast(comm, sums)
    out = {"volume_eroded_m3": sums["eroded"], "volume_deposited_m3": sums["deposited"],
           "volume_in_grid_end_m3": sums["inside_end"], "area_eroded_m2": sums["area_eroded"],
           "area_deposited_m2": sums["area_deposited"]}

    src = (erosion > 0) & (erosion >= h_min)
    crown = _pick(allgather(comm, _local_best(src & np.isfinite(top0), top0, j0)))
    toe = None
    if crown is not None:
        xc = grid.x0 + crown[2] * grid.cell
        yc = grid.y0 + crown[1] * grid.cell
        nrows, nx = deposit.shape
        dx = _wrap(grid.x0 + np.arange(nx)[None, :] * grid.cell - xc, grid.period_x)
        dy = _wrap(grid.y0 + (j0 + np.arange(nrows))[:, None] * grid.cell - yc, grid.period_y)
        dep = (deposit > 0) & (deposit >= h_min) & np.isfinite(topend)
        best = _local_best(dep, np.hypot(dx, dy), j0)
        if best is not None:
            best = best + (float(topend[best[1] - j0, best[2]]),)
        toe = _pick(allgather(comm, best))
    if crown is None or toe is None:
        out.update(runout_m=None, height_drop_m=None, travel_angle_deg=None,
                   crown_xyz_m=None, toe_xyz_m=None)
    else:
        crown_xyz = [grid.x0 + crown[2] * grid.cell, grid.y0 + crown[1] * grid.cell, crown[0]]
        toe_xyz = [grid.x0 + toe[2] * grid.cell, grid.y0 + toe[1] * grid.cell, toe[3]]
        length, drop = toe[0], crown[0] - toe[3]
        out.update(runout_m=length, height_drop_m=drop,
                   travel_angle_deg=math.degrees(math.atan2(drop, length)),
                   crown_xyz_m=crown_xyz, toe_xyz_m=toe_xyz)
    if sums["ev"] > 0 and sums["dv"] > 0:
        e = [sums[k] / sums["ev"] for k in ("ex", "ey", "ez")]
        d = [sums[k] / sums["dv"] for k in ("dx", "dy", "dz")]
        length = math.hypot(float(_wrap(e[0] - d[0], grid.period_x)),
                            float(_wrap(e[1] - d[1], grid.period_y)))
        drop = e[2] - d[2]
        out.update(runout_com_m=length, height_drop_com_m=drop,
                   travel_angle_com_deg=math.degrees(math.atan2(drop, length)),
                   source_centroid_xyz_m=e, deposit_centroid_xyz_m=d)
    else:
        out.update(runout_com_m=None, height_drop_com_m=None, travel_angle_com_deg=None,
                   source_centroid_xyz_m=None, deposit_centroid_xyz_m=None)
    return out


def peak(comm, speed: float, time: float) -> tuple[float, float]:
    """Collective: the largest ``speed`` over the ranks and its ``time`` (the earliest on
    ties)."""
    best = min(allgather(comm, (float(speed), float(time))), key=lambda c: (-c[0], c[1]))
    return best
