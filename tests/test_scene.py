"""Scene loading: validation into frozen dataclasses and one clear message per mistake."""
import dataclasses

import pytest

from parsph.errors import SceneError
from parsph.scene.loader import builtin_names, load_scene
from tests.scenes import MOVING_2D, MOVING_3D, box, hencky, toml_text, write


def test_builtin_scenes_load():
    assert "hydrostatic" in builtin_names()
    for name in builtin_names():
        scn = load_scene(name)
        assert scn.name == name
        assert scn.domain.dim in (2, 3)
        assert scn.scene.description


def test_scene_is_frozen_and_defaults_filled(tmp_path):
    scn = load_scene(write(tmp_path, MOVING_2D))
    with pytest.raises(dataclasses.FrozenInstanceError):
        scn.domain.dim = 3
    assert scn.domain.periodic == (True, False)
    assert scn.gravity.g == (0.0, -9.81)
    assert scn.bodies[1].vertices[3] == (1.2, 0.4)
    assert load_scene(write(tmp_path, MOVING_3D)).gravity.g == (0.0, 0.0, -9.81)


def test_overrides(tmp_path):
    path = write(tmp_path, MOVING_2D)
    scn = load_scene(path, ["domain.particle_size=0.1", "bodies.0.velocity=[1, 2]",
                            "run.mode=geometry", "output.progress=true"])
    assert scn.domain.particle_size == 0.1
    assert scn.bodies[0].velocity == (1.0, 2.0)
    assert scn.run.mode == "geometry"


BAD = [
    # (edit to the scene text or --set override, words the message must contain)
    ({"set": "domain.particle_size=-1"}, ["domain.particle_size", "> 0.0"]),
    ({"set": "domain.particle_size=0"}, ["domain.particle_size", "> 0.0"]),
    ({"set": "domain.particle_size=nan"}, ["domain.particle_size", "finite"]),
    ({"set": "domain.particle_size=inf"}, ["domain.particle_size", "finite"]),
    ({"set": "domain.particle_size=abc"}, ["domain.particle_size", "number", "abc"]),
    ({"set": "domain.dim=4"}, ["domain.dim", "<= 3"]),
    ({"set": "domain.dim=2.5"}, ["domain.dim", "whole number"]),
    ({"set": "domain.dim=true"}, ["domain.dim", "whole number"]),
    ({"set": "domain.colour=1"}, ["domain.colour", "unknown key", "particle_size"]),
    ({"set": "run.mode=fast"}, ["run.mode", "physics"]),
    ({"set": "run.end_time=0"}, ["run.end_time", "> 0.0"]),
    ({"set": "output.every=-0.1"}, ["output.every"]),
    ({"set": "domain.lo=[0, 0, 0]"}, ["domain.lo", "2 numbers"]),
    ({"set": "domain.hi=[-1, 1]"}, ["domain.hi", "above"]),
    ({"set": "bodies.0.material=mud"}, ["bodies[0].material", "mud", "sand"]),
    ({"set": "bodies.0.shape=sphere"}, ["bodies[0].shape", "box"]),
    ({"set": "bodies.0.hi=[9, 0.5]"}, ["bodies[0]", "not inside the domain"]),
    ({"set": "bodies.1.vertices=[[0, 0], [1, 1]]"}, ["bodies[1].vertices", "at least 3"]),
    ({"set": "bodies.1.vertices=[[1.0, 0.0], [1.9, -0.3], [1.9, 0.6]]"},
     ["bodies[1].vertices", "-0.3..0.6", "along axis 1", "not inside the domain"]),
    ({"set": "bodies.5.lo=[0, 0]"}, ["bodies.5", "index"]),
    ({"set": "walls.0.name=left"}, ["walls[0].name", "duplicate"]),
    ({"set": "materials.sand.model=gel"}, ["materials.sand.model", "gel", "kinematic"]),
    ({"set": "materials.sand.density=-5"}, ["materials.sand.density", "> 0.0"]),
    ({"set": "materials.sand.stiffness=5"}, ["materials.sand.stiffness", "unknown key"]),
    ({"set": "gravity.g=[0, -9.81, 0]"}, ["gravity.g", "2 numbers"]),
    ({"set": "novalue"}, ["--set", "dotted.key=value"]),
    ({"text": "", }, ["empty"]),
    ({"text": "[scene\nname = 1"}, ["not valid TOML"]),
    ({"text": "[scene]\nname = 'x'\n"}, ["[domain]", "missing"]),
    ({"drop": "particle_size = 0.05\n"}, ["domain.particle_size", "missing"]),
]


@pytest.mark.parametrize("edit,words", BAD, ids=[str(i) for i in range(len(BAD))])
def test_bad_scene_gives_one_clear_message(tmp_path, edit, words):
    text = MOVING_2D
    overrides = []
    if "set" in edit:
        overrides = [edit["set"]]
    if "text" in edit:
        text = edit["text"]
    if "drop" in edit:
        text = text.replace(edit["drop"], "")
    path = write(tmp_path, text)
    with pytest.raises(SceneError) as info:
        load_scene(path, overrides)
    message = str(info.value)
    for word in words:
        assert word in message, message
    assert "\n" not in message.strip()


def test_a_frame_interval_longer_than_the_run_is_fine(tmp_path):
    """The run then writes frame 0 and its last state (tests/test_output_schedule.py)."""
    scn = load_scene(write(tmp_path, MOVING_2D), ["output.every=5"])
    assert scn.output.every > scn.run.end_time


def test_unknown_scene_and_missing_file():
    with pytest.raises(SceneError, match="unknown scene 'nope'.*hydrostatic"):
        load_scene("nope")
    with pytest.raises(SceneError, match="does not exist"):
        load_scene("missing/scene.toml")


def test_an_extruded_polygon_outside_the_domain_is_refused(tmp_path):
    """Its particles would start outside the domain: refused when the scene loads, with
    the key and the span, not at the run's first step."""
    path = write(tmp_path, MOVING_3D)
    with pytest.raises(SceneError, match=r"bodies\[0\]\.vertices.*spans -0\.6\.\.0\.6 m along "
                       r"axis 2.*-0\.4\.\.1"):
        load_scene(path, ["bodies.0.vertices=[[0.0, -0.6], [1.2, 0.0], [0.0, 0.6]]"])
    with pytest.raises(SceneError, match=r"bodies\[0\]\.extent.*along y"):
        load_scene(path, ["bodies.0.extent=[0.0, 1.5]"])


def test_heightmap_errors(tmp_path):
    text = MOVING_3D.replace('shape = "extruded_polygon"', 'shape = "heightmap"\ntop = "z.asc"\nbottom = 0.0')
    with pytest.raises(SceneError, match="z.asc"):
        load_scene(write(tmp_path, text))
    (tmp_path / "z.asc").write_text("ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 0.5\n"
                                    "0.5 0.6 nan\n0.4 0.5 0.6\n")
    with pytest.raises(SceneError, match="NaN"):
        load_scene(write(tmp_path, text))
    (tmp_path / "z.asc").write_text("ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 0.5\n"
                                    "0.5 0.6 0.7\n0.4 0.5 0.6\n")
    with pytest.raises(SceneError, match="3 rows, found 2"):
        load_scene(write(tmp_path, text))


def test_scene_key_reference_is_current():
    import os

    from parsph.scene.scenedoc import markdown

    path = os.path.join(os.path.dirname(__file__), "..", "docs", "scenes.md")
    with open(path) as fh:
        assert fh.read() == markdown(), "regenerate: python -m parsph.scene.scenedoc > docs/scenes.md"


def test_scene_with_solid_and_fluid_is_coupled(tmp_path):
    """Both phases in one scene: the coupled stage in the mixed layout, periodic axes
    too; a bad [phase_change] is refused with the key named."""
    from parsph.step.pipeline import layout, plan
    from parsph.scene.loader import builtin_path

    text = open(builtin_path("hydrostatic")).read() + toml_text(
        materials={"soil": hencky(2000.0, 1.0e6)},
        bodies=[box("block", "soil", [0.4, 1.0], [0.6, 1.1])])
    scene = load_scene(write(tmp_path, text))
    specs = plan(scene)
    assert [s.name for s in specs] == ["coupled"] and layout(specs) == "mixed"
    # periodic axes are allowed in coupled scenes (test_coupling.py: the periodic twin)
    periodic = load_scene(write(tmp_path, text + '\n[phase_change]\neps_p_limit = 0.5\n'
                                'fluid = "water"\n'), ["domain.periodic=[true, false]"])
    assert periodic.domain.periodic == (True, False)
    assert [s.name for s in plan(periodic)] == ["coupled"]
    with pytest.raises(SceneError, match="phase_change.fluid.*no material"):
        load_scene(write(tmp_path, text + '\n[phase_change]\neps_p_limit = 0.5\nfluid = "mud"\n'))
    with pytest.raises(SceneError, match="phase_change.fluid.*not a fluid"):
        load_scene(write(tmp_path, text + '\n[phase_change]\neps_p_limit = 0.5\nfluid = "soil"\n'))
    with pytest.raises(SceneError, match="phase_change.eps_p_limit"):
        load_scene(write(tmp_path, text), ["phase_change.eps_p_limit=-1"])
    with pytest.raises(SceneError, match="output.front_direction"):
        load_scene(write(tmp_path, text), ["output.front_direction=[0.0, 0.0]"])


def test_geometry_warnings_name_thin_walls_and_misfit_bodies():
    """A wall thinner than 2h and a box body that is not a whole number of particles get
    a warning naming them and the fix; the built-in scenes get none."""
    from parsph.scene.geometry import geometry_warnings

    for name in builtin_names():
        assert geometry_warnings(load_scene(name)) == [], name
    coarse = geometry_warnings(load_scene("slope_failure", ["domain.particle_size=0.1"]))
    assert len(coarse) == 2 and all("thick" in w and "0.24 m" in w for w in coarse)
    assert "'floor'" in coarse[0] and "'back'" in coarse[1]
    misfit = geometry_warnings(load_scene("hydrostatic", ["domain.particle_size=0.0667"]))
    assert len(misfit) == 2  # both axes of the 1 m water column
    assert all("'water'" in w and "0.0662 m empty" in w for w in misfit)
    assert geometry_warnings(load_scene("hydrostatic", ["domain.particle_size=0.0625"])) == []
