"""Probes (docs/probes.md): the sums against a brute-force evaluation on any rank count,
a hydrostatic column through a pressure line, 1 vs 2 ranks, restart, bad input."""
import math
import os

import numpy as np
import pytest

from decomposition.box import Box
from parsph.errors import SceneError
from parsph.io import read_frame, read_frames
from parsph.io.probes import read_probes
from parsph.core.kernel import smoothing_length, w_array
from parsph.core.particles import ParticleSet
from parsph.step.probes import Sampler, projected_w_array
from parsph.step.run import run
from parsph.scene.loader import load_scene
from tests.scenes import (MOVING_2D, box, by_id, load_shared, run_on_one_and_two, scene_text,
                          toml_text, wall, write, write_shared)

# --------------------------------------------------------------------------- the sums


def _vertical_integral(rho, h, dim):
    """int W(sqrt(rho^2 + z^2)) dz by a fine midpoint rule (independent of the code's)."""
    n = 20000
    z = (np.arange(n) + 0.5) * (2.0 * h / n)
    return 2.0 * w_array(np.sqrt(rho ** 2 + z ** 2), h, dim).sum() * (2.0 * h / n)


@pytest.mark.parametrize("dim", [2, 3])
def test_projected_kernel(dim):
    """W_hat is the vertical integral of W and integrates to 1 over the horizontal."""
    h = 0.3
    rho = np.linspace(0.0, 2.0 * h, 13)
    got = projected_w_array(rho, h, dim)
    want = np.array([_vertical_integral(r, h, dim) for r in rho])
    assert np.allclose(got, want, rtol=1e-6, atol=1e-9 / h ** (dim - 1))
    r = (np.arange(4000) + 0.5) * (2.0 * h / 4000)
    area = 2.0 if dim == 2 else 2.0 * math.pi * r  # dA per d rho: both sides / a ring
    assert (projected_w_array(r, h, dim) * area).sum() * (2.0 * h / 4000) == \
        pytest.approx(1.0, abs=1e-6)


LAYER = scene_text(
    "layer", 0.1, [0.0, -0.3], [2.0, 1.0], 0.1, periodic=[True, False],
    run={"mode": "kinematic"}, materials={"mud": {"model": "kinematic", "density": 1500.0}},
    bodies=[box("layer", "mud", [0.0, 0.0], [2.0, 0.6])],
    walls=[wall("floor", [0.0, -0.3], [2.0, 0.0])],
    probes=[{"name": "line", "type": "line", "start": [0.0, 0.05], "end": [1.93, 0.77],
             "points": 9, "fields": ["p", "v", "speed", "rho", "volume_fraction",
                                     "fluid_fraction", "solid_fraction"],
             "phases": ["fluid", "solid", "wall"]},
            {"name": "thickness", "type": "line", "start": [0.03, 0.0], "end": [1.97, 0.0],
             "points": 5, "measure": "depth", "fields": ["depth", "v", "p"]},
            {"name": "box", "type": "box", "lo": [0.35, 0.12], "hi": [1.21, 0.9]}])


def _layer_particles(comm, scene):
    """The layer and floor on a lattice with linear p and v; rank r owns rows r::size
    (any split will do: every owned row counts once)."""
    d = scene.domain.particle_size
    xs = (np.arange(20) + 0.5) * d
    layer = np.array([(x, (k + 0.5) * d) for x in xs for k in range(6)])
    floor = np.array([(x, -(k + 0.5) * d) for x in xs for k in range(3)])
    x = np.concatenate([layer, floor])
    n = len(x)
    rng = np.random.default_rng(7)
    phase = np.r_[np.ones(len(layer)), np.full(len(floor), 2)].astype(np.uint8)
    fields = {"id": np.arange(n, dtype=np.int64), "x": x,
              "v": np.c_[0.3 * x[:, 1], -0.1 + rng.normal(0, 0.01, n)],
              "m": np.full(n, 1500.0 * d * d), "phase": phase,
              "material": np.zeros(n, np.int16), "body": np.zeros(n, np.int16)}
    mine = np.arange(comm.rank, n, comm.size)
    p = ParticleSet(2, {k: a[mine] for k, a in fields.items()})
    for name in ("p", "eps_p", "porosity"):
        p.add_field(name)
    p["p"][:] = 1000.0 + 200.0 * p["x"][:, 0] - 5000.0 * p["x"][:, 1]
    return fields, p


def _brute_interpolate(fields, st, d, sel, h, L):
    """Shepard sums at the stations over the selected rows, minimum image along x."""
    dx = st[:, None, :] - fields["x"][None, sel, :]
    dx[..., 0] -= L * np.round(dx[..., 0] / L)
    W = w_array(np.sqrt((dx ** 2).sum(-1)), h, 2) * d * d
    p = 1000.0 + 200.0 * fields["x"][sel, 0] - 5000.0 * fields["x"][sel, 1]
    return W.sum(1), (W * p).sum(1) / W.sum(1), (W @ fields["v"][sel]) / W.sum(1)[:, None]


def test_sums_equal_a_brute_force_evaluation_on_any_rank_count(comm, tmp_path):
    scene = load_scene(write(tmp_path, LAYER))
    d = scene.domain.particle_size
    h = smoothing_length(d)
    fields, particles = _layer_particles(comm, scene)
    box = Box(scene.domain.lo, scene.domain.hi, scene.domain.periodic)
    sampler = Sampler(scene, box, h)
    line, column, boxed = sampler.sample(comm, particles, [0, 1, 2])
    cols = sampler.items[0].columns
    assert cols == ["p", "v_x", "v_y", "speed", "rho", "volume_fraction", "fluid_fraction",
                    "solid_fraction"]
    st = sampler.items[0].stations
    vol, p, v = _brute_interpolate(fields, st, d, np.arange(len(fields["x"])), h, 2.0)
    assert np.allclose(line[:, 0], p, rtol=1e-12)
    assert np.allclose(line[:, 1:3], v, rtol=1e-12, atol=1e-14)
    assert np.allclose(line[:, 5], vol, rtol=1e-12)
    assert np.allclose(line[:, 4], 1500.0 * vol, rtol=1e-12)
    fluid = fields["phase"] == 1
    vol_f, _, _ = _brute_interpolate(fields, st, d, np.flatnonzero(fluid), h, 2.0)
    assert np.allclose(line[:, 6], vol_f / vol, rtol=1e-12)
    assert np.all(line[:, 7] == 0.0)
    # the first station (x = 0) sees the particles across the periodic boundary: a full
    # support, as in the interior (without the image it would get about half)
    assert line[0, 5] == pytest.approx(line[1, 5], rel=2e-3)
    # depth: a 0.6 m layer (walls do not count); the lattice sum of W_hat is 1 to 0.2 %
    assert np.allclose(column[:, 0], 0.6, rtol=2e-3)
    assert np.allclose(column[:, 1], 0.3 * 0.3, rtol=1e-12)  # depth-averaged v_x = 0.3 y
    # box: the fluid rows inside it, summed directly
    x = fields["x"]
    inside = fluid & np.all((x >= [0.35, 0.12]) & (x <= [1.21, 0.9]), axis=1)
    names = sampler.items[2].columns
    got = dict(zip(names, boxed[0]))
    m = fields["m"][inside]
    assert got["count"] == inside.sum() and got["mass"] == pytest.approx(m.sum(), rel=1e-13)
    assert got["volume"] == pytest.approx(inside.sum() * d * d, rel=1e-13)
    assert got["kinetic_energy"] == pytest.approx(
        0.5 * (m * (fields["v"][inside] ** 2).sum(1)).sum(), rel=1e-12)
    assert got["v_y"] == pytest.approx(fields["v"][inside, 1].mean(), rel=1e-12)
    assert "fluidised_volume" not in got  # the scene has no phase change


# --------------------------------------------------------------------------- in a run

PROBES = toml_text(probes=[
    {"name": "column", "type": "line", "start": [0.5, 0.1], "end": [0.5, 0.8], "points": 8,
     "fields": ["p", "v", "rho"], "phases": ["fluid"]},
    {"name": "gauge", "type": "point", "at": [0.5, 0.0], "measure": "depth"},
    {"name": "left", "type": "box", "lo": [0.0, 0.0], "hi": [0.5, 1.2]}])
SHORT = ["domain.particle_size=0.05", "run.end_time=0.1", "output.every=0.05"]


def _hydrostatic(comm, tmp, overrides=SHORT):
    from parsph.scene.loader import builtin_path

    text = None
    if comm.rank == 0:
        with open(builtin_path("hydrostatic")) as fh:
            text = fh.read() + PROBES
    return load_shared(comm, tmp, text, overrides, "hydro.toml")


def _table(out):
    t = read_probes(os.path.join(out, "probes.csv"))
    return {(float(a), str(b), int(c), str(e)): float(v)
            for a, b, c, e, v in zip(t["time"], t["probe"], t["point"], t["field"], t["value"])}


def test_hydrostatic_pressure_line(comm, mpi_tmp_path):
    """p along a vertical line is rho g (H - y) within rho g d: the free-surface row at
    y = H - d/2 carries p = 0, an offset of rho g d / 2 of the whole column, and the
    Shepard interpolation is a convex combination of the particles' values (so adds no
    error beyond theirs for a linear field). The probe is that interpolation of the
    frame taken at the same step; the box's mass is that of the particles inside."""
    scene = _hydrostatic(comm, mpi_tmp_path)
    out = os.path.join(mpi_tmp_path, "out")
    run(scene, out, comm=comm, progress=False)
    if comm.rank != 0:
        return
    table = _table(out)
    times = sorted({k[0] for k in table})
    frames = dict((t, s) for s, t in read_frames(out))
    assert len(times) == 3 and times[0] == 0.0 and set(times) <= set(frames)  # every 0.05 s
    t = times[-1]
    f = by_id(read_frame(out, frames[t]))
    rho_g, d, H = 1000.0 * 9.81, 0.05, 1.0
    y = np.linspace(0.1, 0.8, 8)
    p = np.array([table[(t, "column", k, "p")] for k in range(8)])
    assert np.abs(p - rho_g * (H - y)).max() < rho_g * d
    fluid = f["phase"] == 1
    r = np.hypot(f["x"][fluid, 0][None, :] - 0.5, f["x"][fluid, 1][None, :] - y[:, None])
    W = w_array(r, smoothing_length(d), 2)
    assert np.allclose(p, (W * f["p"][fluid]).sum(1) / W.sum(1), rtol=1e-12)
    inside = fluid & (f["x"][:, 0] <= 0.5)
    assert table[(t, "left", 0, "mass")] == pytest.approx(1000.0 * d * d * inside.sum(),
                                                          rel=1e-13)
    assert table[(t, "left", 0, "count")] == inside.sum() == 200
    assert table[(t, "gauge", 0, "depth")] == pytest.approx(H, rel=2e-3)


@pytest.mark.mpi
def test_probes_agree_on_one_and_two_ranks(comm, mpi_tmp_path):
    """The same run on 1 and 2 ranks: the same rows, values equal to the PPE's tolerance
    (fluid.ppe_rtol = 1e-8; measured 7e-9 of rho g H in p)."""
    scene = _hydrostatic(comm, mpi_tmp_path)
    one, two = run_on_one_and_two(comm, scene, mpi_tmp_path)
    if comm.rank != 0:
        return
    a, b = _table(one), _table(two)
    assert a.keys() == b.keys()
    for field, scale in (("p", 1000.0 * 9.81), ("v_x", 1.0), ("v_y", 1.0), ("rho", 1000.0),
                         ("depth", 1.0), ("mass", 500.0), ("count", 200)):
        keys = [k for k in a if k[3] == field]
        assert keys, field
        assert max(abs(a[k] - b[k]) for k in keys) <= 1e-6 * scale, field


PROBES_2D = toml_text(probes=[
    {"name": "front", "type": "line", "start": [0.2, 0.1], "end": [1.8, 0.1], "points": 5,
     "fields": ["v", "rho"]},
    {"name": "floor", "type": "box", "lo": [0.0, 0.0], "hi": [2.0, 0.3], "every": 0.05}])


def test_restart_continues_probes_without_duplicates(comm, mpi_tmp_path):
    """0 -> 0.2 s, a stale row (a run killed after its checkpoint), restart to 0.4 s: the
    file equals the uninterrupted run's, row for row."""
    path = write_shared(comm, mpi_tmp_path, MOVING_2D + PROBES_2D)
    half, whole = (os.path.join(mpi_tmp_path, n) for n in ("half", "whole"))
    run(load_scene(path, ["run.end_time=0.2"]), half, comm=comm, progress=False)
    if comm.rank == 0:
        with open(os.path.join(half, "probes.csv"), "a") as fh:
            fh.write("0.25,floor,0,mass,1.0\n")
    comm.Barrier()
    run(load_scene(path), half, comm=comm, progress=False,
        restart=os.path.join(half, "checkpoint.h5"))
    run(load_scene(path), whole, comm=comm, progress=False)
    if comm.rank == 0:
        with open(os.path.join(half, "probes.csv")) as fh, \
                open(os.path.join(whole, "probes.csv")) as gh:
            rows_a, rows_b = fh.readlines(), gh.readlines()
        assert rows_a == rows_b
        times = sorted({float(r.split(",")[0]) for r in rows_a[1:] if ",floor," in r})
        assert len(times) == 9 and times[0] == 0.0  # every 0.05 s to 0.4 s


def test_a_branch_starts_its_own_probes(comm, mpi_tmp_path):
    """--restart A/checkpoint.h5 --out B: B's probes.csv starts at the checkpoint's time
    and then equals the uninterrupted run's rows; A's file is left as it was."""
    path = write_shared(comm, mpi_tmp_path, MOVING_2D + PROBES_2D)
    a, b, whole = (os.path.join(mpi_tmp_path, n) for n in ("a", "b", "whole"))
    run(load_scene(path, ["run.end_time=0.2"]), a, comm=comm, progress=False)
    with open(os.path.join(a, "probes.csv")) as fh:
        before = fh.read()
    run(load_scene(path), b, comm=comm, progress=False,
        restart=os.path.join(a, "checkpoint.h5"))
    run(load_scene(path), whole, comm=comm, progress=False)
    if comm.rank == 0:
        with open(os.path.join(a, "probes.csv")) as fh:
            assert fh.read() == before
        with open(os.path.join(b, "probes.csv")) as fh, \
                open(os.path.join(whole, "probes.csv")) as gh:
            rows_b, rows_w = fh.readlines(), gh.readlines()
        assert rows_b[0] == rows_w[0]  # the header
        start = min(float(r.split(",")[0]) for r in rows_b[1:])
        assert start >= 0.2
        assert [r for r in rows_b[1:] if float(r.split(",")[0]) > start] == \
            [r for r in rows_w[1:] if float(r.split(",")[0]) > start]
        assert os.path.exists(os.path.join(b, "probes_points.csv"))


# --------------------------------------------------------------------------- bad input

BAD = [
    ('type = "point"\nat = [5.0, 0.5]', ["probes[0].at", "outside the domain"]),
    ('type = "line"\nstart = [0.1, 0.5]\nend = [2.5, 0.5]\npoints = 4',
     ["probes[0].end", "outside the domain"]),
    ('type = "box"\nlo = [0.1, 0.1]\nhi = [0.5, 1.5]', ["probes[0].hi", "outside the domain"]),
    ('type = "point"\nat = [0.5, 0.5]\nfields = ["p", "presure"]',
     ["probes[0].fields[1]", "unknown field 'presure'", "eps_p"]),
    ('type = "box"\nlo = [0.1, 0.1]\nhi = [0.5, 0.5]\nfields = ["depth"]',
     ["probes[0].fields[0]", "unknown field 'depth'", "kinetic_energy"]),
    ('type = "line"\nstart = [0.1, 0.5]\nend = [0.5, 0.5]\npoints = 1',
     ["probes[0].points", "at least 2"]),
    ('type = "line"\nstart = [0.1, 0.5]\nend = [0.5, 0.5]', ["probes[0].points", "at least 2"]),
    ('type = "box"\nlo = [0.5, 0.1]\nhi = [0.5, 0.5]', ["probes[0].hi", "above"]),
    ('type = "box"\nlo = [0.6, 0.1]\nhi = [0.5, 0.5]', ["probes[0].hi", "above"]),
    ('type = "circle"\nat = [0.5, 0.5]', ["probes[0].type", "'point', 'line', 'box'", "circle"]),
    ('type = "point"\nat = [0.5, 0.5, 0.5]', ["probes[0].at", "2 numbers"]),
    ('type = "point"\nat = [0.5, 0.5]\nlo = [0.0, 0.0]', ["probes[0].lo", "box probes"]),
    ('type = "point"\nat = [0.5, 0.5]\nfields = ["nu"]', ["probes[0].fields[0]", "nu",
                                                         "fluid"]),
    ('type = "point"\nat = [0.5, 0.5]\nphases = ["soil"]', ["probes[0].phases[0]", "soil"]),
    ('type = "box"\nlo = [0.1, 0.1]\nhi = [0.5, 0.5]\nmeasure = "depth"',
     ["probes[0].measure", "point and line"]),
    ('at = [0.5, 0.5]', ["probes[0].type", "missing"]),
]


@pytest.mark.parametrize("body,words", BAD)
def test_bad_probe_gives_one_clear_message(tmp_path, body, words):
    path = write(tmp_path, MOVING_2D + f'\n[[probes]]\nname = "p"\n{body}\n')
    with pytest.raises(SceneError) as err:
        load_scene(path)
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_duplicate_probe_names(tmp_path):
    probe = '\n[[probes]]\nname = "g"\ntype = "point"\nat = [0.5, 0.5]\n'
    with pytest.raises(SceneError, match=r"probes\[1\].name.*duplicate"):
        load_scene(write(tmp_path, MOVING_2D + probe + probe))
