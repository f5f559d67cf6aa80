"""The README's tutorial (docs/tutorial/) and the annotated scene of docs/scenes.md work
as written: make_slope.py writes the height map the scene reads, the scene loads and
`parsph check` reports the particles the README says, its first steps run with finite
energy and paraview_phase.py draws them, on 1 and 2 ranks."""
import importlib.util
import os
import re
import shutil

import numpy as np
import pytest

from parsph.cli.check import check
from parsph.io import read_stats
from parsph.scene.geometry import estimate_count
from parsph.scene.heightmap import read_grid
from parsph.scene.loader import load_scene
from parsph.step.run import run
from tests.scenes import assert_energy_balance, pvbatch, stats_rows

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TUTORIAL = os.path.join(ROOT, "docs", "tutorial")
SCENE = os.path.join(TUTORIAL, "my_slope.toml")
PVBATCH = shutil.which("pvbatch")


def _make_slope():
    spec = importlib.util.spec_from_file_location("make_slope",
                                                  os.path.join(TUTORIAL, "make_slope.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_make_slope_writes_the_grid_the_scene_reads(comm, mpi_tmp_path):
    """make_slope.py writes the shipped slope.asc byte for byte, and that is the grid the
    scene's heightmap body reads: a 1 m slope, flat ground at x <= 0.4 m."""
    path = os.path.join(mpi_tmp_path, f"slope_{comm.rank}.asc")
    _make_slope().main(path)
    with open(path) as fh, open(os.path.join(TUTORIAL, "slope.asc")) as shipped:
        assert fh.read() == shipped.read()
    scene = load_scene(SCENE)
    (body,) = scene.bodies
    assert body.shape == "heightmap" and body.top == "slope.asc"
    read, written = scene.data[body.top], read_grid(path)
    assert (read.x0, read.y0, read.cell) == (written.x0, written.y0, written.cell)
    assert np.array_equal(read.z, written.z)
    assert read.z.min() == 0.0 and read.z.max() == 1.0
    (x0, x1), (y0, y1) = read.extent
    assert (x0, x1) == (0.0, 2.2) and (y0, y1) == (0.0, 0.5)  # y: the periodic width
    assert (scene.domain.lo[1], scene.domain.hi[1]) == (y0, y1)


def test_tutorial_scene_loads_and_checks_with_the_particles_the_readme_says(comm):
    scene = load_scene(SCENE)
    assert scene.domain.dim == 3 and scene.domain.periodic == (False, True, False)
    assert scene.phase_change.eps_p_limit == 0.5 and scene.phase_change.fluid == "debris"
    assert estimate_count(scene) == 1565  # docs/tutorial/README.md, README.md
    report = check(comm, scene)  # `parsph check docs/tutorial/my_slope.toml`
    if comm.rank == 0:
        assert "particles: 1565 (solid 755, fluid 0, wall 810)" in report, report
        assert re.search(r"^  coupled ", report, re.M), report
        assert "warning" not in report, report
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as fh:
        readme = re.sub(r"<!--.*?-->", "", fh.read())  # as rendered (docs/figures.md)
    assert "1,565 particles" in readme and "docs/tutorial/my_slope.toml" in readme


def test_tutorial_scene_steps_on_this_session_s_ranks(comm, mpi_tmp_path):
    """A few steps of the slope: the soil starts to move under gravity, every particle
    stays, the energy is finite and the energy balance rises by at most 1e-3 of the peak
    kinetic energy in a step and 2e-3 over any stretch (measured on 1 and 2 ranks:
    2.8e-4 and 5.5e-4)."""
    out = os.path.join(mpi_tmp_path, "out")
    summary = run(load_scene(SCENE, ["run.end_time=0.03"]), out, comm=comm, progress=False)
    assert summary["particles"] == 1565 and summary["steps"] > 10
    if comm.rank == 0:
        stats = read_stats(os.path.join(out, "stats.csv"))
        assert np.all(np.isfinite(stats["kinetic_energy"]))
        assert np.all(np.isfinite(stats["elastic_energy"]))
        assert stats["kinetic_energy"][-1] > 0.0
        rows = stats_rows(out)
        assert_energy_balance(rows, 1e-3, 2e-3, "tutorial")
        assert np.all(stats["n_particles"] == 1565)


@pytest.mark.skipif(PVBATCH is None, reason="pvbatch not found: install Debian's paraview, "
                    "python3-paraview and xvfb (scripts/setup.sh does)")
def test_paraview_phase_script_draws_the_run(comm, mpi_tmp_path):
    """`xvfb-run -a pvbatch docs/tutorial/paraview_phase.py RUN_DIR` saves its PNG with
    the particles drawn (rank 0 runs it, outside the test's MPI job)."""
    out = os.path.join(mpi_tmp_path, "out")
    run(load_scene(SCENE, ["run.end_time=0.005"]), out, comm=comm, progress=False)
    comm.Barrier()
    if comm.rank != 0:
        return
    r = pvbatch(os.path.join(TUTORIAL, "paraview_phase.py"), out)
    assert r.returncode == 0, r.stdout + r.stderr
    import matplotlib.image

    image = matplotlib.image.imread(os.path.join(out, "plots", "paraview_phase.png"))
    assert image.shape[:2] == (640, 1600)
    rgb = image[:, 800:, :3]  # the right half: the slope, not the phase legend
    brown = (np.abs(rgb - [0.63, 0.32, 0.18]) < 0.05).all(axis=2)  # solid particles
    grey = (np.abs(rgb - [0.60, 0.60, 0.60]) < 0.05).all(axis=2)  # wall particles
    assert brown.mean() > 0.002 and grey.mean() > 0.002, (brown.mean(), grey.mean())


def test_annotated_scene_of_the_key_reference_loads(mpi_tmp_path, comm):
    """The annotated example at the top of docs/scenes.md is a valid scene."""
    from parsph.scene.scenedoc import EXAMPLE

    text = re.search(r"```toml\n(.*?)```", EXAMPLE, re.S).group(1)
    path = os.path.join(mpi_tmp_path, f"example_{comm.rank}.toml")
    with open(path, "w") as fh:
        fh.write(text)
    scene = load_scene(path)
    assert scene.scene.name == "hydrostatic" and estimate_count(scene) > 0
