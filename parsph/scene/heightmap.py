"""Height maps: ESRI ASCII grids or GeoTIFF DEMs of a surface z(x, y), read and checked.

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

A GeoTIFF (:func:`read_geotiff`, with tifffile) gives one node per pixel, at the pixel's
centre as its georeferencing says (ModelPixelScale and ModelTiepoint, or an unrotated
ModelTransformation; GTRasterTypeGeoKey area or point). Its CRS (GeoKeyDirectory) must
be projected in metres; a geographic (lat/lon) CRS, another unit, nodata cells or no
georeferencing at all are refused (docs/geometry.md).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from parsph.errors import SceneError

_HEADER = ("ncols", "nrows", "xllcorner", "yllcorner", "cellsize")


@dataclass(frozen=True)
class Grid:
    """Node heights ``z`` (m) at ``x0 + i cell``, ``y0 + j cell``.

    ``georef`` (GeoTIFF only, else None): the file's georeferencing tags as read, TIFF
    tag code -> value (GeoKeyDirectory, GeoDoubleParams, GeoAsciiParams, ModelPixelScale,
    ModelTiepoint or ModelTransformation), so that rasters written on this grid
    (``parsph maps``) carry the same CRS and transform.
    """

    x0: float
    y0: float
    cell: float
    z: np.ndarray  # (ny, nx), row j at y = y0 + j * cell
    georef: dict | None = field(default=None, compare=False, repr=False)

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


_TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
#: TIFF tags of GeoTIFF and GDAL.
_PIXEL_SCALE, _TIEPOINT, _TRANSFORMATION, _GEOKEYS, _GDAL_NODATA = 33550, 33922, 34264, 34735, 42113
#: GeoTIFF tags of the CRS's double and text parameters (kept with the GeoKeyDirectory).
_GEO_DOUBLES, _GEO_ASCII = 34736, 34737
#: GeoKeys read (GeoTIFF 1.1): model type, raster type, geographic CRS, projected CRS,
#: projected linear unit, vertical unit; EPSG unit 9001 is the metre.
_MODEL_TYPE, _RASTER_TYPE, _GEOGRAPHIC, _PROJECTED, _LINEAR_UNITS, _VERTICAL_UNITS = \
    1024, 1025, 2048, 3072, 3076, 4099
_METRE = 9001
_MODEL_NAMES = {1: "projected", 2: "geographic (lat/lon, degrees)", 3: "geocentric"}


def read_grid(path: str, key: str = "", source: str = "") -> Grid:
    """A height map by its content: GeoTIFF (``.tif``/``.tiff`` or TIFF bytes), else ESRI ASCII."""
    if os.path.splitext(path)[1].lower() in (".tif", ".tiff"):
        return read_geotiff(path, key, source)
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError:
        magic = b""
    if magic in _TIFF_MAGIC:
        return read_geotiff(path, key, source)
    return read_ascii_grid(path, key, source)


def _geokeys(values) -> dict:
    """GeoKeyDirectory: {key id: value} of the keys stored in the directory itself."""
    values = [int(v) for v in values]
    n = values[3] if len(values) >= 4 else 0
    out = {}
    for e in range(n):
        kid, loc, _, val = values[4 + 4 * e: 8 + 4 * e]
        out[kid] = val if loc == 0 else None  # doubles/strings elsewhere: not needed here
    return out


def read_geotiff(path: str, key: str = "", source: str = "") -> Grid:
    """Read and check a one-band GeoTIFF DEM in a projected CRS in metres.

    Raises
    ------
    SceneError
        If the file is missing or unreadable, has no georeferencing or no CRS, a
        geographic or non-metre CRS, rotated or non-square pixels, several bands, or
        nodata / NaN cells; the message names the file and ``key``.
    """
    import tifffile

    where = f"{source}: key '{key}': " if key else ""
    what = f"GeoTIFF height map '{path}'"
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            tags = {code: page.tags[code].value for code in
                    (_PIXEL_SCALE, _TIEPOINT, _TRANSFORMATION, _GEOKEYS, _GDAL_NODATA,
                     _GEO_DOUBLES, _GEO_ASCII)
                    if code in page.tags}
            z = page.asarray()
    except FileNotFoundError:
        raise SceneError(f"{where}cannot read height map '{path}': No such file or directory "
                         f"(paths are relative to the scene file)") from None
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
        raise SceneError(f"{where}cannot read {what}: {type(exc).__name__}: {exc}") from None
    if _GEOKEYS not in tags or not ((_PIXEL_SCALE in tags and _TIEPOINT in tags)
                                    or _TRANSFORMATION in tags):
        raise SceneError(f"{where}{what} has no georeferencing (GeoKeyDirectory, "
                         f"ModelPixelScale and ModelTiepoint tags): parsph needs its CRS and "
                         f"cell size; write it as a GeoTIFF in a projected CRS in metres "
                         f"(e.g. gdal_translate -a_srs EPSG:32633 -a_ullr ...)")
    geo = _geokeys(tags[_GEOKEYS])
    model = geo.get(_MODEL_TYPE)
    if model is None:
        model = 1 if geo.get(_PROJECTED) else 2 if geo.get(_GEOGRAPHIC) else None
    if model != 1:
        kind = _MODEL_NAMES.get(model, "not given" if model is None else f"type {model}")
        raise SceneError(f"{where}{what}: its CRS is {kind}; parsph needs x, y and z in "
                         f"metres: reproject it to a projected CRS in metres (e.g. gdalwarp "
                         f"-t_srs EPSG:326NN for UTM zone NN north)")
    for gk, name in ((_LINEAR_UNITS, "linear unit (ProjLinearUnitsGeoKey)"),
                     (_VERTICAL_UNITS, "vertical unit (VerticalUnitsGeoKey)")):
        if geo.get(gk) not in (None, _METRE):
            raise SceneError(f"{where}{what}: its {name} is EPSG {geo[gk]}, not the metre "
                             f"(9001); reproject or rescale it to metres (gdalwarp -t_srs)")
    if geo.get(_PROJECTED) in (None, 32767) and geo.get(_LINEAR_UNITS) != _METRE:
        raise SceneError(f"{where}{what}: a user-defined projected CRS without "
                         f"ProjLinearUnitsGeoKey = 9001 (metre); parsph cannot tell its unit")
    if z.ndim != 2:
        raise SceneError(f"{where}{what} has shape {z.shape}; a DEM has one band (rows, "
                         f"columns): extract it (gdal_translate -b 1)")
    ny, nx = z.shape
    offset = 0.0 if geo.get(_RASTER_TYPE) == 2 else 0.5  # PixelIsPoint / PixelIsArea
    if _TRANSFORMATION in tags:
        t = [float(v) for v in tags[_TRANSFORMATION]]
        if t[1] != 0.0 or t[4] != 0.0 or t[0] <= 0.0 or t[5] >= 0.0:
            raise SceneError(f"{where}{what}: its ModelTransformation is rotated or flipped; "
                             f"warp it to a north-up grid (gdalwarp)")
        sx, sy, x_tie, y_tie, i_tie, j_tie = t[0], -t[5], t[3], t[7], 0.0, 0.0
    else:
        scale, tie = [float(v) for v in tags[_PIXEL_SCALE]], [float(v) for v in tags[_TIEPOINT]]
        if len(tie) != 6:
            raise SceneError(f"{where}{what} has {len(tie) // 6} tie points; parsph reads a "
                             f"grid with one (warp it: gdalwarp)")
        sx, sy, (i_tie, j_tie, _, x_tie, y_tie, _) = scale[0], scale[1], tie
    if not (sx > 0 and sy > 0) or abs(sx - sy) > 1e-9 * sx:
        raise SceneError(f"{where}{what}: pixels of {sx} x {sy} m; parsph needs square "
                         f"cells: resample it (gdalwarp -tr CELL CELL)")
    if nx < 2 or ny < 2:
        raise SceneError(f"{where}{what}: needs at least 2 x 2 cells, has {nx} x {ny}")
    z = np.asarray(z, dtype=np.float64)
    nodata = tags.get(_GDAL_NODATA)
    if nodata is not None:
        try:
            value = float(str(nodata).strip().strip("\x00"))
        except ValueError:
            raise SceneError(f"{where}{what}: GDAL_NODATA tag {nodata!r} is not a number") from None
        bad = np.isnan(z) if np.isnan(value) else z == value
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise SceneError(f"{where}{what} has {int(bad.sum())} nodata cells (GDAL_NODATA "
                             f"{value:g}; the first at row {r}, column {c}); fill them before "
                             f"use (gdal_fillnodata.py)")
    if not np.all(np.isfinite(z)):
        raise SceneError(f"{where}{what} has NaN or infinite heights")
    x0 = x_tie + (offset - i_tie) * sx
    y0 = y_tie - (ny - 1 + offset - j_tie) * sy  # the southernmost row's centre
    georef = {code: (value if isinstance(value, str) else tuple(np.ravel(value).tolist()))
              for code, value in tags.items()
              if code in (_PIXEL_SCALE, _TIEPOINT, _TRANSFORMATION, _GEOKEYS, _GEO_DOUBLES,
                          _GEO_ASCII)}
    return Grid(x0=x0, y0=y0, cell=sx, z=z[::-1].copy(), georef=georef)
