"""The raster grid of ``parsph maps``: its cells in the scene's x, y, its CRS, its rows per rank.

Cells are square, of size ``cell``; column ``i`` is centred at ``x0 + i cell``, row ``j``
at ``y0 + j cell`` (row 0 the southernmost, as :class:`parsph.scene.heightmap.Grid`).

- **A scene with a height map** (its first ``heightmap`` body): the DEM's pixels, so that
  its nodes are the cell centres; extended by whole cells where the domain's x, y box
  reaches beyond the DEM (the debris may run off the DEM onto box walls), so the cells
  stay the DEM's pixels. ``--cell`` gives another size, aligned on the DEM's north-west
  corner (the GeoTIFF origin). The rasters carry the DEM's CRS (a GeoTIFF DEM; an ESRI ASCII grid has none).
- **Otherwise** ``--cell`` is required: cells from the domain's south-west corner over
  its x, y box, in the scene's own coordinates.

Rows are dealt to the ranks in contiguous blocks (rank ``r`` of ``P``: rows
``r ny / P … (r + 1) ny / P − 1``); no rank holds another's rows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from parsph.errors import ParsphError

#: Bytes a rank holds per cell of its rows: 7 running fields and 5 of the frame being
#: binned (8 B each), and the float32 row copy of the raster being written.
BYTES_PER_CELL = 12 * 8 + 4
#: The grid may use at most this share of a node's memory (as a scene's particles).
MEMORY_SHARE = 0.8
#: Lattice round-off allowed when counting cells (1e-9 of a cell).
_EPS = 1e-9


@dataclass(frozen=True)
class MapGrid:
    """A raster grid in the scene's x, y.

    Attributes
    ----------
    x0, y0 : float
        Centre of the south-west cell (m).
    cell : float
        Cell size (m).
    nx, ny : int
        Columns (west to east) and rows (south to north).
    georef : dict or None
        The DEM's georeferencing tags, or None (the scene's own coordinates).
    same_as_dem : bool
        The cells are the DEM's pixels, same origin and count (its transform tags are
        copied as read).
    source : str
        Where the grid comes from, for messages and ``summary.json``.
    period_x, period_y : tuple of float or None
        The domain's ``(lo, hi)`` along a periodic axis (None if not periodic).
    """

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int
    georef: dict | None = None
    same_as_dem: bool = False
    source: str = ""
    period_x: tuple[float, float] | None = None
    period_y: tuple[float, float] | None = None

    @property
    def west(self) -> float:
        return self.x0 - 0.5 * self.cell

    @property
    def south(self) -> float:
        return self.y0 - 0.5 * self.cell

    @property
    def north(self) -> float:
        return self.south + self.ny * self.cell

    @property
    def east(self) -> float:
        return self.west + self.nx * self.cell

    def rows(self, rank: int, size: int) -> tuple[int, int]:
        """``(j0, j1)``: the rows ``j0 … j1 − 1`` rank ``rank`` of ``size`` owns."""
        return rank * self.ny // size, (rank + 1) * self.ny // size

    def owner(self, j: np.ndarray, size: int) -> np.ndarray:
        """The rank that owns row ``j`` (an array of rows in ``[0, ny)``)."""
        starts = np.array([r * self.ny // size for r in range(size)], dtype=np.int64)
        return np.searchsorted(starts, np.asarray(j, dtype=np.int64), side="right") - 1

    def cell_weights(self, axis: str, first: int, count: int) -> np.ndarray:
        """Share of each cell ``first … first + count − 1`` along ``axis`` ("x" or "y")
        that lies inside the domain's period (1 on an axis that is not periodic): the
        cells past a periodic face repeat material from the other side, and a volume
        summed over the cells counts it once with these weights."""
        period = self.period_x if axis == "x" else self.period_y
        if period is None:
            return np.ones(count)
        start = self.west if axis == "x" else self.south
        lo = start + (first + np.arange(count)) * self.cell
        inside = np.clip(np.minimum(lo + self.cell, period[1]) - np.maximum(lo, period[0]),
                         0.0, self.cell)
        return inside / self.cell

    def describe(self) -> dict:
        """The grid for ``summary.json``."""
        return {"nx": self.nx, "ny": self.ny, "cell_m": self.cell, "west_m": self.west,
                "south_m": self.south, "east_m": self.east, "north_m": self.north,
                "crs": "the DEM's" if self.georef is not None else "none (scene x, y)",
                "source": self.source}


def _heightmap(scene):
    """``(body, Grid)`` of the scene's first heightmap body, or ``(None, None)``."""
    for body in scene.bodies:
        if body.shape == "heightmap":
            return body, scene.data[body.top]
    return None, None


def grid_for(scene, cell: float | None, ranks: int, ranks_on_node: int,
             node_memory: int) -> MapGrid:
    """The maps' grid of ``scene`` (module docstring), checked against the memory.

    Parameters
    ----------
    cell : float or None
        ``--cell`` (m), or None for the DEM's.
    ranks, ranks_on_node : int
        Ranks in all and on this node (each holds ``1 / ranks`` of the rows).
    node_memory : int
        This node's memory in bytes (0 if unknown: not checked).

    Raises
    ------
    ParsphError
        A cell size that is not a positive number, no height map and no ``--cell``, or a
        grid whose rows would not fit in the node's memory.
    """
    if cell is not None and not (math.isfinite(cell) and cell > 0):
        raise ParsphError(f"--cell {cell!r}: the cell size must be a positive number of "
                          "metres, e.g. --cell 2.0")
    dom = scene.domain
    lo, hi = dom.lo, dom.hi
    periodic = tuple(dom.periodic) + (False,) * (3 - len(dom.periodic))
    body, dem = _heightmap(scene)
    if dem is None and cell is None:
        raise ParsphError(f"{scene.source}: the scene has no heightmap body, so there is no "
                          "DEM grid to use; give the cell size, e.g. --cell "
                          f"{2 * dom.particle_size:g} (m)")
    if dem is not None:
        ny_dem, nx_dem = dem.z.shape
        dem_w, dem_s = dem.x0 - 0.5 * dem.cell, dem.y0 - 0.5 * dem.cell
        dem_e, dem_n = dem_w + nx_dem * dem.cell, dem_s + ny_dem * dem.cell
        c = dem.cell if cell is None else float(cell)
        # whole cells of size c from the DEM's north-west corner (a GeoTIFF's origin),
        # over the DEM and the domain
        west = dem_w - math.ceil(max(0.0, dem_w - lo[0]) / c - _EPS) * c
        north = dem_n + math.ceil(max(0.0, hi[1] - dem_n) / c - _EPS) * c
        east, south = max(dem_e, hi[0]), min(dem_s, lo[1])
        what = "DEM" if dem.georef is not None else "ESRI ASCII grid (no CRS)"
        source = f"{what} '{body.top}'" + ("" if cell is None else f", --cell {c:g}")
    else:
        c = float(cell)
        west, south, east, north = lo[0], lo[1], hi[0], hi[1]
        source = f"the domain's x, y box, --cell {c:g}"
    fx, fy = (east - west) / c, (north - south) / c
    need = fx * fy / ranks * BYTES_PER_CELL * ranks_on_node
    if fx * fy > 2.0 ** 50 or (node_memory and need > MEMORY_SHARE * node_memory):
        node = f"{node_memory / 2**30:.3g} GiB" if node_memory else "memory"
        raise ParsphError(
            f"a grid of {fx:.4g} x {fy:.4g} cells of {c:g} m would need {need / 2**30:.3g} GiB "
            f"on this node ({ranks_on_node} of {ranks} rank(s), {BYTES_PER_CELL} B per cell), "
            f"more than {MEMORY_SHARE:.0%} of its {node}; use a larger "
            "--cell or more nodes")
    nx = max(1, math.ceil(fx - _EPS))
    ny = max(1, math.ceil(fy - _EPS))
    if dem is not None:
        south = north - ny * c  # rows hang from the north edge
    same = dem is not None and cell is None and (nx, ny) == (dem.z.shape[1], dem.z.shape[0]) \
        and west == dem_w and north == dem_n
    if same:  # the DEM's own numbers, not recomputed ones
        x0, y0 = dem.x0, dem.y0
    else:
        x0, y0 = west + 0.5 * c, south + 0.5 * c
    return MapGrid(x0=x0, y0=y0, cell=c, nx=nx, ny=ny,
                   georef=None if dem is None else dem.georef, same_as_dem=same,
                   source=source,
                   period_x=(lo[0], hi[0]) if periodic[0] else None,
                   period_y=(lo[1], hi[1]) if periodic[1] else None)
