"""The README's tutorial (docs/tutorial/) and the annotated scene of docs/scenes.md work
as written: the height map is what make_slope.py writes, the scenes load, the tutorial's
slope has the particles the README says and its first steps run, on 1 and 2 ranks."""
import importlib.util
import os
import re

import numpy as np

from parsph.io import read_stats
from parsph.scene.geometry import estimate_count
from parsph.scene.loader import load_scene
from parsph.step.run import run

TUTORIAL = os.path.join(os.path.dirname(__file__), "..", "docs", "tutorial")
SCENE = os.path.join(TUTORIAL, "my_slope.toml")


def _make_slope():
    spec = importlib.util.spec_from_file_location("make_slope",
                                                  os.path.join(TUTORIAL, "make_slope.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_make_slope_writes_the_shipped_height_map(comm, mpi_tmp_path):
    path = os.path.join(mpi_tmp_path, f"slope_{comm.rank}.asc")
    _make_slope().main(path)
    with open(path) as fh, open(os.path.join(TUTORIAL, "slope.asc")) as shipped:
        assert fh.read() == shipped.read()


def test_tutorial_scene_has_the_particles_the_readme_says():
    scene = load_scene(SCENE)
    assert scene.domain.dim == 3 and scene.domain.periodic == (False, True, False)
    assert estimate_count(scene) == 1565  # docs/tutorial/README.md, README.md
    with open(os.path.join(os.path.dirname(__file__), "..", "README.md")) as fh:
        readme = fh.read()
    assert "1,565 particles" in readme and "docs/tutorial/my_slope.toml" in readme


def test_tutorial_scene_steps_on_this_session_s_ranks(comm, mpi_tmp_path):
    """A few steps of the slope: the soil starts to move under gravity, every particle
    stays, no step gains more kinetic energy than gravity and the elastic energy
    supply (energy_ratio <= 1)."""
    out = os.path.join(mpi_tmp_path, "out")
    summary = run(load_scene(SCENE, ["run.end_time=0.03"]), out, comm=comm, progress=False)
    assert summary["particles"] == 1565 and summary["steps"] > 10
    if comm.rank == 0:
        stats = read_stats(os.path.join(out, "stats.csv"))
        assert np.all(np.isfinite(stats["kinetic_energy"]))
        assert stats["kinetic_energy"][-1] > 0.0
        assert np.nanmax(stats["energy_ratio"]) <= 1.0


def test_annotated_scene_of_the_key_reference_loads(mpi_tmp_path, comm):
    """The annotated example at the top of docs/scenes.md is a valid scene."""
    from parsph.scene.scenedoc import EXAMPLE

    text = re.search(r"```toml\n(.*?)```", EXAMPLE, re.S).group(1)
    path = os.path.join(mpi_tmp_path, f"example_{comm.rank}.toml")
    with open(path, "w") as fh:
        fh.write(text)
    scene = load_scene(path)
    assert scene.scene.name == "hydrostatic" and estimate_count(scene) > 0
