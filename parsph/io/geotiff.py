"""GeoTIFF rasters (float32, one band) written block by block from several ranks.

A raster of ``ny`` x ``nx`` cells is laid out by rank 0 with tifffile (one contiguous,
uncompressed strip: the header and the georeferencing tags, then ``ny nx`` little-endian
float32 values, north row first); then each rank writes the rows it owns straight into
the file at their byte offset (``os.pwrite``: byte ranges that never overlap, which
parallel and network file systems keep apart, unlike pages of a memory map). No rank
holds more than its own rows.

Georeferencing (GeoTIFF 1.1 tags, as GDAL reads them):

- a DEM's grid unchanged: its ModelPixelScale, ModelTiepoint or ModelTransformation,
  GeoKeyDirectory, GeoDoubleParams and GeoAsciiParams copied as read, so the CRS and
  the transform are the DEM's exactly;
- another grid in a DEM's CRS: its GeoKeys copied, a new ModelPixelScale and
  ModelTiepoint (the north-west pixel's corner, or its centre for PixelIsPoint);
- no CRS (an ESRI ASCII height map, or no height map): a user-defined (local) projected
  CRS in metres, GTModelTypeGeoKey 32767 with ProjLinearUnitsGeoKey 9001, the scene's
  own x, y.

Cells without a value are NaN, declared by the GDAL_NODATA tag ``nan``.
"""
from __future__ import annotations

import os

import numpy as np

from decomposition.comm import collective
from decomposition.reduce import barrier, broadcast

PIXEL_SCALE, TIEPOINT, TRANSFORMATION = 33550, 33922, 34264
GEOKEYS, GEO_DOUBLES, GEO_ASCII, GDAL_NODATA = 34735, 34736, 34737, 42113
#: GeoKeys written for a grid without a CRS: GTModelType user-defined, GTRasterType
#: PixelIsArea, ProjLinearUnits metre.
LOCAL_GEOKEYS = (1, 1, 0, 3, 1024, 0, 1, 32767, 1025, 0, 1, 1, 3076, 0, 1, 9001)
_RASTER_TYPE, _PIXEL_IS_POINT = 1025, 2
_TYPES = {PIXEL_SCALE: "d", TIEPOINT: "d", TRANSFORMATION: "d", GEOKEYS: "H",
          GEO_DOUBLES: "d", GEO_ASCII: "s"}


def _raster_type(geokeys) -> int:
    keys = [int(v) for v in geokeys]
    for e in range(keys[3] if len(keys) >= 4 else 0):
        kid, loc, _, val = keys[4 + 4 * e: 8 + 4 * e]
        if kid == _RASTER_TYPE and loc == 0:
            return val
    return 1


def geotags(georef: dict | None, west: float, north: float, cell: float,
            same_grid: bool) -> list[tuple]:
    """tifffile ``extratags`` that georeference a raster.

    Parameters
    ----------
    georef : dict or None
        A DEM's georeferencing tags as read (:attr:`parsph.scene.heightmap.Grid.georef`:
        TIFF tag code -> value), or None for the scene's own coordinates.
    west, north : float
        The raster's north-west corner (m): the west edge of its first column, the north
        edge of its first (northernmost) row.
    cell : float
        Square cell size (m).
    same_grid : bool
        The raster's cells are the DEM's pixels (same origin, size and count): its
        transform tags are copied as read, not recomputed.
    """
    tags = []
    if georef is None:
        geokeys = LOCAL_GEOKEYS
    else:
        geokeys = tuple(int(v) for v in georef[GEOKEYS])
    if georef is not None and same_grid:
        for code in (PIXEL_SCALE, TIEPOINT, TRANSFORMATION):
            if code in georef:
                tags.append((code, "d", len(georef[code]), tuple(georef[code]), True))
    else:
        zscale = 0.0
        if georef is not None and PIXEL_SCALE in georef and len(georef[PIXEL_SCALE]) == 3:
            zscale = float(georef[PIXEL_SCALE][2])
        half = 0.5 * cell if _raster_type(geokeys) == _PIXEL_IS_POINT else 0.0
        tags.append((PIXEL_SCALE, "d", 3, (cell, cell, zscale), True))
        tags.append((TIEPOINT, "d", 6, (0.0, 0.0, 0.0, west + half, north - half, 0.0), True))
    tags.append((GEOKEYS, "H", len(geokeys), geokeys, True))
    if georef is not None:
        for code in (GEO_DOUBLES, GEO_ASCII):
            if code in georef:
                value = georef[code]
                count = 0 if code == GEO_ASCII else len(value)
                tags.append((code, _TYPES[code], count, value, True))
    tags.append((GDAL_NODATA, "s", 0, "nan", True))
    return tags


def create(path: str, ny: int, nx: int, tags: list[tuple]) -> int:
    """Lay out an ``ny`` x ``nx`` float32 GeoTIFF (values left to :func:`write_rows`);
    return the byte offset of its first value. One process only."""
    import tifffile

    tifffile.imwrite(path, shape=(ny, nx), dtype="<f4", extratags=tags,
                     photometric="minisblack", metadata=None, byteorder="<")
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        offsets, counts = list(page.dataoffsets), list(page.databytecounts)
    contiguous = all(o + c == nxt for o, c, nxt in zip(offsets, counts, offsets[1:]))
    if not contiguous or sum(counts) != 4 * ny * nx:
        raise RuntimeError(f"{path}: tifffile laid out {sum(counts)} bytes of data in "
                           f"{len(counts)} strips, expected {4 * ny * nx} in one block")
    return int(offsets[0])


def write_rows(path: str, offset: int, nx: int, first_row: int, rows: np.ndarray) -> None:
    """Write ``rows`` (k x nx, north row first) at file rows ``first_row …`` of a raster
    laid out by :func:`create`."""
    data = np.ascontiguousarray(rows, dtype="<f4")
    if data.size == 0:
        return
    fd = os.open(path, os.O_WRONLY)
    try:
        at = offset + 4 * nx * int(first_row)
        view = memoryview(data.reshape(-1).view(np.uint8))
        while view.nbytes:
            done = os.pwrite(fd, view, at)
            at += done
            view = view[done:]
    finally:
        os.close(fd)


def write_blocks(comm, path: str, ny: int, nx: int, j0: int, block: np.ndarray,
                 tags: list[tuple]) -> None:
    """Collective: write a raster whose rows are spread over the ranks.

    Parameters
    ----------
    ny, nx : int
        The raster's rows and columns.
    j0 : int
        This rank's first row, counted from the south (row ``j`` lies at ``y0 + j cell``).
    block : ndarray, shape (k, nx)
        This rank's rows ``j0 … j0 + k − 1``, south first (k may be 0).
    tags : list
        :func:`geotags`.
    """
    offset = None
    with collective(comm):
        if comm.rank == 0:
            offset = create(path, ny, nx, tags)
    offset = broadcast(comm, offset)
    k = block.shape[0]
    with collective(comm):
        write_rows(path, offset, nx, ny - j0 - k, block[::-1])
    barrier(comm)


def read_raster(path: str, stride: int = 1) -> np.ndarray:
    """The raster's values (north row first), every ``stride``-th row and column (a
    memory map: only those values are read)."""
    import tifffile

    data = tifffile.memmap(path, mode="r")
    try:
        return np.array(data[::stride, ::stride], dtype=np.float64)
    finally:
        del data
