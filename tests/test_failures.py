"""Failures as a batch job meets them: pre-emption signals, NaNs, a checkpoint write that
dies half-way. Each case runs ``parsph`` under ``mpirun -n 2`` (one-rank session only)."""
import os
import signal
import subprocess
import sys
import time

import h5py
import pytest

from tests.scenes import MOVING_2D, write
from tests.test_cli import _env, parsph

pytestmark = pytest.mark.serial_only

LONG = ["--set", "run.dt=2e-4", "--set", "run.end_time=0.4", "--set", "output.every=0.1",
        "--set", "output.checkpoint_every=0.02"]


@pytest.mark.parametrize("signame", ["SIGUSR1", "SIGTERM"])
def test_preemption_writes_checkpoint_and_restart_finishes(tmp_path, signame):
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    cmd = ["mpirun", "-n", "2", sys.executable, "-m", "parsph", "run", scene, "--out", str(out),
           "--no-progress"] + LONG
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(), stdin=subprocess.DEVNULL)
    deadline = time.time() + 120
    while not (out / "checkpoint.h5").exists() and time.time() < deadline:
        time.sleep(0.2)
    # what a batch system does: signal every rank of the job
    ranks = subprocess.run(["pgrep", "-f", f"parsph run {scene}"], capture_output=True,
                           text=True).stdout.split()
    for pid in ranks:
        if int(pid) != proc.pid:
            os.kill(int(pid), getattr(signal, signame))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 4, err
    assert "stopped by a signal" in err and "--restart" in err and "Traceback" not in err
    with h5py.File(out / "checkpoint.h5", "r") as f:
        stopped_at = f.attrs["time"]
    assert 0 < stopped_at < 0.4
    r = parsph("run", scene, "--restart", str(out / "checkpoint.h5"), *LONG, ranks=2)
    assert r.returncode == 0, r.stderr
    with h5py.File(out / "checkpoint.h5", "r") as f:
        assert f.attrs["time"] == pytest.approx(0.4)


@pytest.mark.parametrize("ranks", [1, 2])
def test_nan_stops_every_rank_with_one_message(tmp_path, ranks):
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    bad_rank = ranks - 1
    try:
        os.environ["PARSPH_FAULT"] = f"nan:150:{bad_rank}"
        r = parsph("run", scene, "--out", str(out), *LONG, ranks=ranks)
    finally:
        os.environ.pop("PARSPH_FAULT")
    assert r.returncode == 3, r.stderr
    assert r.stderr.count("numerical failure") == 1 and "Traceback" not in r.stderr
    assert "non-finite v" in r.stderr and "step 150" in r.stderr
    assert f"rank {bad_rank}" in r.stderr and "particle id" in r.stderr
    with h5py.File(out / "particles.h5", "r") as f:
        assert len(f["frames"]) >= 1  # frames written before the failure are kept
    with h5py.File(out / "checkpoint.h5", "r") as f:
        assert f.attrs["step"] == 100  # the last good checkpoint is kept


@pytest.mark.parametrize("ranks", [1, 2])
def test_checkpoint_write_dying_halfway_keeps_the_previous_one(tmp_path, ranks):
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    # checkpoints every 0.02 s at dt = 2e-4: steps 100, 200, ...; the second write dies
    try:
        os.environ["PARSPH_FAULT"] = "checkpoint:200"
        r = parsph("run", scene, "--out", str(out), *LONG, ranks=ranks)
    finally:
        os.environ.pop("PARSPH_FAULT")
    assert r.returncode != 0
    with h5py.File(out / "checkpoint.h5", "r") as f:
        assert f.attrs["step"] == 100
    r = parsph("run", scene, "--restart", str(out / "checkpoint.h5"), *LONG, ranks=ranks)
    assert r.returncode == 0, r.stderr


def test_aso_cluster_job_runs_the_scene_at_three_metres(tmp_path):
    """jobs/aso_d3.sbatch hands the aso scene at d = 3 m (and the user's SET after it) to
    jobs/slurm.sbatch; a stand-in srun records what it was asked to run."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "srun").write_text(f'#!/bin/bash\necho "$@" >> {tmp_path}/srun.log\n')
    (bin_dir / "srun").chmod(0o755)
    env = _env()
    env.update(PATH=f"{bin_dir}:{env['PATH']}", SLURM_SUBMIT_DIR=root, OUT=str(tmp_path / "o"),
               SET="output.every=1", VENV=str(tmp_path / "none"))
    r = subprocess.run(["bash", os.path.join(root, "jobs", "aso_d3.sbatch")], env=env,
                       capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert r.returncode == 0, r.stdout + r.stderr
    args = (tmp_path / "srun.log").read_text().split()
    assert args[:3] == ["parsph", "run", "aso"]
    sets = [args[i + 1] for i, a in enumerate(args) if a == "--set"]
    assert sets == ["domain.particle_size=3", "output.checkpoint_every=25", "output.every=1"]
    assert args[args.index("--out") + 1] == str(tmp_path / "o")


def test_slurm_template_checkpoints_and_requeues(tmp_path):
    """jobs/slurm.sbatch with stand-ins for srun (mpirun -n 2) and scontrol (a log)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "srun").write_text('#!/bin/bash\nexec mpirun -n 2 "$@"\n')
    (bin_dir / "scontrol").write_text(f'#!/bin/bash\necho "$@" >> {tmp_path}/scontrol.log\n')
    for name in ("srun", "scontrol"):
        (bin_dir / name).chmod(0o755)
    scene = write(tmp_path, MOVING_2D)
    out = tmp_path / "out"
    env = _env()
    env.update(PATH=f"{bin_dir}:{os.path.join(root, '.venv', 'bin')}:{env['PATH']}",
               SCENE=scene, OUT=str(out), VENV=os.path.join(root, ".venv"), SLURM_JOB_ID="123",
               SET="run.dt=2e-4 run.end_time=0.4 output.every=0.1 output.checkpoint_every=0.02")
    script = os.path.join(root, "jobs", "slurm.sbatch")
    proc = subprocess.Popen(["bash", script], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    deadline = time.time() + 120
    while not (out / "checkpoint.h5").exists() and time.time() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGUSR1)  # what --signal=B:USR1@300 does
    log, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0, log
    assert (tmp_path / "scontrol.log").read_text().split() == ["requeue", "123"], log
    with h5py.File(out / "checkpoint.h5", "r") as f:
        assert f.attrs["time"] < 0.4
    # the re-queued job restarts from the checkpoint and finishes
    again = subprocess.run(["bash", script], env=env, capture_output=True, text=True,
                           timeout=300, stdin=subprocess.DEVNULL)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "restarting from" in again.stdout
    with h5py.File(out / "checkpoint.h5", "r") as f:
        assert f.attrs["time"] == pytest.approx(0.4)
