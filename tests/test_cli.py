"""The command line, run as a user would: each verb, and bad input on 1 and 2 ranks.

These tests spawn ``parsph`` (and ``mpirun -n 2 parsph``) as subprocesses, so they run in
the one-rank session only (mpirun cannot be nested).
"""
import os
import subprocess
import sys

import pytest

from tests.scenes import MOVING_2D, write

pytestmark = pytest.mark.serial_only

_MPI_ENV_PREFIXES = ("OMPI_", "PMIX_", "OPAL_", "PRTE_", "HYDRA_", "PMI_")


def _env():
    env = {k: v for k, v in os.environ.items() if not k.startswith(_MPI_ENV_PREFIXES)}
    env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1")
    return env


def parsph(*args, ranks=1, timeout=240, cwd=None):
    cmd = [sys.executable, "-m", "parsph", *args]
    if ranks > 1:
        cmd = ["mpirun", "-n", str(ranks)] + cmd
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=_env(),
                          cwd=cwd, stdin=subprocess.DEVNULL)


def test_scenes_lists_builtins():
    r = parsph("scenes")
    assert r.returncode == 0, r.stderr
    assert "hydrostatic" in r.stdout and "tank" in r.stdout


def test_info_prints_versions():
    r = parsph("info")
    assert r.returncode == 0, r.stderr
    for word in ("MPI", "mpi4py", "PETSc", "hypre", "HDF5", "numba", "numpy"):
        assert word in r.stdout
    assert "parallel" in r.stdout


def test_check_prints_stages_counts_memory():
    r = parsph("check", "hydrostatic", "--set", "run.mode=geometry", ranks=2)
    assert r.returncode == 0, r.stderr
    assert "iisph" not in r.stdout
    r = parsph("check", "hydrostatic", ranks=2)
    assert r.returncode == 0 and "iisph" in r.stdout, r.stderr
    assert "stages of one step" in r.stdout and "neighbours" in r.stdout
    assert "per rank: 0:" in r.stdout and "1:" in r.stdout and "MiB" in r.stdout
    assert r.stdout.count("stages of one step") == 1  # rank 0 only
    assert "bodies as filled" in r.stdout and "warning" not in r.stdout


def test_check_reports_a_body_the_lattice_does_not_meet():
    """At d = 0.035 m the slope's 1 m stands 29 rows = 1.015 m tall: ``check`` prints the
    body as filled beside its geometry and warns, naming a size that meets it (2 ranks: the
    same report as on one)."""
    r = parsph("check", "slope_failure", "--set", "domain.particle_size=0.035", ranks=2)
    assert r.returncode == 0, r.stderr
    assert "slope        polygon, 1810 particles: 2.485 x 1.015 m (geometry 2.5 x 1 m)" in r.stdout
    assert "2.217 m^2 (geometry 2.2 m^2, +0.78 %)" in r.stdout
    assert "warning: body 'slope' is not met by the lattice of d = 0.035 m" in r.stdout
    assert "d = 0.03333 m meets every vertex" in r.stdout


def test_run_and_plot_on_two_ranks(tmp_path):
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    r = parsph("run", scene, "--out", str(out), ranks=2)
    assert r.returncode == 0, r.stderr
    for name in ("particles.h5", "particles.xdmf", "stats.csv"):
        assert (out / name).stat().st_size > 0
    assert "1/2 " not in r.stderr  # non-root ranks log warnings only
    r = parsph("plot", str(out))
    assert r.returncode == 0, r.stderr
    pngs = [p for p in r.stdout.split() if p.endswith(".png")]
    assert pngs and all(os.path.getsize(p) > 1000 for p in pngs)
    r = parsph("plot", str(out), "--series", "--frames", "first,last")
    assert r.returncode == 0, r.stderr
    pngs = r.stdout.split()
    from parsph.io import read_frames

    last = read_frames(str(out))[-1][0]
    assert [os.path.basename(p) for p in pngs] == ["series.png", "frame_000000.png",
                                                   f"frame_{last:06d}.png"]
    assert len({os.path.dirname(p) for p in pngs}) == 1  # side by side in DIR/plots
    assert all(os.path.getsize(p) > 1000 for p in pngs)


BAD_INPUT = [
    (["frobnicate"], "invalid choice"),
    ([], "no command"),
    (["run", "nope"], "unknown scene 'nope'"),
    (["run", "missing/scene.toml"], "does not exist"),
    (["run", "hydrostatic", "--set", "domain.particle_size=-0.1"], "domain.particle_size"),
    (["run", "hydrostatic", "--set", "domain.particle_size=1e-5", "--set", "run.mode=geometry"],
     "run.max_particles"),
    (["run", "hydrostatic", "--set", "domain.dim=4"], "domain.dim"),
    (["run", "hydrostatic", "--set", "run.end_time=nan"], "run.end_time"),
    (["run", "hydrostatic", "--bogus"], "unknown option '--bogus'"),
    (["run", "-ppe_ksp_monitor", "dam_break"], "name the scene before PETSc options"),
    (["scenes", "-ppe_ksp_monitor"], "PETSc options go to"),
    (["check", "hydrostatic", "--set", "walls.0.sides=[\"roof\"]"], "walls[0].sides"),
    (["plot", "/nonexistent/dir"], "/nonexistent/dir"),
    (["check", "triaxial_light", "--set", "domain.particle_size=0.0002"], "GiB"),
    (["run", "hydrostatic", "--set", "materials.water.model=hencky", "--set",
      "materials.water.poisson_ratio=0.3", "--set", "materials.water.young_modulus=1e6"],
     "materials.water.viscosity"),
]


def test_petsc_options_are_split_off_before_argparse():
    """``-visc_...`` is no ``-v``, and an option's value is no scene (PETSc's reading:
    the next argument unless it starts with a dash and is no number)."""
    from parsph.cli.main import split_petsc_options

    ours, petsc = split_petsc_options(
        ["run", "-visc_ksp_monitor", "-ppe_ksp_rtol", "1e-10", "-v", "--set", "a.b=-1",
         "-ppe_pc_hypre_boomeramg_agg_nl", "1", "-x_shift", "-2.5", "-log_view"])
    assert ours == ["run", "-v", "--set", "a.b=-1"]
    assert petsc == ["-visc_ksp_monitor", "-ppe_ksp_rtol", "1e-10", "-ppe_pc_hypre_boomeramg_agg_nl",
                     "1", "-x_shift", "-2.5", "-log_view"]
    ours, petsc = split_petsc_options(["run", "dam_break", "-ppe_ksp_monitor", "--out", "o"])
    assert ours == ["run", "dam_break", "--out", "o"] and petsc == ["-ppe_ksp_monitor"]


@pytest.mark.parametrize("ranks", [1, 2])
@pytest.mark.parametrize("args,words", BAD_INPUT, ids=[" ".join(a) or "none" for a, _ in BAD_INPUT])
def test_bad_input_one_message_no_traceback(args, words, ranks):
    r = parsph(*args, ranks=ranks, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert words in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.count("parsph: error:") == 1, r.stderr


def test_bad_scene_files(tmp_path):
    empty = write(tmp_path, "", "empty.toml")
    broken = write(tmp_path, "[scene\n", "broken.toml")
    for path, words in ((empty, "is empty"), (broken, "not valid TOML")):
        r = parsph("run", path, ranks=2)
        assert r.returncode == 2 and words in r.stderr and "Traceback" not in r.stderr


def test_output_dir_not_writable(tmp_path):
    scene = write(tmp_path, MOVING_2D)
    blocker = tmp_path / "file"
    blocker.write_text("I am a file, not a directory")
    r = parsph("run", scene, "--out", str(blocker / "out"), ranks=2)
    assert r.returncode == 2 and "not writable" in r.stderr
    assert blocker.read_text() == "I am a file, not a directory"


def test_numerical_failure_particle_leaves_domain(tmp_path):
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    r = parsph("run", scene, "--out", str(out), "--set", "bodies.0.velocity=[0, 30]", ranks=2)
    assert r.returncode == 3, r.stderr
    assert "left the domain" in r.stderr and "particle id" in r.stderr
    assert r.stderr.count("numerical failure") == 1
    assert (out / "particles.h5").stat().st_size > 0  # the frames written before are kept


def test_bad_input_never_touches_earlier_output(tmp_path):
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    assert parsph("run", scene, "--out", str(out), ranks=2).returncode == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    for bad in (["--set", "run.end_time=-1"], ["--set", "bodies.0.material=x"], ["--bogus"],
                ["--restart", str(tmp_path / "none.h5")], ["--restart", str(out)]):
        r = parsph("run", scene, "--out", str(out), *bad, ranks=2)
        assert r.returncode == 2, r.stderr
        if bad[-1] == str(out):  # the run directory, not its checkpoint: named in the message
            assert "is a directory" in r.stderr and "checkpoint.h5" in r.stderr, r.stderr
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert after == before


def test_one_thread_per_rank_unless_asked():
    """Importing parsph first keeps OpenBLAS (and OpenMP) to one thread per process:
    their idle workers spin in sched_yield on the cores of the other ranks. A value the
    user set is kept."""
    code = ("import os, parsph, numpy as np; a = np.ones((400, 400)); a @ a; "
            "print(len(os.listdir('/proc/self/task')), os.environ['OMP_NUM_THREADS'])")
    env = {k: v for k, v in _env().items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=60, check=True).stdout.split()
    assert out == ["1", "1"]
    env["OMP_NUM_THREADS"] = "2"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=60, check=True).stdout.split()
    assert out[1] == "2"
