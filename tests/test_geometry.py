"""Particle generation from shapes: counts, layers, ids independent of the rank count."""
import numpy as np
import pytest

from decomposition.reduce import global_sum
from parsph.scene.geometry import (body_fill, estimate_count, fill_warnings, fitting_size,
                                   generate, wall_layers)
from parsph.scene.materials import PHASE_WALL
from parsph.scene.loader import load_scene
from parsph.errors import SceneError
from tests.scenes import MOVING_2D, MOVING_3D, alone_on_rank_zero, gather_particles, write


def test_tank_layers_and_counts(comm, tmp_path):
    scn = load_scene("hydrostatic")
    fields = generate(comm, scn)
    ids, x, phase = gather_particles(comm, fields)
    d = scn.domain.particle_size
    layers = wall_layers(scn, scn.walls[0])
    assert layers == 3  # ceil(2h/d) with h = 1.2 d
    n_water = int(round(1.0 / d)) ** 2
    n_inner = (int(round(1.0 / d)), int(round(1.2 / d)))
    n_wall = (n_inner[0] + 2 * layers) * (n_inner[1] + layers) - n_inner[0] * n_inner[1]
    assert (phase != PHASE_WALL).sum() == n_water
    assert (phase == PHASE_WALL).sum() == n_wall
    assert np.array_equal(ids, np.arange(len(ids)))
    walls = x[phase == PHASE_WALL]
    assert walls[:, 1].min() == pytest.approx(-(layers - 0.5) * d)
    assert walls[:, 1].max() == pytest.approx(1.2 - 0.5 * d)  # open top
    water = x[phase != PHASE_WALL]
    assert water.min() == pytest.approx(0.5 * d) and water.max() == pytest.approx(1.0 - 0.5 * d)
    assert estimate_count(scn) >= len(ids)


def test_polygon_and_extruded_polygon_inside(comm, tmp_path):
    scn = load_scene(write(tmp_path, MOVING_2D))
    ids, x, phase = gather_particles(comm, generate(comm, scn))
    right = x[(x[:, 0] > 1.0) & (phase != PHASE_WALL)]
    # the slanted top edge from (1.2, 0.4) to (1.9, 0.6): nothing above it
    top = 0.4 + (right[:, 0] - 1.2) * (0.2 / 0.7)
    assert np.all(right[(right[:, 0] > 1.2), 1] < top[right[:, 0] > 1.2] + 1e-12)
    scn3 = load_scene(write(tmp_path, MOVING_3D, "s3.toml"))
    ids3, x3, phase3 = gather_particles(comm, generate(comm, scn3))
    slab = x3[phase3 != PHASE_WALL]
    assert np.all(slab[:, 2] <= 0.6 * (1 - slab[:, 0] / 1.2) + 1e-12)
    assert set(np.round(slab[:, 1], 6)) == {round(0.05 + 0.1 * k, 6) for k in range(10)}


def test_heightmap_body(comm, tmp_path):
    (tmp_path / "z.asc").write_text(
        "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 0.5\n0.6 0.6 0.6\n0.2 0.4 0.6\n")
    text = MOVING_3D.replace('shape = "extruded_polygon"',
                             'shape = "heightmap"\ntop = "z.asc"\nbottom = 0.0')
    scn = load_scene(write(tmp_path, text))
    ids, x, phase = gather_particles(comm, generate(comm, scn))
    soil = x[phase != PHASE_WALL]
    # rows: y = 0 holds 0.2 0.4 0.6, y = 0.5 holds 0.6 everywhere (the file lists north first)
    assert len(soil) > 0
    assert np.all(soil[:, 0] <= 1.0) and np.all(soil[:, 1] <= 0.5)
    near_origin = soil[(soil[:, 0] < 0.1) & (soil[:, 1] < 0.1)]
    assert near_origin[:, 2].max() < 0.3


LAYERS = """
[scene]
name = "layers"

[domain]
dim = 3
particle_size = 0.1
lo = [0.0, 0.0, 0.0]
hi = [2.0, 1.0, 2.0]

[run]
end_time = 0.1
mode = "geometry"

[output]
every = 0.1
progress = false

[materials.rock]
model = "kinematic"
density = 2000.0
"""


def _grid(path, row):
    """An ESRI ASCII grid, 5 x 3 nodes every 0.5 m, every row (y) ``row`` (along x)."""
    path.write_text("ncols 5\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 0.5\n"
                    + "".join(" ".join(f"{v:g}" for v in row) + "\n" for _ in range(3)))


def _heightmap(name, top, **keys):
    lines = [f'[[bodies]]\nname = "{name}"\nmaterial = "rock"\nshape = "heightmap"',
             f'top = "{top}"'] + [f"{k} = {v!r}".replace("'", '"') for k, v in keys.items()]
    return "\n".join(lines) + "\n"


def test_layers_between_surfaces(comm, tmp_path):
    """``bottom_surface``: a lens between the ground and a base that meets the ground at
    its edges (a mass of varying thickness: soil 2 of the ``aso`` scene), and a layer
    hanging from that base. Together they are exactly the one body from the ground down,
    no lattice point twice and none missing, although the base's highest node (1.3 m) is
    below the ground's (1.4 m): every height map hangs its lattice from the highest node
    of all of them. The lens is empty where the base is the ground."""
    ground = [1.0, 1.1, 1.2, 1.3, 1.4]          # x = 0, 0.5, 1, 1.5, 2 m
    thick = [0.0, 0.0, 0.35, 0.0, 0.25]          # the lens: 0.35 m at x = 1, 0.25 at x = 2
    _grid(tmp_path / "ground.asc", ground)
    _grid(tmp_path / "base.asc", [g - t for g, t in zip(ground, thick)])
    two = LAYERS + _heightmap("lens", "ground.asc", bottom_surface="base.asc") \
        + _heightmap("under", "base.asc", bottom=0.0)
    one = LAYERS + _heightmap("all", "ground.asc", bottom=0.0)
    ids, x, _ = gather_particles(comm, generate(comm, load_scene(write(tmp_path, two))))
    _, x_one, _ = gather_particles(comm, generate(comm, load_scene(write(tmp_path, one, "1.toml"))))
    d = 0.1
    key = lambda p: np.round(p / (0.5 * d)).astype(np.int64)  # noqa: E731 (lattice cells)
    assert len(np.unique(key(x), axis=0)) == len(x)  # no point twice
    assert np.array_equal(np.unique(key(x), axis=0), np.unique(key(x_one), axis=0))
    n_lens = len(generate(comm, load_scene(write(tmp_path, LAYERS + _heightmap(
        "lens", "ground.asc", bottom_surface="base.asc"), "lens.toml")))["x"])
    lens = x[:global_sum(comm, n_lens)]  # the first body's ids come first
    assert len(lens) > 0
    # where the base is the ground (x <= 0.5 m and at x = 1.5 m) the lens has no point
    assert np.all((lens[:, 0] > 0.5) & (np.abs(lens[:, 0] - 1.5) > 0.5 * d - 1e-9))
    # the lens is 0.35 m thick at x = 1 m: 3 or 4 lattice points in its columns there
    mid = lens[np.abs(lens[:, 0] - 0.95) < 1e-9]
    assert len(np.unique(np.round(mid[:, 2], 9))) in (3, 4)


def test_heightmap_body_needs_a_base(tmp_path):
    """A height-map body without bottom, depth or bottom_surface, and a bottom_surface
    that cannot be read: one message each, naming the key."""
    _grid(tmp_path / "ground.asc", [1.0] * 5)
    with pytest.raises(SceneError, match=r"bodies\[0\]\.bottom'.*'bottom_surface'"):
        load_scene(write(tmp_path, LAYERS + _heightmap("a", "ground.asc")))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.bottom_surface'.*nothere.asc"):
        load_scene(write(tmp_path, LAYERS + _heightmap("a", "ground.asc",
                                                       bottom_surface="nothere.asc")))


@pytest.mark.parametrize("d", [0.05, 0.035])
def test_box_walls_continue_the_lattice_of_the_body_they_touch(comm, d):
    """slope_failure's 0.15 m floor and back wall at any d: the wall's first layer is one
    spacing from the soil's last, below it and behind it (0.15 / 0.035 is no whole number
    of layers: the floor's top layer was 1.29 d under the soil), and the floor stays in
    its box; at d = 0.05 m the walls are the same as laid from their lower corner."""
    scn = load_scene("slope_failure", [f"domain.particle_size={d}"])
    ids, x, phase = gather_particles(comm, generate(comm, scn))
    soil, wall = x[phase != PHASE_WALL], x[phase == PHASE_WALL]
    floor = wall[wall[:, 1] < 0.0]
    back = wall[wall[:, 1] > 0.0]
    assert soil[:, 1].min() - floor[:, 1].max() == pytest.approx(d)
    assert back[:, 0].min() - soil[:, 0].max() == pytest.approx(d)
    # columns continue: the floor's x and the soil's x are on one lattice
    assert np.allclose(np.remainder(floor[:, 0] - soil[0, 0] + 0.5 * d, d), 0.5 * d)
    assert floor[:, 1].min() >= -0.15 and back[:, 0].max() <= 2.65
    layers = len(np.unique(np.round(floor[:, 1], 9)))
    assert layers == int(0.15 / d + 1e-9)  # whole layers that fit: the wall's thickness
    if d == 0.05:
        assert np.isclose(floor[:, 1].max(), -0.025) and np.isclose(back[:, 0].min(), 2.525)


@pytest.mark.parametrize("d, rows, fits", [(0.05, 20, 0.05), (0.0177, 56, 0.1 / 6),
                                           (0.035, 29, 0.1 / 3), (0.02, 50, 0.02)])
def test_body_fill_reports_the_height_the_lattice_gives(comm, d, rows, fits):
    """The slope's 1 m stands as many rows tall as have their centre (k + 1/2) d under it
    (docs/geometry.md): 56 rows = 0.991 m at d = 0.0177 m, 29 = 1.015 m at 0.035 m. The
    report (the same on every rank) gives that height, the count and area, and the 2.2 m^2
    of the polygon; a warning names the nearest size that meets every vertex when the
    height is more than d/4 off, none where d divides the slope."""
    scn = load_scene("slope_failure", [f"domain.particle_size={d}"])
    fields = generate(comm, scn)
    (fill,) = body_fill(comm, scn, fields)
    n = global_sum(comm, int((fields["body"] == 0).sum()))
    assert fill["particles"] == n and fill["measure"] == pytest.approx(n * d * d)
    assert fill["hi"][1] - fill["lo"][1] == pytest.approx(rows * d)
    assert fill["lo"][0] == pytest.approx(0.0) and fill["lo"][1] == pytest.approx(0.0)
    assert fill["geometry_measure"] == pytest.approx(2.2)
    assert tuple(fill["geometry_hi"]) == (2.5, 1.0)
    assert fitting_size(scn.bodies[0], d) == pytest.approx(fits)
    warnings = fill_warnings(scn, [fill])
    off = abs(rows * d - 1.0) > 0.25 * d
    assert len(warnings) == off
    if off:
        assert "'slope'" in warnings[0] and f"{rows * d:.4g} m" in warnings[0]
        assert f"d = {fits:.4g} m meets every vertex" in warnings[0]


def test_a_period_the_lattice_does_not_tile_is_warned():
    """slope_failure_3d's slab is periodic over 0.25 m: at d = 0.04 m six layers leave the
    particles either side of the periodic boundary 0.05 m apart; at 0.0417 m none."""
    from parsph.scene.geometry import geometry_warnings

    (text,) = geometry_warnings(load_scene("slope_failure_3d", ["domain.particle_size=0.04"]))
    assert "periodic along axis 1 over 0.25 m" in text and "0.05 m apart" in text
    assert "0.04167 m" in text
    assert geometry_warnings(load_scene("slope_failure_3d",
                                        ["domain.particle_size=0.041666666666666664"])) == []


@pytest.mark.mpi
def test_ids_independent_of_rank_count(comm, tmp_path):
    path = write(tmp_path, MOVING_2D) if comm.rank == 0 else None
    path = comm.bcast(path)
    scn = load_scene(path)
    serial = alone_on_rank_zero(comm, lambda one: gather_particles(one, generate(one, scn)))
    parallel = gather_particles(comm, generate(comm, scn))
    assert global_sum(comm, 1) == comm.size
    if comm.rank == 0:
        assert np.array_equal(serial[0], parallel[0])
        assert np.array_equal(serial[1], parallel[1])


@pytest.mark.parametrize("name", ["hydrostatic", "dam_break", "bingham_slump", "slope_failure",
                                  "slope_failure_solid", "elastic_plate", "granular_collapse",
                                  "aso", "poiseuille"])
def test_estimate_count_is_the_generated_count(comm, name):
    """Tanks in closed form and small polygons tested point by point: exact. (The lattice
    candidates, which the budget used to take, counted dam_break's tank interior: 5.6x.)"""
    scn = load_scene(name)
    n = global_sum(comm, len(generate(comm, scn)["id"]))
    assert estimate_count(scn) == n


def test_estimate_count_samples_large_filtered_lattices(comm, monkeypatch):
    """Above _COUNT_EXACT candidates a polygon is sampled: an upper bound within 2 %."""
    import parsph.scene.geometry as geometry

    scn = load_scene("slope_failure")
    n = global_sum(comm, len(generate(comm, scn)["id"]))
    monkeypatch.setattr(geometry, "_COUNT_EXACT", 1 << 14)
    est = estimate_count(scn)
    assert n <= est <= 1.02 * n


def test_aso_terrain_is_its_generator_and_has_the_published_shape():
    """The ``aso`` scene's three grids are ``jobs/make_aso_terrain.py``'s output byte for
    byte, with the shape docs/aso.md matches to the published descriptions: the crown at
    725 m (Song et al. 2017: 725 m), about 400 m above the river and 700 m from it
    (web-gis.jp: about 400 m and 700 m), about 810 m of path (ICL: about 800 m of travel),
    a source 34 degrees steep on average (ICL: 35.0) and 359 m long (PASCO: 350 m), the
    gorge 77 m deep (ICL: 80 m), soil 2 30 m thick at most (ICL: at most about 35 m)."""
    import os

    from jobs import make_aso_terrain as gen

    x, s, b, t = gen.grids()
    for name, z in (("aso_surface.asc", s), ("aso_soil2_base.asc", b), ("aso_soil1_base.asc", t)):
        with open(os.path.join(gen.DATA, name), encoding="utf-8") as fh:
            assert fh.read() == gen.ascii_grid(z), name
    m = gen.summary(x, s, b)
    assert m["crown_m"] == pytest.approx(725.0, abs=1.0)
    assert m["relief_crown_river_m"] == pytest.approx(400.0, abs=5.0)
    assert m["crown_to_river_horizontal_m"] == pytest.approx(700.0, abs=1.0)
    assert m["crown_to_river_along_surface_m"] == pytest.approx(800.0, abs=15.0)
    assert 34.0 <= m["source_mean_slope_deg"] <= 35.5
    assert m["source_length_along_surface_m"] == pytest.approx(350.0, abs=15.0)
    rim = np.interp(40.0, x, s[0])                            # the far rim of the gorge
    assert rim - m["river_m"] == pytest.approx(77.0, abs=1.0)
    assert m["soil2_max_thickness_m"] == pytest.approx(30.0, abs=0.5)
    assert np.all(s >= b) and np.all(b > t)                   # the layers in order
    assert np.array_equal(b[:, x < 560.0], s[:, x < 560.0])   # no soil 2 below the source
