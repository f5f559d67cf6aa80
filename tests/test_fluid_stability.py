"""IISPH stability: a Bingham fluid with nu_fMAX = 1e4 m^2/s at the CFL step, long runs,
two resolutions of the dam break, no leak through the walls."""
import math
import os

import numpy as np
import pytest

from parsph.io import read_frame, read_frames
from parsph.step.run import run
from parsph.scene.loader import load_scene
from jobs.figures import record
from tests.scenes import LONE_ROW, assert_energy_balance, load_shared, stats_rows
from tests.test_iisph import front_positions


def _run(comm, tmp, name, overrides, sub="out"):
    scene = load_scene(name, ["output.progress=false", *overrides])
    out = os.path.join(tmp, sub)
    run(scene, out, comm=comm, progress=False)
    return scene, out


def _frames(out):
    h5 = os.path.join(out, "particles.h5")
    for step, t in read_frames(h5):
        f = read_frame(h5, step)
        yield t, f


def _inside_tank(f, lo, hi, tol):
    """All fluid particles within the tank's inner box (a particle in a wall leaked)."""
    x = f["x"][f["phase"] == 1]
    return bool(np.all(x >= np.asarray(lo) - tol) and np.all(x <= np.asarray(hi) + tol))


def test_bingham_slump_comes_to_rest_at_the_cfl_step(comm, mpi_tmp_path):
    """nu_fMAX = 1e4 m^2/s: an explicit scheme would need dt ~ d^2 / nu = 6e-8 s. With the
    projection first (fluid.splitting, docs/coupling.md) the PPE carries the deposit's
    weight and its yield stress (40) holds it: every fluid particle below 1 cm/s at 2 s
    (the viscous predictor first left it creeping at 1.8 cm/s median, 3-4 cm/s max)."""
    scene, out = _run(comm, mpi_tmp_path, "bingham_slump", ["run.end_time=2.0"])
    vmax = _slump_checks(scene, out) if comm.rank == 0 else None
    vmax = comm.bcast(vmax, root=0)  # every rank reports the same outcome
    assert vmax < 0.01, f"a fluid particle at {vmax:.4f} m/s at 2 s"


def _slump_checks(scene, out):
    """What the slump must show at 2 s (rank 0); returns its fastest fluid speed."""
    rows = stats_rows(out)
    d = scene.domain.particle_size
    dts = np.array([float(r["dt"]) for r in rows])
    assert np.median(dts) > 1e4 * d * d / scene.materials["soil"].viscosity_max
    # fluid.viscous_solver = auto: a viscous number this large is solved implicitly
    assert min(float(r["viscous_number"]) for r in rows) > 0.1
    assert all(float(r["visc_iterations"]) > 0 for r in rows)
    ke = np.array([float(r["kinetic_energy"]) for r in rows])
    assert ke[-1] < 0.01 * ke.max()  # slumped and (nearly) stopped
    # the energy balance (docs/energy.md) falls: the work of gravity is dissipated by the
    # yield stress and the viscosity (and taken by the wall contact)
    work = np.array([float(r["work_body"]) for r in rows])
    energy = np.array([float(r["mechanical_energy"]) for r in rows])
    assert energy[-1] - energy[0] < -0.99 * work[-1]  # measured: the whole 630 J
    # measured: no step raises E (0 on 1 rank); 1e-9 is far above E's round-off
    # (1e-16 of the 630 J of work: 1e-15 of the 118 J peak kinetic energy)
    assert_energy_balance(rows, 1e-9, 1e-9, "bingham_slump")
    f = read_frame(os.path.join(out, "particles.h5"), "last")
    assert _inside_tank(f, (0.0, 0.0), (3.0, 0.6), 0.5 * d)
    return float(np.sqrt((f["v"][f["phase"] == 1] ** 2).sum(axis=1)).max())


def test_long_hydrostatic_run_stays_at_rest(comm, mpi_tmp_path):
    """20 s of water in the tank at a coarse d = H / 10 (affordable in a test), default
    numerics: at rest in every frame (rms speed < 1 % of sqrt(g H), about twice the
    largest measured, 0.49 %; any particle < 5 %),
    the surface flat within half a spacing, nothing leaks. Before the corrected PPE
    Laplacian, the unclamped wall pressure and the two-sided density term
    (docs/iisph.md) the top layers sloshed at 6 % of sqrt(g H)."""
    scene, out = _run(comm, mpi_tmp_path, "hydrostatic",
                      ["domain.particle_size=0.1", "run.end_time=20.0", "output.every=2.0"])
    if comm.rank == 0:
        d = scene.domain.particle_size
        scale = math.sqrt(9.81 * 1.0)
        frames = list(_frames(out))
        # the run stops at the first sync step at or after run.end_time
        dt = max(float(r["dt"]) for r in stats_rows(out))
        reuse = scene.fluid.preconditioner_reuse
        assert 20.0 <= frames[-1][0] <= 20.0 + reuse * dt * (1 + 1e-9)
        rms = [np.sqrt(np.mean((f["v"][f["phase"] == 1] ** 2).sum(1))) / scale
               for _, f in frames]
        record("hydrostatic_20s", {"max_rms_speed_pc": 100 * max(rms)}, ranks=comm.size)
        for _, f in frames:
            fl = f["phase"] == 1
            assert _inside_tank(f, (0.0, 0.0), (1.0, 1.2), 0.5 * d)
            speed = np.sqrt((f["v"][fl] ** 2).sum(1))
            assert np.sqrt(np.mean(speed ** 2)) < 0.01 * scale
            assert speed.max() < 0.05 * scale
            assert f["x"][fl, 1].max() < 1.0  # top layer starts at H - d/2: flat to d/2


def _lone_row(comm, tmp, contact, sub):
    overrides = [f"fluid.surface_wall_contact={str(contact).lower()}",
                 "run.end_time=0.6" if contact else "run.end_time=0.4"]
    scene = load_shared(comm, tmp, LONE_ROW, overrides, "lone_row.toml")
    out = os.path.join(tmp, sub)
    run(scene, out, comm=comm, progress=False)
    return scene, list(_frames(out)) if comm.rank == 0 else None


def test_lone_bingham_row_slides_to_rest_on_the_floor(comm, mpi_tmp_path):
    """Five debris particles, all free surface (p = 0), sliding on a floor at 1 m/s: the
    PPE does not hold them off the wall, the contact rule does (fluid.surface_wall_contact,
    docs/iisph.md): never below their resting height, and they stop after about the
    Coulomb distance v0^2 / (2 tan(phi') g) = 0.144 m of the Bingham yield (eq. 40) with
    the wall's normal impulse as pressure (measured 0.116 m, 19 % short: the no-slip
    viscous drag adds; the test allows twice that, 38 % short, to 5 % long)."""
    scene, frames = _lone_row(comm, mpi_tmp_path, True, "contact")
    if comm.rank == 0:
        d = scene.domain.particle_size
        mu = math.tan(math.radians(scene.materials["debris"].friction_angle))
        coulomb = 1.0 ** 2 / (2.0 * mu * 9.81)
        for _, f in frames:
            assert f["x"][:, 1][f["phase"] == 1].min() > 0.45 * d  # rests at d / 2
        first, last = frames[0][1], frames[-1][1]
        fl0, fl = first["phase"] == 1, last["phase"] == 1
        slide = last["x"][fl, 0].max() - first["x"][fl0, 0].max()
        record("lone_row", {"slide_m": slide, "coulomb_m": coulomb}, ranks=comm.size)
        assert 0.62 * coulomb < slide < 1.05 * coulomb
        assert np.abs(last["v"][fl, 0]).max() < 0.02  # stopped (it sits with a mm bounce)


def test_lone_bingham_row_sinks_into_the_floor_without_the_contact(comm, mpi_tmp_path):
    """What the contact rule removes: at p = 0, in a layer too thin to bring the floor's
    particles into contact (docs/iisph.md), nothing holds the row but its own pressure once
    it is compressed, and it sinks below its resting height d/2 (with the floor's rows
    extrapolating the pressure, before, it sank into the floor and the PPE later threw it
    out at tens of m/s: the slope_failure run of docs/coupling.md)."""
    scene, frames = _lone_row(comm, mpi_tmp_path, False, "free")
    if comm.rank == 0:
        d = scene.domain.particle_size
        lowest = min(f["x"][:, 1][f["phase"] == 1].min() for _, f in frames)
        assert lowest < 0.45 * d  # below its resting height


@pytest.mark.parametrize("divisions", [10, 14])
def test_dam_break_runs_and_does_not_leak(comm, mpi_tmp_path, divisions):
    """Two resolutions (a / 10, a / 14): stable to T = 3.5, nothing leaves the tank
    (the corner at the foot of the left wall and the impact on the right wall), and the
    mean front error against both experiments (T > 0.5) within 12 % (measured 9.7 % at
    a / 10 and 6.8 % at a / 14: simulations of this experiment run ahead of it, gate
    release and bed friction are not modelled)."""
    a = 0.146
    d = round(a / divisions, 6)
    scene, out = _run(comm, mpi_tmp_path, "dam_break",
                      [f"domain.particle_size={d}", "run.end_time=0.3", "output.every=0.02"])
    if comm.rank == 0:
        from parsph.verify.fluid import dam_break

        error = dam_break(scene, out)
        record(f"dam_break_a{divisions}", {"mean_front_error_pc": 100 * error},
               ranks=comm.size)
        assert error < 0.12
        for _, f in _frames(out):
            assert _inside_tank(f, (0.0, 0.0), (4 * a, 0.35), 0.5 * d)
        T, Z = front_positions(out, a, d)
        assert Z[-1] > 3.5  # the surge reached the right wall
        # both resolutions give the same surge: z/a = 2.5 +- 10 % at T = 2
        assert np.interp(2.0, T, Z) == pytest.approx(2.5, rel=0.1)


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_ppe_that_cannot_converge_stops_the_run(tmp_path, ranks):
    """PETSc options pass through the command line; a PPE that cannot converge stops the
    run with exit status 3 and one message naming the solve, its reason and iterations."""
    from tests.test_cli import parsph

    r = parsph("run", "hydrostatic", "--out", str(tmp_path / "out"), "--no-progress",
               "--set", "domain.particle_size=0.1", "--set", "run.end_time=0.1",
               "-ppe_ksp_max_it", "1", "-ppe_ksp_rtol", "1e-14", ranks=ranks)
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert r.stderr.count("numerical failure") == 1, r.stderr
    assert "linear solve 'ppe_' did not converge" in r.stderr
    assert "DIVERGED_MAX_IT" in r.stderr and "after 1 iterations" in r.stderr
    assert "Traceback" not in r.stderr
