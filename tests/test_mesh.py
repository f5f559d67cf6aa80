"""Bodies and walls from triangle meshes (STL binary/ASCII, OBJ), written by the tests."""
import math
import os
import pathlib

import numpy as np
import pytest
import trimesh
from mpi4py import MPI

from decomposition.reduce import global_sum
from parsph.errors import SceneError
from parsph.geometry import estimate_count, generate
from parsph.materials import PHASE_WALL
from parsph.scene import load_scene
from tests.scenes import write

SCENE = """
[scene]
name = "mesh"

[domain]
dim = 3
particle_size = {d}
lo = [-0.5, -0.5, -0.5]
hi = [1.5, 1.5, 1.5]

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

BODY = """
[[bodies]]
name = "{name}"
material = "rock"
shape = "mesh"
file = "{file}"
{extra}
"""

WALL = """
[[walls]]
name = "{name}"
shape = "mesh"
file = "{file}"
{extra}
"""


def _scene(tmp_path, d=0.05, bodies=(), walls=(), name="scene.toml", comm=None):
    """Write a scene (rank 0 only, when ``comm`` says the directory is shared) and load it."""
    text = SCENE.format(d=d)
    for n, (file, extra) in enumerate(bodies):
        text += BODY.format(name=f"b{n}", file=file, extra=extra)
    for n, (file, extra) in enumerate(walls):
        text += WALL.format(name=f"w{n}", file=file, extra=extra)
    if comm is None or comm.rank == 0:
        write(str(tmp_path), text, name)
    if comm is not None:
        comm.Barrier()
    return load_scene(os.path.join(str(tmp_path), name))


def _export(mesh, path, file_type=None):
    mesh.export(str(path), file_type=file_type)
    return path.name


def _gather(comm, fields):
    allf = comm.allgather({k: fields[k] for k in ("id", "x", "phase", "body")})
    ids = np.concatenate([f["id"] for f in allf])
    order = np.argsort(ids)
    return {k: np.concatenate([f[k] for f in allf])[order] for k in ("id", "x", "phase", "body")}


def _shared(mpi_tmp_path):
    """The directory all ranks share (fixtures are written there by rank 0)."""
    return pathlib.Path(mpi_tmp_path)


def _unit_cube():
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    box.apply_translation((0.5, 0.5, 0.5))
    return box


def test_cube_and_sphere_fill_their_volume(comm, mpi_tmp_path):
    """A unit cube on an aligned lattice holds exactly (1/d)^3 points. A ball of radius
    R = 10 d: count d^3 within 2 % of 4/3 pi R^3: the 5,120-triangle sphere is 0.2 %
    smaller than the ball, and a ball's lattice count differs from its volume by 0.6 %
    at most over random centres and 1.1 % at the lattice-symmetric centre used here
    (whole shells of lattice points enter at once). A column with a missed or doubled
    crossing would flip up to 20 points at once, and a fill of the bounding box is 91 %
    too many."""
    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        _export(_unit_cube(), tmp / "cube.stl")
        ball = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
        ball.apply_translation((0.5, 0.5, 0.5))
        _export(ball, tmp / "ball.stl")
    comm.Barrier()
    d = 0.05
    scn = _scene(tmp, d, bodies=[("cube.stl", ""), ("ball.stl", 'translate = [0.0, 0.0, 0.0]')],
                 comm=comm)
    f = _gather(comm, generate(comm, scn))
    n_cube = int((f["body"] == 0).sum())
    n_ball = int((f["body"] == 1).sum())
    assert n_cube == 20 ** 3
    assert n_ball * d ** 3 == pytest.approx(4.0 / 3.0 * math.pi * 0.5 ** 3, rel=0.02)
    cube = f["x"][f["body"] == 0]
    assert cube.min() == pytest.approx(0.5 * d) and cube.max() == pytest.approx(1 - 0.5 * d)
    ball_x = f["x"][f["body"] == 1]
    assert np.all(np.linalg.norm(ball_x - 0.5, axis=1) < 0.5)
    assert np.array_equal(f["id"], np.arange(len(f["id"])))
    assert estimate_count(scn) == len(f["id"])


def test_stl_binary_ascii_and_obj_give_the_same_particles(comm, mpi_tmp_path):
    """Vertices on a 1/64 m grid are exact in every format (float32 STL, text), so the
    three files describe one surface and must fill the same lattice points."""
    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
        ball.vertices = np.round((ball.vertices + 0.5) * 64) / 64
        _export(ball, tmp / "b.stl", "stl")
        _export(ball, tmp / "a.stl", "stl_ascii")
        _export(ball, tmp / "o.obj", "obj")
        assert (tmp / "a.stl").read_text().startswith("solid")
    comm.Barrier()
    runs = []
    for file in ("b.stl", "a.stl", "o.obj"):
        scn = _scene(tmp, 0.05, bodies=[(file, "")], name=f"{file}.toml", comm=comm)
        runs.append(_gather(comm, generate(comm, scn)))
    assert len(runs[0]["id"]) > 1000
    for other in runs[1:]:
        assert np.array_equal(runs[0]["id"], other["id"])
        assert np.array_equal(runs[0]["x"], other["x"])


def test_scale_rotate_translate_place_the_mesh(comm, mpi_tmp_path):
    """A 10 x 20 x 40 mm brick, scale = 0.01 (to 0.1 x 0.2 x 0.4 m), turned 90 degrees
    about z (0.2 x 0.1 x 0.4 m), moved by (0.3, 0.4, 0.5): exactly where it should be."""
    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        brick = trimesh.creation.box(extents=(10.0, 20.0, 40.0))
        brick.apply_translation((5.0, 10.0, 20.0))
        _export(brick, tmp / "brick.stl")
    comm.Barrier()
    extra = "scale = 0.01\nrotate = [0.0, 0.0, 90.0]\ntranslate = [0.5, 0.4, 0.5]"
    f = _gather(comm, generate(comm, _scene(tmp, 0.05, bodies=[("brick.stl", extra)], comm=comm)))
    x = f["x"]
    assert len(x) == 4 * 2 * 8
    assert x.min(axis=0) == pytest.approx([0.325, 0.425, 0.525])
    assert x.max(axis=0) == pytest.approx([0.475, 0.475, 0.875])


def test_mesh_wall_layers_inside_and_outside(comm, mpi_tmp_path):
    """A cube of 10 d as a wall. inside: the points with an outside point within 3 d:
    the cube less its 4^3 core. outside: the points within 3 d of an inside point: faces
    6 (3 n^2), edges 12 (4 n) (offsets (a, b) >= 1 with a^2 + b^2 <= 9), corners 8 (7)."""
    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        _export(_unit_cube(), tmp / "cube.stl")
    comm.Barrier()
    d, n = 0.1, 10
    scn = _scene(tmp, d, walls=[("cube.stl", 'fill = "inside"'),
                                ("cube.stl", 'fill = "outside"')], comm=comm)
    f = _gather(comm, generate(comm, scn))
    assert np.all(f["phase"] == PHASE_WALL)
    inside, outside = f["x"][f["body"] == 0], f["x"][f["body"] == 1]
    assert len(inside) == n ** 3 - (n - 6) ** 3
    assert len(outside) == 6 * 3 * n ** 2 + 12 * 4 * n + 8 * 7
    assert np.all((inside > 0) & (inside < 1))
    assert np.all(np.any((outside < 0) | (outside > 1), axis=1))
    assert outside.min() == pytest.approx(-2.5 * d) and outside.max() == pytest.approx(1 + 2.5 * d)
    assert estimate_count(scn) == len(f["id"])
    one = _gather(comm, generate(comm, load_scene(scn.source, ["walls.0.layers=1"])))
    assert int((one["body"] == 0).sum()) == n ** 3 - (n - 2) ** 3


def test_estimate_samples_large_mesh_lattices(comm, mpi_tmp_path, monkeypatch):
    """Above _MESH_COLUMNS columns the count is sampled: an upper bound, within 25 %
    for a body from 256 of 625 columns (four standard errors: ~15 %; the default 16,384
    columns are 8 times tighter) and within a factor 2 for a wall (16 blocks of columns)."""
    import parsph.geometry as geometry

    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
        ball.apply_translation((0.5, 0.5, 0.5))
        _export(ball, tmp / "ball.stl")
    comm.Barrier()
    for kind in ("bodies", "walls"):
        scn = _scene(tmp, 0.04, comm=comm, name=f"{kind}.toml", **{kind: [("ball.stl", "")]})
        n = global_sum(comm, len(generate(comm, scn)["id"]))
        monkeypatch.setattr(geometry, "_MESH_COLUMNS", 256)
        est = estimate_count(scn)
        monkeypatch.undo()
        assert n <= est <= (1.25 if kind == "bodies" else 2.0) * n, (kind, n, est)


def test_open_and_bad_meshes_are_refused(tmp_path):
    cube = _unit_cube()
    open_cube = trimesh.Trimesh(cube.vertices, cube.faces[:-1], process=False)
    _export(open_cube, tmp_path / "open.stl")
    with pytest.raises(SceneError) as info:
        _scene(tmp_path, bodies=[("open.stl", "")])
    message = str(info.value)
    for word in ("bodies[0].file", "open.stl", "not watertight", "3 of its 18 edges"):
        assert word in message, message
    with pytest.raises(SceneError, match=r"walls\[0\].file.*nope.stl.*does not exist"):
        _scene(tmp_path, walls=[("nope.stl", "")])
    (tmp_path / "junk.stl").write_bytes(b"\x00\x01 not a mesh at all")
    with pytest.raises(SceneError, match=r"bodies\[0\].file.*junk.stl"):
        _scene(tmp_path, bodies=[("junk.stl", "")])
    (tmp_path / "cube.ply").write_text("ply\n")
    with pytest.raises(SceneError, match=r"bodies\[0\].file.*'.ply'.*\.stl, \.obj"):
        _scene(tmp_path, bodies=[("cube.ply", "")])
    _export(cube, tmp_path / "cube.stl")
    with pytest.raises(SceneError, match=r"bodies\[0\].file.*not inside the domain"):
        _scene(tmp_path, bodies=[("cube.stl", "translate = [1.0, 0.0, 0.0]")])
    with pytest.raises(SceneError, match=r"walls\[0\].file.*outside layers.*not inside"):
        _scene(tmp_path, walls=[("cube.stl", 'fill = "outside"\nlayers = 12')])
    with pytest.raises(SceneError, match=r"bodies\[0\].rotate.*3 numbers"):
        _scene(tmp_path, bodies=[("cube.stl", "rotate = [90.0]")])
    with pytest.raises(SceneError, match=r"bodies\[0\].file.*needs the path"):
        _scene(tmp_path, bodies=[("", "")])


def test_mesh_in_2d_is_refused(tmp_path):
    _export(_unit_cube(), tmp_path / "cube.stl")
    text = (SCENE.format(d=0.1).replace("dim = 3", "dim = 2")
            .replace("[-0.5, -0.5, -0.5]", "[-0.5, -0.5]").replace("[1.5, 1.5, 1.5]", "[1.5, 1.5]")
            + BODY.format(name="b", file="cube.stl", extra=""))
    with pytest.raises(SceneError, match=r"bodies\[0\].shape.*3D scenes.*polygon"):
        load_scene(write(tmp_path, text))


@pytest.mark.mpi
def test_mesh_particles_independent_of_rank_count(comm, mpi_tmp_path):
    """A body and both kinds of wall: rank 0 alone and all ranks fill the same points
    with the same ids (each rank tests only its share of the lattice)."""
    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
        ball.apply_translation((0.5, 0.5, 0.5))
        _export(ball, tmp / "ball.stl")
        _export(_unit_cube(), tmp / "cube.stl")
    comm.Barrier()
    scn = _scene(tmp, 0.05, bodies=[("ball.stl", "")],
                 walls=[("cube.stl", 'fill = "outside"\ntranslate = [0.0, 0.0, 0.0]'),
                        ("ball.stl", 'fill = "inside"\ntranslate = [0.0, 0.0, -0.4]\nlayers = 2')],
                 comm=comm)
    one = comm.Split(0 if comm.rank == 0 else MPI.UNDEFINED, comm.rank)
    serial = _gather(one, generate(one, scn)) if comm.rank == 0 else None
    local = generate(comm, scn)
    assert global_sum(comm, int(len(local["id"]) > 0)) == comm.size  # every rank filled some
    parallel = _gather(comm, local)
    if comm.rank == 0:
        for k in ("id", "x", "body"):
            assert np.array_equal(serial[k], parallel[k])
        one.Free()


BOULDER = """
[scene]
name = "boulder"
description = "an elastic boulder from an STL hitting a ramp from an OBJ, both in mm"

[domain]
dim = 3
particle_size = 0.03
lo = [-0.2, -0.2, -0.2]
hi = [1.2, 0.6, 0.8]

[run]
end_time = 1.0
max_steps = 50

[output]
every = 0.5
progress = false

[solid]
hourglass = 1.0

[materials.granite]
model = "hencky"
density = 2700.0
young_modulus = 2.0e6
poisson_ratio = 0.3

[[bodies]]
name = "boulder"
material = "granite"
shape = "mesh"
file = "boulder.stl"
scale = 0.001
rotate = [0.0, 20.0, 0.0]
translate = [0.3, 0.2, 0.32]
velocity = [0.0, 0.0, -2.0]

[[walls]]
name = "ramp"
shape = "mesh"
file = "ramp.obj"
scale = 0.001
fill = "inside"
"""


def _ramp_mm():
    """A wedge 1000 x 400 mm, 300 mm high at x = 0 and 50 mm at x = 1000."""
    v = np.array([[0, 0, 0], [1000, 0, 0], [1000, 400, 0], [0, 400, 0], [0, 0, 300],
                  [1000, 0, 50], [1000, 400, 50], [0, 400, 300]], dtype=float)
    f = [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [3, 7, 6],
         [3, 6, 2], [0, 4, 7], [0, 7, 3], [1, 2, 6], [1, 6, 5]]
    return trimesh.Trimesh(v, f)


@pytest.mark.mpi(min_size=2)
def test_user_scene_mesh_boulder_on_mesh_ramp_one_vs_two_ranks(comm, mpi_tmp_path):
    """A user's scene: CAD files in mm, loaded on rank 0 as the CLI does; the boulder
    reaches the ramp, and 1 and 2 ranks agree by global id."""
    from decomposition.comm import on_root
    from tests.scenes import last_frame, run_on_one_and_two

    tmp = _shared(mpi_tmp_path)
    if comm.rank == 0:
        rock = trimesh.creation.icosphere(subdivisions=2, radius=100.0)
        rock.apply_scale((1.0, 0.8, 0.7))
        _export(rock, tmp / "boulder.stl")
        _export(_ramp_mm(), tmp / "ramp.obj")
        write(str(tmp), BOULDER, "boulder.toml")
    comm.Barrier()
    scene = on_root(comm, load_scene, str(tmp / "boulder.toml"))
    one, two = run_on_one_and_two(comm, scene, str(tmp))
    if comm.rank == 0:
        a, b = last_frame(one), last_frame(two)
        assert np.array_equal(a["id"], b["id"])
        assert set(np.unique(b["rank"])) == {0, 1}
        solid = a["phase"] != PHASE_WALL
        assert 60 < solid.sum() < 120 and (~solid).sum() > 1000
        assert np.abs(a["x"] - b["x"]).max() < 1e-9
        assert np.abs(a["v"] - b["v"]).max() < 1e-7
        # it hit the ramp and is bouncing off (with the ramp 0.15 m lower: -2.2 m/s)
        assert a["v"][solid, 2].mean() > 0.0
