"""parsph study: the sweep, its table and plot, the Pareto front and the order."""
import csv
import os

import numpy as np
import pytest

from parsph.errors import ParsphError
from parsph.cli.study import convergence_order, pareto, parse_vary, study
from tests.scenes import MOVING_2D, write_shared


def test_pareto_and_order():
    wall = np.array([1.0, 2.0, 3.0, 2.5])
    err = np.array([0.1, 0.05, 0.01, 0.2])
    assert pareto(wall, err).tolist() == [True, True, True, False]
    d = np.array([0.04, 0.02, 0.01])
    assert convergence_order(d, 3.0 * d ** 2) == pytest.approx(2.0)
    assert np.isnan(convergence_order([0.1, 0.1], [1.0, 2.0]))


def test_parse_vary_errors():
    assert parse_vary(["particle_size=0.1,0.05"]) == {"particle_size": [0.1, 0.05]}
    for bad in ("particle_size", "cfl=a,b", "cfl=-1", "cfl="):
        with pytest.raises(ParsphError, match="--vary"):
            parse_vary([bad])


def test_study_writes_table_and_plot(comm, mpi_tmp_path):
    path = write_shared(comm, mpi_tmp_path, MOVING_2D)
    out = os.path.join(mpi_tmp_path, "study")
    rows = study(comm, path, out, {"particle_size": [0.1, 0.05], "cfl": [0.5, 0.25]},
                 overrides=["run.end_time=0.2", "output.every=0.1"])
    assert len(rows) == 4
    assert {r["ranks"] for r in rows} == {comm.size}
    assert all(r["error"] < 1e-9 for r in rows)  # kinematic reference: exact motion
    steps = {(r["particle_size"], r["cfl"]): r["steps"] for r in rows}
    assert steps[(0.05, 0.25)] > steps[(0.05, 0.5)] > steps[(0.1, 0.5)]  # cfl really varied
    if comm.rank == 0:
        with open(os.path.join(out, "study.csv")) as fh:
            table = list(csv.DictReader(fh))
        assert list(table[0]) == ["particle_size", "cfl", "ksp_rtol", "ranks", "steps",
                                  "wall_s", "error"]
        assert os.path.getsize(os.path.join(out, "study.png")) > 1000
    with pytest.raises(ParsphError, match="no setting 'ksp_rtol'"):
        study(comm, path, out, {"ksp_rtol": [1e-6]})
    with pytest.raises(ParsphError, match="no reference"):
        study(comm, path, out, {"particle_size": [0.1]}, overrides=["run.mode=geometry"])


def test_study_of_a_dotted_key_gives_it_a_column(comm, mpi_tmp_path):
    """--vary of any dotted scene key (fluid.ppe_density_error, ...): study.csv, the
    table and the plot's labels name its value, after ksp_rtol."""
    from parsph.cli.study import point_labels

    path = write_shared(comm, mpi_tmp_path, MOVING_2D)
    out = os.path.join(mpi_tmp_path, "study_key")
    rows = study(comm, path, out, {"output.every": [0.1, 0.05]},
                 overrides=["run.end_time=0.2", "domain.particle_size=0.1"])
    assert [r["output.every"] for r in rows] == [0.1, 0.05]
    assert point_labels(rows) == ["every=0.1", "every=0.05"]
    if comm.rank == 0:
        with open(os.path.join(out, "study.csv")) as fh:
            table = list(csv.DictReader(fh))
        assert list(table[0])[:4] == ["particle_size", "cfl", "ksp_rtol", "output.every"]
        assert [float(r["output.every"]) for r in table] == [0.1, 0.05]


def test_plot_labels_name_the_settings_that_vary():
    """study.png labels each point with what the study varied, not always d."""
    from parsph.cli.study import point_labels

    nan = float("nan")
    by_d = [dict(particle_size=d, cfl=nan, ksp_rtol=nan) for d in (0.1, 0.05)]
    assert point_labels(by_d) == ["d=0.1", "d=0.05"]
    by_cfl = [dict(particle_size=0.01, cfl=c, ksp_rtol=1e-8) for c in (0.1, 0.4)]
    assert point_labels(by_cfl) == ["cfl=0.1", "cfl=0.4"]
    both = [dict(particle_size=d, cfl=0.1, ksp_rtol=r) for d, r in ((0.1, 1e-4), (0.05, 1e-8))]
    assert point_labels(both) == ["d=0.1, rtol=0.0001", "d=0.05, rtol=1e-08"]


def test_study_without_vary_runs_the_scenes_default_sweep(comm, mpi_tmp_path, capsys):
    """``parsph study hydrostatic --out DIR``: the three sizes the scene declares."""
    from parsph.cli.main import main
    from parsph.scene.loader import load_scene

    out = os.path.join(mpi_tmp_path, "default")
    assert main(["study", "hydrostatic", "--out", out, "--set", "run.end_time=0.01",
                 "--set", "output.every=0.01"]) == 0
    comm.Barrier()
    if comm.rank != 0:
        return
    sizes = list(load_scene("hydrostatic").study.particle_sizes)
    assert len(sizes) == 3
    with open(os.path.join(out, "study.csv")) as fh:
        table = list(csv.DictReader(fh))
    assert [float(r["particle_size"]) for r in table] == sizes
    errors = [float(r["error"]) for r in table]
    assert all(np.isfinite(errors)) and errors[0] > errors[-1]  # finer is closer to rho g (H - y)
    assert "observed order of convergence" in capsys.readouterr().out


def test_study_default_sweep_of_a_users_scene(comm, mpi_tmp_path):
    """A scene of one's own: refused without a declaration (naming --vary and the key),
    its declared sweep run with one, --vary still overriding it."""
    path = write_shared(comm, mpi_tmp_path, MOVING_2D)
    out = os.path.join(mpi_tmp_path, "mine")
    short = ["run.end_time=0.1", "output.every=0.1"]
    with pytest.raises(ParsphError, match=r"declares no default sweep; give --vary .*"
                       r"\[study\] particle_sizes"):
        study(comm, path, out, {}, overrides=short)
    assert not os.path.exists(os.path.join(out, "runs"))  # refused before any run
    declared = short + ["study.particle_sizes=[0.1, 0.05]"]
    rows = study(comm, path, out, None, overrides=declared)
    assert [r["particle_size"] for r in rows] == [0.1, 0.05]
    rows = study(comm, path, out, {"particle_size": [0.2]}, overrides=declared)
    assert [r["particle_size"] for r in rows] == [0.2]


def test_every_builtin_scene_declares_its_sweep():
    """Every built-in scene has a sweep of three or more sizes, coarse to fine, and each
    size meets the scene's geometry: its boxes and periods (``geometry_warnings``) and the
    extents of its polygons as filled (``fill_warnings``; the slope's 1 m stood 1.015 m
    tall at d = 0.035 m, and the 3D slab's 0.25 m period left a 0.05 m seam at 0.04 m)."""
    from mpi4py import MPI

    from parsph.scene.geometry import body_fill, fill_warnings, generate, geometry_warnings
    from parsph.scene.loader import builtin_names, load_scene

    for name in builtin_names():
        sizes = load_scene(name).study.particle_sizes
        assert len(sizes) >= 3, name  # Richardson needs three (slope_failure has four)
        assert list(sizes) == sorted(sizes, reverse=True), name  # coarse to fine
        for d in sizes:  # each size fits the scene's geometry
            scn = load_scene(name, [f"domain.particle_size={d!r}"])
            assert geometry_warnings(scn) == [], (name, d)
            if any(b.shape in ("polygon", "extruded_polygon") for b in scn.bodies):
                fills = body_fill(MPI.COMM_SELF, scn, generate(MPI.COMM_SELF, scn))
                assert fill_warnings(scn, fills) == [], (name, d)


@pytest.mark.parametrize("sizes, match", [("[0.01, 0.02]", "coarse to fine"),
                                          ("[0.01]", "two or more"),
                                          ("[0.02, -0.01]", r"study.particle_sizes\[1\]")])
def test_bad_sweep_names_the_key(sizes, match):
    from parsph.errors import SceneError
    from parsph.scene.loader import load_scene

    with pytest.raises(SceneError, match=match) as info:
        load_scene("hydrostatic", [f"study.particle_sizes={sizes}"])
    assert "study.particle_sizes" in str(info.value)


def test_slope_scatter_job_measures_and_resumes(comm, mpi_tmp_path, capsys):
    """jobs/slope_scatter.py (docs/slope.md): the scene as it is and one run per perturbed
    value at each size, the landslide's quantities of each and their largest deviation
    from the mean; a second call measures the finished runs without running them again;
    a malformed --perturb is refused before any run."""
    from jobs import slope_scatter

    out = os.path.join(mpi_tmp_path, "scatter")
    args = ["--d", "0.1", "--perturb", "solid.cfl=0.45", "--set", "run.end_time=0.3",
            "--out", out]
    assert slope_scatter.main(args) == 0
    base = os.path.join(out, "d0.1", "base", "stats.csv")
    assert os.path.exists(os.path.join(out, "d0.1", "solid.cfl=0.45", "stats.csv"))
    first = capsys.readouterr().out
    stamp = os.path.getmtime(base)
    assert slope_scatter.main(args) == 0
    assert os.path.getmtime(base) == stamp  # measured, not run again
    if comm.rank == 0:
        line = [s for s in first.splitlines() if s.startswith("figures slope_failure_scatter")]
        assert line and "runs = ['base', 'solid.cfl=0.45']" in line[0]
        runout = [s for s in first.splitlines() if s.startswith("d = 0.1 m: runout_m mean")]
        assert runout and "over 2 runs" in runout[0]
    with pytest.raises(SystemExit, match="--perturb 'solid.cfl'"):
        slope_scatter.main(["--perturb", "solid.cfl", "--out", out])
