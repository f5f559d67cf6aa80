"""Height maps from GeoTIFF DEMs (written by the tests with tifffile)."""
import pathlib

import numpy as np
import pytest
import tifffile

from parsph.errors import SceneError
from parsph.scene.geometry import generate
from parsph.scene.heightmap import read_grid
from parsph.scene.materials import PHASE_WALL
from parsph.scene.loader import load_scene
from tests.scenes import MOVING_3D, alone_on_rank_zero, gather_particles, write

#: GeoKeyDirectory entries (key, location 0, count 1, value) of GeoTIFF 1.1.
MODEL, RASTER, GEOGRAPHIC, PROJECTED, LINEAR = 1024, 1025, 2048, 3072, 3076

#: Node heights (m), northernmost row first, on multiples of 1/8 (exact in float32 and text).
Z = np.array([[0.625, 0.625, 0.625], [0.25, 0.375, 0.5]])
X0, Y0, CELL = 0.0, 0.0, 0.5  # node (column 0, southern row) and spacing (m)


def _geokeys(keys):
    entries = [(k, 0, 1, v) for k, v in sorted(keys.items())]
    return tuple([1, 1, 0, len(entries)] + [n for e in entries for n in e])


def write_geotiff(path, z=Z, keys=None, nodata=None, point=False, georeferenced=True,
                  dtype=np.float32, compression=None, photometric=None):
    """A one-band DEM: PixelIsArea (the tie point is the north-west pixel's corner) or
    PixelIsPoint (its centre), EPSG 32633 (UTM 33N, metres) unless ``keys`` says."""
    keys = {MODEL: 1, RASTER: 2 if point else 1, PROJECTED: 32633} if keys is None else keys
    half = 0.0 if point else 0.5 * CELL
    top = Y0 + (z.shape[0] - 1) * CELL
    tags = []
    if georeferenced:
        tags = [(33550, "d", 3, (CELL, CELL, 0.0), True),
                (33922, "d", 6, (0.0, 0.0, 0.0, X0 - half, top + half, 0.0), True),
                (34735, "H", len(_geokeys(keys)), _geokeys(keys), True)]
    if nodata is not None:
        tags.append((42113, "s", 0, str(nodata), True))
    tifffile.imwrite(path, z.astype(dtype), extratags=tags, compression=compression,
                     photometric=photometric)


def _ascii(path, z=Z):
    rows = "\n".join(" ".join(repr(float(v)) for v in row) for row in z)
    path.write_text(f"ncols {z.shape[1]}\nnrows {z.shape[0]}\nxllcorner {X0}\nyllcorner {Y0}\n"
                    f"cellsize {CELL}\n{rows}\n")


def _scene_text(top):
    return MOVING_3D.replace('shape = "extruded_polygon"',
                             f'shape = "heightmap"\ntop = "{top}"\nbottom = 0.0')


def test_geotiff_gives_the_particles_of_the_ascii_grid(comm, mpi_tmp_path):
    """The same DEM as an ESRI ASCII grid and as GeoTIFFs (pixel-is-area, pixel-is-point,
    LZW-compressed): identical particles."""
    tmp = pathlib.Path(mpi_tmp_path)
    if comm.rank == 0:
        _ascii(tmp / "z.asc")
        write_geotiff(tmp / "area.tif")
        write_geotiff(tmp / "point.tif", point=True)
        write_geotiff(tmp / "lzw.tif", compression="lzw")
        for top in ("z.asc", "area.tif", "point.tif", "lzw.tif"):
            write(str(tmp), _scene_text(top), f"{top}.toml")
    comm.Barrier()
    runs = {}
    for top in ("z.asc", "area.tif", "point.tif", "lzw.tif"):
        scn = load_scene(str(tmp / f"{top}.toml"))
        ids, x, phase = gather_particles(comm, generate(comm, scn))
        runs[top] = x[phase != PHASE_WALL]
    assert len(runs["z.asc"]) > 20
    for top in ("area.tif", "point.tif", "lzw.tif"):
        assert np.array_equal(runs["z.asc"], runs[top]), top
    grid = read_grid(str(tmp / "area.tif"))
    assert (grid.x0, grid.y0, grid.cell) == (X0, Y0, CELL)
    assert np.array_equal(grid.z, Z[::-1])


@pytest.mark.mpi
def test_geotiff_particles_independent_of_rank_count(comm, mpi_tmp_path):
    tmp = pathlib.Path(mpi_tmp_path)
    if comm.rank == 0:
        write_geotiff(tmp / "dem.tif")
    comm.Barrier()
    scn = load_scene(write(tmp, _scene_text("dem.tif"))) if comm.rank == 0 else None
    scn = comm.bcast(scn)
    serial = alone_on_rank_zero(comm, lambda one: gather_particles(one, generate(one, scn)))
    parallel = gather_particles(comm, generate(comm, scn))
    if comm.rank == 0:
        assert np.array_equal(serial[0], parallel[0])
        assert np.array_equal(serial[1], parallel[1])


BAD = [
    (dict(nodata=-9999, z=np.where(np.arange(6).reshape(2, 3) == 4, -9999.0, Z)),
     ["nodata cells", "GDAL_NODATA -9999", "row 1, column 1", "gdal_fillnodata"]),
    (dict(keys={MODEL: 2, GEOGRAPHIC: 4326}), ["geographic (lat/lon, degrees)", "gdalwarp"]),
    (dict(keys={GEOGRAPHIC: 4326}), ["geographic"]),
    (dict(keys={MODEL: 1, PROJECTED: 2227, LINEAR: 9003}), ["ProjLinearUnitsGeoKey", "9003",
                                                           "not the metre"]),
    (dict(keys={MODEL: 1, PROJECTED: 32767}), ["user-defined", "cannot tell its unit"]),
    (dict(georeferenced=False), ["no georeferencing", "ModelTiepoint"]),
    (dict(z=np.zeros((2, 3, 3)), photometric="rgb"), ["one band"]),
]


@pytest.mark.parametrize("kwargs,words", BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_geotiffs_are_refused_naming_the_key(tmp_path, kwargs, words):
    write_geotiff(tmp_path / "dem.tif", **kwargs)
    with pytest.raises(SceneError) as info:
        load_scene(write(tmp_path, _scene_text("dem.tif")))
    message = str(info.value)
    for word in ["bodies[0].top", "dem.tif"] + words:
        assert word in message, message
    assert "\n" not in message


def test_missing_and_broken_geotiff(tmp_path):
    with pytest.raises(SceneError, match=r"bodies\[0\].top.*nope.tif.*No such file"):
        load_scene(write(tmp_path, _scene_text("nope.tif")))
    (tmp_path / "junk.tif").write_bytes(b"II*\x00 truncated")
    with pytest.raises(SceneError, match=r"bodies\[0\].top.*cannot read GeoTIFF.*junk.tif"):
        load_scene(write(tmp_path, _scene_text("junk.tif")))
