"""``parsph maps``: rasters of known deposits and cuts, the DEM's georeference through
GDAL, the same rasters on 1 and 2 ranks, and bad input (one message, no hang).

Runs are written frame by frame with the project's writer (synthetic: particles on a
lattice of spacing d moved by the test) or by ``parsph.run``. The thickness is
volume-based (each particle d³ over its d x d footprint, docs/maps.md), so a lattice
block gives its thickness exactly up to the fixed point of the shares: each boundary of
a footprint's shares along an axis is rounded by at most 2^-17 of the footprint, a cell
has two boundaries per axis, and a share is a fraction d / c of the cell, so a cell's
thickness T is off by at most 2 x 2 x 2^-17 x max(1, d / c) x T (:func:`tol`), far
inside the issue's "within d".
"""
import json
import os
import shutil
import subprocess

import numpy as np
import pytest
import tifffile
from mpi4py import MPI

from parsph.errors import ParsphError
from parsph.io import FrameWriter
from parsph.maps.compute import make_maps
from tests.scenes import MOVING_3D, write_shared

D = 0.1


def tol(thickness, cell):
    """The fixed point's bound on a cell's thickness error (module docstring)."""
    return 4 * 2.0 ** -17 * max(1.0, D / cell) * thickness

SCENE = """
[scene]
name = "synthetic"

[domain]
dim = 3
particle_size = 0.1
lo = [0.0, 0.0, -0.2]
hi = [2.0, 1.0, 1.5]

[run]
end_time = 1.0
mode = "kinematic"

[output]
every = 0.5
progress = false

[materials.rock]
model = "kinematic"
density = 2000.0

[[bodies]]
name = "block"
material = "rock"
shape = "box"
lo = [0.2, 0.2, 0.0]
hi = [0.6, 0.6, 0.5]
"""


def lattice(lo, hi, d=D):
    """Points ``lo + (k + 1/2) d`` inside the box [lo, hi]."""
    axes = [np.arange(a + d / 2, b - 1e-9, d) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


FLOOR = lattice((0.0, 0.0, -0.1), (2.0, 1.0, 0.0))


def write_run(comm, path, frames, scene=SCENE):
    """A run directory: ``scene.toml`` and ``particles.h5`` with ``frames``, a list of
    ``(time, soil positions, soil velocities[, {field: soil values}])`` over the wall
    floor (the soil solid unless ``phase`` is given); every rank writes an interleaved
    share of the rows."""
    scene_path = write_shared(comm, path, scene)
    attrs = {"scene": "synthetic", "particle_size": D, "scene_source": scene_path}
    with FrameWriter(path, comm, 3, attrs=attrs) as writer:
        for step, (time, x, v, *more) in enumerate(frames):
            soil = {"phase": np.zeros(len(x), np.uint8), **(more[0] if more else {})}
            fields = {"x": np.concatenate([x, FLOOR]),
                      "v": np.concatenate([v, np.zeros_like(FLOOR)])}
            for name, values in soil.items():
                wall = 2 if name == "phase" else 0
                fields[name] = np.r_[values, np.full(len(FLOOR), wall, values.dtype)]
            fields["id"] = np.arange(len(fields["x"]))
            mine = slice(comm.rank, None, comm.size)
            writer.write_frame(step, time, {k: a[mine] for k, a in fields.items()})
    return path


def raster(out, name):
    return tifffile.imread(os.path.join(out, f"{name}.tif")).astype(np.float64)


def centres(summary):
    g = summary["grid"]
    x = g["west_m"] + (np.arange(g["nx"]) + 0.5) * g["cell_m"]
    y = g["north_m"] - (np.arange(g["ny"]) + 0.5) * g["cell_m"]  # file rows: north first
    return np.meshgrid(x, y)


@pytest.mark.parametrize("cell", [0.25, 0.1, 0.04])
def test_block_come_to_rest_gives_its_thickness(comm, mpi_tmp_path, cell):
    """A block 5 layers thick slides 1 m and stops: the deposit is 0.5 m wherever it
    covers a cell wholly, on cells of 2.5 d (the cells cut the lattice), d and 0.4 d;
    the source is eroded by as much; the path had 0.5 m of flow at 1 m/s."""
    block = lattice((0.2, 0.2, 0.0), (0.6, 0.6, 0.5))
    moving = np.tile([1.0, 0.0, 0.0], (len(block), 1))
    write_run(comm, mpi_tmp_path, [(0.0, block, moving), (0.5, block + [0.5, 0, 0], moving),
                                   (1.0, block + [1.0, 0, 0], 0 * moving)])
    s = make_maps(comm, mpi_tmp_path, cell=cell, pictures=False)
    out = os.path.join(mpi_tmp_path, "maps")
    x, y = centres(s)
    h = cell / 2
    covered = lambda x0, x1: (x - h >= x0 - 1e-9) & (x + h <= x1 + 1e-9) \
        & (y - h >= 0.2 - 1e-9) & (y + h <= 0.6 + 1e-9)  # noqa: E731
    dep, ero = raster(out, "deposit_thickness"), raster(out, "erosion_depth")
    assert covered(1.2, 1.6).sum() >= 1
    assert np.abs(dep[covered(1.2, 1.6)] - 0.5).max() <= tol(0.5, cell)
    assert np.abs(ero[covered(0.2, 0.6)] - 0.5).max() <= tol(0.5, cell)
    # partly covered cells get their share; nothing outside the footprints (the rasters
    # are float32: 6e-8 relative per value)
    volume = 0.4 * 0.4 * 0.5
    assert dep.sum() * cell ** 2 == pytest.approx(volume, rel=1e-6)
    assert s["volume_deposited_m3"] == pytest.approx(volume, rel=1e-9)
    assert s["volume_eroded_m3"] == pytest.approx(volume, rel=1e-9)
    assert s["volume_outside_grid_m3"] == pytest.approx(0.0, abs=1e-12)
    flow = raster(out, "max_flow_depth")
    moving = covered(0.2, 0.6) | covered(0.7, 1.1)  # under the block at 0 and 0.5 s
    assert np.abs(flow[moving] - 0.5).max() <= tol(0.5, cell)
    assert flow[covered(1.2, 1.6) & ~covered(0.2, 1.1)].max() == 0.0  # at rest when there
    arrival = raster(out, "arrival_time")
    assert np.all(arrival[covered(0.2, 0.6)] == 0.0)
    assert np.all(arrival[covered(0.7, 1.1) & ~covered(0.2, 0.6)] == 0.5)
    assert np.all(np.isnan(arrival[covered(1.2, 1.6) & ~covered(0.2, 1.1)]))
    assert raster(out, "max_speed").max() == 1.0 and s["peak_speed_ms"] == 1.0
    assert raster(out, "surface_final")[covered(1.2, 1.6)] == pytest.approx(0.5)


def test_flowing_fluid_counts_only_the_debris(comm, mpi_tmp_path):
    """A block 5 layers deep, its upper 2 layers fluidised debris (phase 1, flagged
    ``fluidised``), all moving at 1 m/s: with ``flowing="fluid"`` the flow depth is the
    debris' 0.2 m, with the default the whole 0.5 m; the fluidised volume is 2 layers."""
    block = lattice((0.2, 0.2, 0.0), (0.6, 0.6, 0.5))
    debris = (block[:, 2] > 0.3).astype(np.uint8)
    soil = {"phase": debris, "fluidised": debris}
    moving = np.tile([1.0, 0.0, 0.0], (len(block), 1))
    write_run(comm, mpi_tmp_path, [(0.0, block, moving, soil), (0.5, block, moving, soil)])
    flow = {}
    for flowing in ("any", "fluid"):
        out = os.path.join(mpi_tmp_path, flowing)
        s = make_maps(comm, mpi_tmp_path, cell=D, out=out, flowing=flowing, pictures=False)
        assert s["flowing"] == flowing
        flow[flowing] = raster(out, "max_flow_depth").max()
    assert flow["any"] == pytest.approx(0.5, abs=tol(0.5, D))
    assert flow["fluid"] == pytest.approx(0.2, abs=tol(0.2, D))
    assert s["volume_fluidised_m3"] == s["volume_fluid_m3"] == pytest.approx(32 * D ** 3)
    with pytest.raises(ParsphError, match="--flowing 'debris'"):
        make_maps(comm, mpi_tmp_path, cell=D, flowing="debris")


def test_periodic_face_cells_are_filled_and_counted_once(comm, mpi_tmp_path):
    """A slab across a domain periodic in y (0 … 1 m) moves 1 m down x; cells of 0.15 m
    from y = 0 end at 1.05 m, so the last row is cut by the periodic face: it is filled
    from both sides (images), shows the slab's full thickness, and the volumes count
    its part inside the period once."""
    scene = SCENE.replace("[run]", "periodic = [false, true, false]\n\n[run]")
    slab = lattice((0.2, 0.0, 0.0), (0.6, 1.0, 0.5))
    write_run(comm, mpi_tmp_path, [(0.0, slab, 0 * slab), (1.0, slab + [1, 0, 0], 0 * slab)],
              scene=scene)
    s = make_maps(comm, mpi_tmp_path, cell=0.15, pictures=False)
    assert s["grid"]["north_m"] == pytest.approx(1.05)
    dep = raster(os.path.join(mpi_tmp_path, "maps"), "deposit_thickness")
    x, _ = centres(s)
    whole = (x - 0.075 >= 1.2 - 1e-9) & (x + 0.075 <= 1.6 + 1e-9)
    assert whole[0].sum() >= 1  # file row 0: the northern row, cut by the face
    assert np.abs(dep[whole] - 0.5).max() <= tol(0.5, 0.15)
    volume = 0.4 * 1.0 * 0.5
    for key in ("volume_deposited_m3", "volume_eroded_m3", "volume_in_grid_end_m3"):
        assert s[key] == pytest.approx(volume, rel=1e-9), key
    assert s["volume_outside_grid_m3"] == pytest.approx(0.0, abs=1e-12)


def test_cut_gives_its_erosion_and_the_travel_angle(comm, mpi_tmp_path):
    """A stair-shaped source (columns 10, 9, 8, 7, 6 layers high, two rows wide) is cut
    away and laid down as a sheet two layers thick 0.5 m further: the erosion is each
    column's height, the deposit 0.2 m, the volumes equal, and the Fahrböschung runs from
    the highest eroded point (the 1 m column) to the farthest deposited cell."""
    stair = np.concatenate([lattice((0.1 * k, 0.0, 0.0), (0.1 * k + 0.1, 0.2, 1.0 - 0.1 * k))
                            for k in range(5)])
    sheet = lattice((1.0, 0.0, 0.0), (2.0, 0.4, 0.2))
    assert len(stair) == len(sheet) == 80
    write_run(comm, mpi_tmp_path, [(0.0, stair, np.zeros_like(stair)),
                                   (1.0, sheet, np.zeros_like(sheet))])
    s = make_maps(comm, mpi_tmp_path, cell=D, pictures=False)
    out = os.path.join(mpi_tmp_path, "maps")
    ero, dep = raster(out, "erosion_depth"), raster(out, "deposit_thickness")
    x, y = centres(s)
    src = (x < 0.5) & (y < 0.2)
    heights = 1.0 - 0.1 * np.floor(x / 0.1 + 1e-9)
    assert np.abs(ero[src] - heights[src]).max() <= tol(1.0, D)
    assert ero[~src].max() == 0.0
    sheet_cells = (x > 1.0) & (y < 0.4)
    assert np.abs(dep[sheet_cells] - 0.2).max() <= tol(0.2, D) and dep[~sheet_cells].max() == 0.0
    volume = 80 * D ** 3
    assert s["volume_eroded_m3"] == pytest.approx(volume, rel=1e-9)
    assert s["volume_deposited_m3"] == pytest.approx(volume, rel=1e-9)
    assert s["area_eroded_m2"] == pytest.approx(0.1) and s["area_deposited_m2"] == pytest.approx(0.4)
    # crown: the 1 m column (the southern of its two cells: ties go to the lowest row);
    # toe: the sheet's cell farthest from it, whose top is 0.2 m
    assert s["crown_xyz_m"] == pytest.approx([0.05, 0.05, 1.0])
    assert s["toe_xyz_m"] == pytest.approx([1.95, 0.35, 0.2])
    length = np.hypot(1.9, 0.3)
    assert s["runout_m"] == pytest.approx(length)
    assert s["height_drop_m"] == pytest.approx(0.8)
    assert s["travel_angle_deg"] == pytest.approx(np.degrees(np.arctan(0.8 / length)))
    # centroids: of the eroded columns (each at half its height) and of the sheet
    h = np.array([1.0, 0.9, 0.8, 0.7, 0.6])
    e = [np.sum(h * (0.05 + 0.1 * np.arange(5))) / h.sum(), 0.1, np.sum(h * h / 2) / h.sum()]
    assert s["source_centroid_xyz_m"] == pytest.approx(e)
    assert s["deposit_centroid_xyz_m"] == pytest.approx([1.5, 0.2, 0.1])
    assert s["travel_angle_com_deg"] == pytest.approx(
        np.degrees(np.arctan2(e[2] - 0.1, np.hypot(1.5 - e[0], 0.2 - e[1]))))
    with open(os.path.join(out, "summary.json")) as fh:
        on_disk = json.load(fh)
    for key in ("volume_fluidised_m3", "volume_deposited_m3", "runout_m", "height_drop_m",
                "travel_angle_deg", "peak_speed_ms"):
        assert key in on_disk
    assert on_disk["runout_m"] == pytest.approx(length)


def _gdalinfo(path):
    exe = shutil.which("gdalinfo")
    assert exe, "gdalinfo not found: scripts/setup.sh installs Debian's gdal-bin"
    return json.loads(subprocess.run([exe, "-json", path], capture_output=True, text=True,
                                     check=True).stdout)


def test_geotiff_dem_in_gives_its_transform_and_crs_out(comm, mpi_tmp_path):
    """A slab from a GeoTIFF DEM in UTM 33N (EPSG 32633), 500 km east: the rasters have
    the DEM's size, geotransform and CRS as GDAL reads them; with --cell, the DEM's CRS
    and corner, the new cell size."""
    from tests.test_geotiff import MODEL, PROJECTED, RASTER

    x0, y0, cell = 500000.0, 4100000.0, 0.25
    z = np.full((5, 8), 0.4)
    dem = os.path.join(mpi_tmp_path, "dem.tif")
    if comm.rank == 0:
        tags = [(33550, "d", 3, (cell, cell, 0.0), True),
                (33922, "d", 6, (0.0, 0.0, 0.0, x0 - cell / 2, y0 + 4.5 * cell, 0.0), True),
                (34735, "H", 16, (1, 1, 0, 3, MODEL, 0, 1, 1, RASTER, 0, 1, 1,
                                  PROJECTED, 0, 1, 32633), True)]
        tifffile.imwrite(dem, z.astype(np.float32), extratags=tags)
    scene = MOVING_3D.replace('shape = "extruded_polygon"', 'shape = "heightmap"\n'
                              'top = "dem.tif"\nbottom = 0.0')
    scene = scene.replace("lo = [0.0, 0.0, -0.4]", f"lo = [{x0 - 0.1}, {y0 - 0.1}, -0.4]")
    scene = scene.replace("hi = [1.5, 1.0, 1.0]", f"hi = [{x0 + 1.85}, {y0 + 1.1}, 1.0]")
    scene = scene.replace("periodic = [true, true, false]", "periodic = [false, false, false]")
    scene = scene.replace('mode = "kinematic"', 'mode = "geometry"')
    scene = scene.split("[[walls]]")[0]
    import parsph

    path = write_shared(comm, mpi_tmp_path, scene)
    run = os.path.join(mpi_tmp_path, "run")
    parsph.run(parsph.load_scene(path), out=run, comm=comm)
    s = make_maps(comm, run)
    wide = make_maps(comm, run, cell=0.5, out=os.path.join(run, "wide"), pictures=False)
    if comm.rank == 0:
        ref = _gdalinfo(dem)
        assert s["grid"]["nx"] == 8 and s["grid"]["ny"] == 5
        for name in ("deposit_thickness", "erosion_depth", "max_flow_depth", "max_speed",
                     "arrival_time"):
            info = _gdalinfo(os.path.join(run, "maps", f"{name}.tif"))
            assert info["size"] == ref["size"] == [8, 5]
            assert info["geoTransform"] == ref["geoTransform"]
            assert info["coordinateSystem"]["wkt"] == ref["coordinateSystem"]["wkt"]
            assert "32633" in info["coordinateSystem"]["wkt"]
            assert info["bands"][0]["noDataValue"] == "NaN"
        info = _gdalinfo(os.path.join(run, "wide", "max_speed.tif"))
        assert info["coordinateSystem"]["wkt"] == ref["coordinateSystem"]["wkt"]
        t = ref["geoTransform"]
        assert info["geoTransform"] == pytest.approx([t[0], 0.5, 0.0, t[3], 0.0, -0.5], rel=1e-12)
        assert info["size"] == [4, 3]
        thick = raster(os.path.join(run, "maps"), "surface_initial")
        assert np.abs(thick - 0.4).max() <= D / 2  # the slab's top: the DEM's 0.4 m
        assert os.path.getsize(os.path.join(run, "maps", "deposit_thickness.png")) > 1000


@pytest.mark.mpi
def test_one_and_two_ranks_give_identical_rasters(comm, mpi_tmp_path):
    """A slab sliding over a periodic bed (images across both periodic faces), cells of
    0.07 m that cut the lattice: the rasters and summary of 1 rank and 2 ranks agree bit
    for bit."""
    import parsph

    path = write_shared(comm, mpi_tmp_path, MOVING_3D)
    run = os.path.join(mpi_tmp_path, "run")
    parsph.run(parsph.load_scene(path), out=run, comm=comm)
    one = comm.Split(0 if comm.rank == 0 else MPI.UNDEFINED, comm.rank)
    serial = None
    if comm.rank == 0:
        serial = make_maps(one, run, cell=0.07, out=os.path.join(run, "one"), pictures=False)
    parallel = make_maps(comm, run, cell=0.07, out=os.path.join(run, "two"), pictures=False)
    if comm.rank == 0:
        assert parallel["grid"]["ny"] >= 10 and parallel["volume_eroded_m3"] > 0.01
        for name in ("deposit_thickness", "erosion_depth", "max_flow_depth", "max_speed",
                     "arrival_time", "surface_initial", "surface_final"):
            a = tifffile.imread(os.path.join(run, "one", f"{name}.tif"))
            b = tifffile.imread(os.path.join(run, "two", f"{name}.tif"))
            assert np.array_equal(a, b, equal_nan=True), name
        for key in serial:
            if key != "files":
                assert serial[key] == parallel[key], key


def test_bad_input_is_refused_before_any_work(comm, mpi_tmp_path):
    """No frames, a cell size <= 0, a grid beyond the memory, a 2D run, a lost scene
    file and no height map without --cell: one ParsphError each, on every rank."""
    empty = os.path.join(mpi_tmp_path, "empty")
    if comm.rank == 0:
        os.makedirs(empty)
    comm.Barrier()
    with pytest.raises(ParsphError, match="particles.h5: no such file"):
        make_maps(comm, empty)
    with FrameWriter(empty, comm, 3, attrs={"particle_size": D}):
        pass
    with pytest.raises(ParsphError, match="holds no frame yet"):
        make_maps(comm, empty)
    block = lattice((0.2, 0.2, 0.0), (0.6, 0.6, 0.5))
    run = write_run(comm, os.path.join(mpi_tmp_path), [(0.0, block, 0 * block)])
    for cell in (0.0, -1.0, float("nan")):
        with pytest.raises(ParsphError, match="must be a positive number"):
            make_maps(comm, run, cell=cell)
    with pytest.raises(ParsphError, match=r"would need .* GiB.*larger --cell"):
        make_maps(comm, run, cell=1e-6)
    with pytest.raises(ParsphError, match="no heightmap body.*--cell 0.2"):
        make_maps(comm, run)
    with pytest.raises(ParsphError, match="not there now.*--scene"):
        make_maps(comm, run, cell=0.1, scene=os.path.join(mpi_tmp_path, "gone.toml"))
    assert not os.path.exists(os.path.join(run, "maps", "deposit_thickness.tif"))
    flat = os.path.join(mpi_tmp_path, "flat")
    if comm.rank == 0:
        os.makedirs(flat)
    comm.Barrier()
    with FrameWriter(flat, comm, 2, attrs={"particle_size": D}) as w:
        w.write_frame(0, 0.0, {"x": np.zeros((1, 2)) if comm.rank == 0 else np.zeros((0, 2))})
    with pytest.raises(ParsphError, match="2D run.*parsph plot"):
        make_maps(comm, flat, cell=0.1)


@pytest.mark.serial_only
def test_cli_maps_on_two_ranks_and_its_bad_input(tmp_path):
    """``mpirun -n 2 parsph maps``: the files, and for no frames, --cell 0 and a grid
    beyond the memory one message on rank 0, exit status 2, no traceback, no hang."""
    from tests.test_cli import parsph

    block = lattice((0.2, 0.2, 0.0), (0.6, 0.6, 0.5))
    run = write_run(MPI.COMM_SELF, str(tmp_path), [(0.0, block, 0 * block),
                                                   (1.0, block + [1, 0, 0], 0 * block)])
    r = parsph("maps", run, "--cell", "0.2", ranks=2)
    assert r.returncode == 0, r.stderr
    files = r.stdout.split()
    names = {os.path.basename(p) for p in files}
    assert {"deposit_thickness.tif", "erosion_depth.tif", "max_flow_depth.tif",
            "max_speed.tif", "arrival_time.tif", "summary.json",
            "deposit_thickness.png"} <= names
    assert all(os.path.getsize(p) > 100 for p in files)
    os.makedirs(tmp_path / "nothing")
    for args, words in (([str(tmp_path / "nothing")], "no such file"),
                        ([run, "--cell", "0"], "must be a positive number"),
                        ([run, "--cell", "1e-7"], "GiB")):
        r = parsph("maps", *args, ranks=2, timeout=120)
        assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
        assert words in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert r.stderr.count("parsph: error:") == 1, r.stderr
