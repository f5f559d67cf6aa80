"""``parsph plot DIR --series``: stats.csv (and probes.csv) over time in one PNG.

A short dam break is run on the session's ranks (1 or 2), ``parsph plot --series`` draws
it on rank 0, and the lines read back from the figure must be the columns of
stats.csv; a synthetic probes.csv (a gauge and a line probe, rows shuffled) adds panels
whose lines must be its values.
"""
import os
import struct
import warnings

import numpy as np
import pytest

from parsph.errors import ParsphError


def _png_size(path):
    """(width, height) in pixels of a PNG, after checking its signature and IHDR chunk."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", path
    return struct.unpack(">II", head[16:24])


@pytest.fixture
def short_run(comm, mpi_tmp_path):
    from parsph.step.run import run
    from parsph.scene.loader import load_scene

    scene = load_scene("dam_break", ["domain.particle_size=0.02", "run.end_time=0.02",
                                     "output.every=0.01"])
    out = os.path.join(mpi_tmp_path, "run")
    os.makedirs(out, exist_ok=True)
    run(scene, out, comm=comm, progress=False)
    comm.Barrier()
    return out


def test_series_of_a_run_match_stats(comm, short_run, capsys):
    from parsph.cli.main import main
    from parsph.io.series import plot_series
    from parsph.io.stats import read_stats

    assert main(["plot", short_run, "--series"]) == 0
    comm.Barrier()
    if comm.rank != 0:
        return
    printed = capsys.readouterr().out.split()
    png = os.path.join(short_run, "plots", "series.png")
    assert printed == [png]  # --series alone draws no frame
    width, height = _png_size(png)
    assert 600 <= width <= 2000 and 600 <= height <= 4000, (width, height)
    import matplotlib.image

    assert matplotlib.image.imread(png).shape[:2] == (height, width)

    stats = read_stats(os.path.join(short_run, "stats.csv"))
    _, lines = plot_series(short_run, os.path.join(short_run, "again.png"), dpi=50)
    expected = {"energy (J)/kinetic": "kinetic_energy", "front (m)/run-out front": "front",
                "max speed (m/s)/max |v|": "max_speed", "Krylov iterations/PPE": "ppe_iterations",
                "Krylov iterations/viscous": "visc_iterations", "time step (s)/dt": "dt"}
    assert set(lines) == set(expected)  # a fluid-only run: no elastic energy, no fluidised volume
    assert len(stats["time"]) >= 4
    for key, column in expected.items():
        x, y = lines[key]
        assert np.array_equal(x, stats["time"]), key
        assert np.array_equal(y, stats[column]), key


def _write(path, text):
    with open(path, "w") as fh:
        fh.write(text)


def test_series_panels_of_probes_and_coupled_columns(comm, mpi_tmp_path):
    if comm.rank != 0:
        return
    from parsph.io.series import plot_series

    run = os.path.join(mpi_tmp_path, "synthetic")
    os.makedirs(run)
    t = np.linspace(0.0, 1.0, 11)
    rows = ["step,time,dt,kinetic_energy,elastic_energy,fluidised_volume,front,ppe_iterations"]
    for k, tk in enumerate(t):
        rows.append(f"{k},{tk!r},0.1,{tk ** 2!r},{1 - tk!r},{0.5 * tk!r},{1 + tk!r},")
    _write(os.path.join(run, "stats.csv"), "\n".join(rows) + "\n")
    rng = np.random.default_rng(3)
    probe_rows = []
    for k, tk in enumerate(t):
        probe_rows.append((tk, "gauge", 0, "p", 1000.0 * tk))
        probe_rows.append((tk, "gauge", 0, "v_x", -tk if k else float("nan")))  # dry at t = 0
        probe_rows.append((tk, "gauge", 0, "v_y", 0.5 * tk))  # shares v_x's panel
        probe_rows.append((tk, "gauge", 0, "sigma_xy", 5.0 * tk))
        for j in range(10):  # a line of 10 stations, none reached at t = 0
            probe_rows.append((tk, "deposit", j, "depth", 0.01 * j * tk if k else float("nan")))
    order = rng.permutation(len(probe_rows))
    _write(os.path.join(run, "probes.csv"), "time,probe,point,field,value\n" + "".join(
        f"{probe_rows[i][0]!r},{probe_rows[i][1]},{probe_rows[i][2]},{probe_rows[i][3]},"
        f"{probe_rows[i][4]!r}\n" for i in order))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # NaN samples draw gaps, not warnings
        png, lines = plot_series(run, dpi=40)
    assert png == os.path.join(run, "plots", "series.png") and _png_size(png)[1] > 200
    # the empty ppe_iterations column draws no panel; elastic energy joins kinetic
    assert set(lines) == {"energy (J)/kinetic", "energy (J)/elastic", "front (m)/run-out front",
                          "fluidised volume/fluidised", "time step (s)/dt",
                          "probe gauge: p (Pa)/p", "probe gauge: v (m/s)/v_x",
                          "probe gauge: v (m/s)/v_y", "probe gauge: sigma_xy (Pa)/sigma_xy",
                          "probe deposit: depth (m)/mean of 10 points"}
    assert np.array_equal(lines["fluidised volume/fluidised"][1], 0.5 * t)
    assert np.array_equal(lines["energy (J)/elastic"][1], 1 - t)
    x, y = lines["probe gauge: p (Pa)/p"]
    assert np.array_equal(x, t) and np.array_equal(y, 1000.0 * t)  # sorted by time
    x, y = lines["probe gauge: v (m/s)/v_x"]
    assert np.isnan(y[0]) and np.array_equal(y[1:], -t[1:])
    assert np.array_equal(lines["probe gauge: v (m/s)/v_y"][1], 0.5 * t)
    x, y = lines["probe deposit: depth (m)/mean of 10 points"]
    assert np.array_equal(x, t) and np.isnan(y[0])
    assert np.allclose(y[1:], 0.045 * t[1:], rtol=1e-12, atol=0)


def test_series_bad_input_names_the_file(comm, mpi_tmp_path):
    if comm.rank != 0:
        return
    from parsph.io.series import plot_series

    run = os.path.join(mpi_tmp_path, "bad")
    os.makedirs(run)
    with pytest.raises(ParsphError, match="stats.csv: no such file"):
        plot_series(run)
    _write(os.path.join(run, "stats.csv"), "step,time,dt\n")
    with pytest.raises(ParsphError, match="holds no step yet"):
        plot_series(run)
    _write(os.path.join(run, "stats.csv"), "step,time,dt\n1,0.1,0.1\n")
    _write(os.path.join(run, "probes.csv"), "time,probe,field,value\n0.1,g,p,1\n")
    with pytest.raises(ParsphError, match=r"probes.csv: columns \['point'\] missing"):
        plot_series(run)
    _write(os.path.join(run, "probes.csv"), "time,probe,point,field,value\n0.1,g,0,p,high\n")
    with pytest.raises(ParsphError, match="probes.csv, line 2"):
        plot_series(run)
