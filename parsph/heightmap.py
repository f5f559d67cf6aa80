"""Height maps: ESRI ASCII grids of a surface z(x, y), read and checked before use.

Format (the common ``.asc`` raster)::

    ncols 4
    nrows 3
    xllcorner 0.0
    yllcorner 0.0
    cellsize 10.0
    NODATA_value -9999
    z z z z      <- northernmost row (largest y) first
    ...

Values are node heights (m) at ``x = xllcorner + i cellsize``, ``y = yllcorner + j
cellsize``; :func:`surface` interpolates bilinearly and holds the edge values outside.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from parsph.errors import SceneError

_HEADER = ("ncols", "nrows", "xllcorner", "yllcorner", "cellsize")


@dataclass(frozen=True)
class Grid:
    x0: float
    y0: float
    cell: float
    z: np.ndarray  # (ny, nx), row j at y = y0 + j * cell

    @property
    def extent(self):
        ny, nx = self.z.shape
        return (self.x0, self.x0 + (nx - 1) * self.cell), (self.y0, self.y0 + (ny - 1) * self.cell)


def read_ascii_grid(path: str, key: str = "", source: str = "") -> Grid:
    """Read and check an ESRI ASCII grid; errors name the file, the key and the line."""
    where = f"{source}: key '{key}': " if key else ""
    try:
        with open(path, encoding="utf-8") as fh:
            lines = [ln.split() for ln in fh if ln.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or "not a text file"
        raise SceneError(f"{where}cannot read height map '{path}': {reason}") from None
    head = {}
    body_start = 0
    for n, parts in enumerate(lines):
        if parts[0].lower() in _HEADER + ("nodata_value", "xllcenter", "yllcenter"):
            if len(parts) != 2:
                raise SceneError(f"{where}height map '{path}': header line {n + 1} should be "
                                 f"'name value'")
            head[parts[0].lower()] = parts[1]
            body_start = n + 1
        else:
            break
    for name in ("ncols", "nrows", "cellsize"):
        if name not in head:
            raise SceneError(f"{where}height map '{path}': header '{name}' missing (an ESRI ASCII "
                             f"grid starts with ncols, nrows, xllcorner, yllcorner, cellsize)")
    try:
        nx, ny = int(head["ncols"]), int(head["nrows"])
        cell = float(head["cellsize"])
        x0 = float(head.get("xllcorner", head.get("xllcenter", 0.0)))
        y0 = float(head.get("yllcorner", head.get("yllcenter", 0.0)))
        nodata = float(head["nodata_value"]) if "nodata_value" in head else None
    except ValueError:
        raise SceneError(f"{where}height map '{path}': a header value is not a number") from None
    if nx < 2 or ny < 2 or not np.isfinite(cell) or cell <= 0:
        raise SceneError(f"{where}height map '{path}': needs ncols, nrows >= 2 and cellsize > 0")
    rows = lines[body_start:]
    if len(rows) != ny:
        raise SceneError(f"{where}height map '{path}': header says {ny} rows, found {len(rows)}")
    try:
        z = np.array([[float(v) for v in r] for r in rows], dtype=float)
    except ValueError:
        raise SceneError(f"{where}height map '{path}': a height is not a number") from None
    if z.ndim != 2 or z.shape[1] != nx:
        raise SceneError(f"{where}height map '{path}': every row needs {nx} values")
    if nodata is not None and np.any(z == nodata):
        raise SceneError(f"{where}height map '{path}': has NODATA cells; fill them before use")
    if not np.all(np.isfinite(z)):
        raise SceneError(f"{where}height map '{path}': has NaN or infinite heights")
    return Grid(x0=x0, y0=y0, cell=cell, z=z[::-1].copy())


def surface(grid: Grid, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of the grid at points (x, y); edge values held outside."""
    ny, nx = grid.z.shape
    fx = np.clip((np.asarray(x) - grid.x0) / grid.cell, 0.0, nx - 1.0)
    fy = np.clip((np.asarray(y) - grid.y0) / grid.cell, 0.0, ny - 1.0)
    i = np.minimum(fx.astype(np.int64), nx - 2)
    j = np.minimum(fy.astype(np.int64), ny - 2)
    tx, ty = fx - i, fy - j
    z = grid.z
    return ((1 - tx) * (1 - ty) * z[j, i] + tx * (1 - ty) * z[j, i + 1]
            + (1 - tx) * ty * z[j + 1, i] + tx * ty * z[j + 1, i + 1])
