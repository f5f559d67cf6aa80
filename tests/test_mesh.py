"""Bodies and walls from triangle meshes (STL binary/ASCII, OBJ), written by the tests."""
import math
import pathlib
import tomllib

import numpy as np
import pytest
import trimesh

from decomposition.reduce import global_sum
from parsph.errors import SceneError
from parsph.scene.geometry import estimate_count, generate
from parsph.scene.materials import PHASE_WALL
from parsph.scene.loader import load_scene
from tests.scenes import alone_on_rank_zero, hencky, scene_text, toml_text, write, write_shared

def _mesh(name, file, extra="", **keys):
    """A body or wall from the mesh ``file``; ``extra``: more of its keys, as TOML."""
    return {"name": name, **keys, "shape": "mesh", "file": file, **tomllib.loads(extra)}


def _text(d, bodies=(), walls=(), dim=3):
    """A geometry scene of rock bodies and walls from meshes, each a (file, extra) pair."""
    return scene_text(
        "mesh", d, [-0.5] * dim, [1.5] * dim, 0.1, run={"mode": "geometry"},
        materials={"rock": {"model": "kinematic", "density": 2000.0}},
        bodies=[_mesh(f"b{n}", *body, material="rock") for n, body in enumerate(bodies)],
        walls=[_mesh(f"w{n}", *wall) for n, wall in enumerate(walls)])


def _scene(tmp_path, d=0.05, bodies=(), walls=(), name="scene.toml", comm=None):
    """Write a scene (rank 0 only, when ``comm`` says the directory is shared) and load it."""
    return load_scene(write_shared(comm, str(tmp_path), _text(d, bodies, walls), name))


def _export(mesh, path, file_type=None):
    mesh.export(str(path), file_type=file_type)
    return path.name


def _gather(comm, fields):
    allf = comm.allgather({k: fields[k] for k in ("id", "x", "phase", "body")})
    ids = np.concatenate([f["id"] for f in allf])
    order = np.argsort(ids)
    return {k: np.concatenate([f[k] for f in allf])[order] for k in ("id", "x", "phase", "body")}


def _shared(comm, mpi_tmp_path, meshes):
    """Rank 0 writes ``meshes`` ({file name: mesh, or (mesh, file type)}) to the directory
    all ranks share; returns that directory once they are there."""
    tmp = pathlib.Path(mpi_tmp_path)
    if comm.rank == 0:
        for name, mesh in meshes.items():
            mesh, file_type = mesh if isinstance(mesh, tuple) else (mesh, None)
            _export(mesh, tmp / name, file_type)
    comm.Barrier()
    return tmp


def _ball(subdivisions, radius, centre=(0.5, 0.5, 0.5)):
    """An icosphere of ``radius`` about ``centre``."""
    ball = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    ball.apply_translation(centre)
    return ball


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
    tmp = _shared(comm, mpi_tmp_path, {"cube.stl": _unit_cube(), "ball.stl": _ball(4, 0.5)})
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
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
    ball.vertices = np.round((ball.vertices + 0.5) * 64) / 64
    tmp = _shared(comm, mpi_tmp_path, {"b.stl": (ball, "stl"), "a.stl": (ball, "stl_ascii"),
                                       "o.obj": (ball, "obj")})
    if comm.rank == 0:
        assert (tmp / "a.stl").read_text().startswith("solid")
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
    brick = trimesh.creation.box(extents=(10.0, 20.0, 40.0))
    brick.apply_translation((5.0, 10.0, 20.0))
    tmp = _shared(comm, mpi_tmp_path, {"brick.stl": brick})
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
    tmp = _shared(comm, mpi_tmp_path, {"cube.stl": _unit_cube()})
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
    import parsph.scene.geometry as geometry

    tmp = _shared(comm, mpi_tmp_path, {"ball.stl": _ball(3, 0.5)})
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
    text = _text(0.1, dim=2) + toml_text(bodies=[_mesh("b", "cube.stl", material="rock")])
    with pytest.raises(SceneError, match=r"bodies\[0\].shape.*3D scenes.*polygon"):
        load_scene(write(tmp_path, text))


@pytest.mark.mpi
def test_mesh_particles_independent_of_rank_count(comm, mpi_tmp_path):
    """A body and both kinds of wall: rank 0 alone and all ranks fill the same points
    with the same ids (each rank tests only its share of the lattice)."""
    tmp = _shared(comm, mpi_tmp_path, {"ball.stl": _ball(3, 0.4), "cube.stl": _unit_cube()})
    scn = _scene(tmp, 0.05, bodies=[("ball.stl", "")],
                 walls=[("cube.stl", 'fill = "outside"\ntranslate = [0.0, 0.0, 0.0]'),
                        ("ball.stl", 'fill = "inside"\ntranslate = [0.0, 0.0, -0.4]\nlayers = 2')],
                 comm=comm)
    serial = alone_on_rank_zero(comm, lambda one: _gather(one, generate(one, scn)))
    local = generate(comm, scn)
    assert global_sum(comm, int(len(local["id"]) > 0)) == comm.size  # every rank filled some
    parallel = _gather(comm, local)
    if comm.rank == 0:
        for k in ("id", "x", "body"):
            assert np.array_equal(serial[k], parallel[k])


BOULDER = scene_text(
    "boulder", 0.03, [-0.2, -0.2, -0.2], [1.2, 0.6, 0.8], 1.0, 0.5, run={"max_steps": 50},
    description="an elastic boulder from an STL hitting a ramp from an OBJ, both in mm",
    solid={"hourglass": 1.0}, materials={"granite": hencky(2700.0, 2.0e6)},
    bodies=[_mesh("boulder", "boulder.stl", material="granite", scale=0.001,
                  rotate=[0.0, 20.0, 0.0], translate=[0.3, 0.2, 0.32], velocity=[0.0, 0.0, -2.0])],
    walls=[_mesh("ramp", "ramp.obj", scale=0.001, fill="inside")])


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

    rock = trimesh.creation.icosphere(subdivisions=2, radius=100.0)
    rock.apply_scale((1.0, 0.8, 0.7))
    tmp = _shared(comm, mpi_tmp_path, {"boulder.stl": rock, "ramp.obj": _ramp_mm()})
    scene = on_root(comm, load_scene, write_shared(comm, str(tmp), BOULDER, "boulder.toml"))
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
