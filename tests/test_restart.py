"""Runs that survive: exact restart, restart on another rank count, bad restart files."""
import os
import shutil

import h5py
import numpy as np
import pytest

from parsph.errors import ParsphError
from parsph.step.run import run
from parsph.scene.loader import load_scene
from tests.scenes import MOVING_2D, alone_on_rank_zero, by_id, last_frame, write


def _scene(comm, tmp, overrides=()):
    # written once: rewriting it while another rank still reads it for the last scene
    # gave that rank an empty file (and a hang, the other rank going on to a collective)
    path = os.path.join(tmp, "scene.toml")
    if comm.rank == 0 and not os.path.exists(path):
        write(tmp, MOVING_2D)
    return load_scene(comm.bcast(path), list(overrides))


def _interrupted_and_whole(comm_a, comm_b, tmp, tag):
    """Run to 0.2 s on comm_a, restart to 0.4 s on comm_b; and 0 → 0.4 s on comm_b."""
    half = os.path.join(tmp, f"half-{tag}")
    whole = os.path.join(tmp, f"whole-{tag}")
    if comm_a is not None:
        run(_scene(comm_a, tmp, ["run.end_time=0.2"]), half, comm=comm_a, progress=False)
    if comm_b is not None:
        comm_b.Barrier()
        run(_scene(comm_b, tmp), half, comm=comm_b, progress=False,
            restart=os.path.join(half, "checkpoint.h5"))
        run(_scene(comm_b, tmp), whole, comm=comm_b, progress=False)
    return half, whole


def test_restart_is_bit_for_bit_at_equal_rank_count(comm, mpi_tmp_path):
    half, whole = _interrupted_and_whole(comm, comm, mpi_tmp_path, "same")
    if comm.rank == 0:
        a, b = last_frame(half), last_frame(whole)
        for key in ("id", "x", "v", "rho", "rank"):
            assert np.array_equal(a[key], b[key]), key
        steps_a = [s for s in h5py.File(os.path.join(half, "particles.h5"))["frames"]]
        assert len(steps_a) == 3  # frames 0, 0.2 (before), 0.4 (after the restart)
        with open(os.path.join(half, "stats.csv")) as fh, \
                open(os.path.join(whole, "stats.csv")) as gh:
            rows_a = [r.split(",")[:4] for r in fh.readlines()]
            rows_b = [r.split(",")[:4] for r in gh.readlines()]
        assert rows_a == rows_b  # same steps, times, dt and particle counts, no duplicates


@pytest.mark.mpi
@pytest.mark.parametrize("direction", ["1to2", "2to1"])
def test_restart_on_another_rank_count(comm, mpi_tmp_path, direction):
    half = os.path.join(mpi_tmp_path, "half")

    def first(on):
        run(_scene(on, mpi_tmp_path, ["run.end_time=0.2"]), half, comm=on, progress=False)

    def second(on):
        run(_scene(on, mpi_tmp_path), half, comm=on, progress=False,
            restart=os.path.join(half, "checkpoint.h5"))
        run(_scene(on, mpi_tmp_path), os.path.join(mpi_tmp_path, "whole"), comm=on,
            progress=False)

    if direction == "1to2":  # rank 0 alone, then all ranks (a failure raises everywhere)
        alone_on_rank_zero(comm, first)
        second(comm)
    else:
        first(comm)
        alone_on_rank_zero(comm, second)
    if comm.rank == 0:
        a, b = last_frame(half), last_frame(os.path.join(mpi_tmp_path, "whole"))
        assert np.array_equal(a["id"], b["id"])
        assert np.allclose(a["x"], b["x"], rtol=0, atol=1e-12)
        assert np.allclose(a["rho"], b["rho"], rtol=1e-12)


def test_bad_restart_files(comm, mpi_tmp_path):
    scene = _scene(comm, mpi_tmp_path, ["run.end_time=0.2"])
    out = os.path.join(mpi_tmp_path, "out")
    run(scene, out, comm=comm, progress=False)
    good = os.path.join(out, "checkpoint.h5")
    broken = os.path.join(mpi_tmp_path, "broken.h5")
    text = os.path.join(mpi_tmp_path, "text.h5")
    if comm.rank == 0:
        with open(good, "rb") as fh, open(broken, "wb") as gh:
            gh.write(fh.read()[:2000])  # a truncated copy
        with open(text, "w") as fh:
            fh.write("not hdf5")
    comm.Barrier()
    cases = [
        (os.path.join(mpi_tmp_path, "missing.h5"), scene, "does not exist"),
        (broken, scene, "not a readable HDF5 checkpoint"),
        (text, scene, "not a readable HDF5 checkpoint"),
        (good, load_scene("hydrostatic", ["run.mode=geometry"]), "from scene 'moving'"),
        (good, _scene(comm, mpi_tmp_path, ["domain.particle_size=0.04"]),
         r"other scene settings: \[domain\] differs"),
        (good, _scene(comm, mpi_tmp_path, ["materials.sand.density=1600.0"]),
         r"\[materials\] differs.*branch"),
    ]
    for path, scn, words in cases:
        with pytest.raises(ParsphError, match=words):
            run(scn, os.path.join(mpi_tmp_path, "again"), comm=comm, progress=False, restart=path)
    assert not os.path.exists(os.path.join(mpi_tmp_path, "again"))  # nothing was written
    # the good checkpoint is untouched by the failed attempts
    assert h5py.File(good, "r").attrs["step"] > 0
    if comm.rank == 0:
        shutil.rmtree(out)


PHYSICS = [
    ("elastic_plate", ["domain.particle_size=0.005", "output.every=0.01"], 0.01, 0.02),
    ("slope_failure_solid", ["domain.particle_size=0.1", "output.every=0.05"], 0.05, 0.1),
    ("hydrostatic", ["domain.particle_size=0.05", "output.every=0.05"], 0.05, 0.1),
    ("dam_break", ["domain.particle_size=0.0146", "output.every=0.02"], 0.02, 0.04),
    # coupled, restarted after the phase change started
    ("slope_failure", ["output.every=0.05"], 0.3, 0.35),
]


@pytest.mark.parametrize("name,overrides,half,end", PHYSICS, ids=[p[0] for p in PHYSICS])
def test_physics_restart_is_bit_for_bit(comm, mpi_tmp_path, name, overrides, half, end):
    """Each phase's state is in the checkpoint: a restarted run equals the whole run."""
    first = os.path.join(mpi_tmp_path, "first")
    whole = os.path.join(mpi_tmp_path, "whole")
    run(load_scene(name, overrides + [f"run.end_time={half}"]), first, comm=comm,
        progress=False)
    run(load_scene(name, overrides + [f"run.end_time={end}"]), first, comm=comm,
        progress=False, restart=os.path.join(first, "checkpoint.h5"))
    run(load_scene(name, overrides + [f"run.end_time={end}"]), whole, comm=comm,
        progress=False)
    if comm.rank == 0:
        a, b = last_frame(first), last_frame(whole)
        for key in ("id", "x", "v", "p", "eps_p", "porosity"):
            assert np.array_equal(a[key], b[key]), key


def _first_at_or_after(times, targets):
    return [min(t for t in times if t >= target - 1e-12) for target in targets]


def test_restart_with_another_frame_interval(comm, mpi_tmp_path):
    """output.every may change at a restart: the next frame follows the new interval,
    each at the first step at or after its time; the steps are those of one run."""
    out = os.path.join(mpi_tmp_path, "out")
    run(_scene(comm, mpi_tmp_path, ["run.end_time=0.25", "output.every=0.1"]), out, comm=comm,
        progress=False)
    run(_scene(comm, mpi_tmp_path, ["run.end_time=0.3", "output.every=0.02"]), out, comm=comm,
        progress=False, restart=os.path.join(out, "checkpoint.h5"))
    run(_scene(comm, mpi_tmp_path, ["run.end_time=0.3"]), os.path.join(mpi_tmp_path, "whole"),
        comm=comm, progress=False)
    if comm.rank == 0:
        from parsph.io import read_frames, read_stats

        times = [t for _, t in read_frames(os.path.join(out, "particles.h5"))]
        steps = list(read_stats(os.path.join(out, "stats.csv"))["time"])
        assert steps == list(read_stats(os.path.join(mpi_tmp_path, "whole", "stats.csv"))["time"])
        first_end = _first_at_or_after(steps, [0.25])[0]  # where the first run stopped
        expected = [0.0] + _first_at_or_after(steps, [0.1, 0.2]) + [first_end] \
            + _first_at_or_after(steps, [0.26, 0.28, 0.3])
        assert times == sorted(set(expected))
        assert times[-1] == steps[-1] >= 0.3


def _hashes(directory):
    import hashlib

    return {name: hashlib.sha256(open(os.path.join(directory, name), "rb").read()).hexdigest()
            for name in sorted(os.listdir(directory))}


BRANCH = ["domain.particle_size=0.0146", "output.every=0.01", "output.progress=false"]


def test_branch_into_a_new_directory(comm, mpi_tmp_path):
    """``--restart A/checkpoint.h5 --out B``: B starts at A's last state (its frame 0, its
    stats from the next step) and, with a later end time and another frame interval, ends
    bit for bit where a straight run ends; A is left byte for byte as it was."""
    a, b, whole = (os.path.join(mpi_tmp_path, k) for k in ("A", "B", "whole"))
    run(load_scene("dam_break", BRANCH + ["run.end_time=0.02"]), a, comm=comm, progress=False)
    before = _hashes(a) if comm.rank == 0 else None
    comm.Barrier()
    run(load_scene("dam_break", BRANCH + ["run.end_time=0.04", "output.every=0.004"]), b,
        comm=comm, progress=False, restart=os.path.join(a, "checkpoint.h5"))
    run(load_scene("dam_break", BRANCH + ["run.end_time=0.04"]), whole, comm=comm,
        progress=False)
    if comm.rank != 0:
        return
    from parsph.io import read_frame, read_frames, read_stats

    assert _hashes(a) == before
    with h5py.File(os.path.join(a, "checkpoint.h5"), "r") as f:
        ck = dict(f.attrs)
    frames = read_frames(b)
    assert frames[0] == (ck["step"], ck["time"]) == read_frames(a)[-1]
    first, start = by_id(read_frame(b, frames[0][0])), last_frame(a)
    for key in ("id", "x", "v", "p"):
        assert np.array_equal(first[key], start[key]), key
    sb, sw = read_stats(os.path.join(b, "stats.csv")), read_stats(os.path.join(whole, "stats.csv"))
    later = sw["step"] > ck["step"]
    assert sb["step"][0] == ck["step"] + 1
    # the energy balance goes on from the checkpoint's (docs/energy.md)
    for col in ("step", "time", "dt", "kinetic_energy", "work_body", "mechanical_energy",
                "energy_rise", "energy_rise_max", "energy_gain_max"):
        assert np.array_equal(sb[col], sw[col][later]), col
    end, straight = last_frame(b), last_frame(whole)
    for key in ("id", "x", "v", "p", "rho"):
        assert np.array_equal(end[key], straight[key]), key


def test_branch_replaces_another_run_in_its_directory(comm, mpi_tmp_path):
    """A branch into a directory that holds an older run writes a new run there (as any
    run does), no frame or stats row of the old one left."""
    src, dst = os.path.join(mpi_tmp_path, "src"), os.path.join(mpi_tmp_path, "dst")
    run(_scene(comm, mpi_tmp_path, ["run.end_time=0.1"]), src, comm=comm, progress=False)
    run(_scene(comm, mpi_tmp_path, ["run.end_time=0.3"]), dst, comm=comm, progress=False)
    run(_scene(comm, mpi_tmp_path, ["run.end_time=0.2"]), dst, comm=comm, progress=False,
        restart=os.path.join(src, "checkpoint.h5"))
    if comm.rank == 0:
        from parsph.io import read_frames, read_stats

        with h5py.File(os.path.join(src, "checkpoint.h5"), "r") as f:
            step = f.attrs["step"]
        assert read_frames(dst)[0][0] == step
        assert read_stats(os.path.join(dst, "stats.csv"))["step"][0] == step + 1
        assert read_frames(dst)[-1][1] < 0.3


def test_same_directory():
    from parsph.step.run import same_directory

    assert same_directory("runs/A/checkpoint.h5", "runs/A/")
    assert same_directory("runs/A/checkpoint.h5", "runs/B/../A")
    assert not same_directory("runs/A/checkpoint.h5", "runs/B")


def test_preemption_waits_for_a_sync_step_and_restarts_bit_for_bit(comm, mpi_tmp_path,
                                                                    monkeypatch):
    """SIGUSR1 on rank 0 after step 5 of a dam break (a sync step every 4 steps, the PPE's
    lagged set-up): every rank goes on to step 8, checkpoints there and stops; the run
    restarted from it ends bit for bit where the uninterrupted one ends."""
    import signal

    from parsph.step import faults
    from parsph.errors import Preempted

    cut, whole = os.path.join(mpi_tmp_path, "cut"), os.path.join(mpi_tmp_path, "whole")
    scene = load_scene("dam_break", BRANCH + ["run.end_time=0.04"])
    inject = faults.inject_nan

    def signal_at_step_5(ctx):
        inject(ctx)
        if ctx.step == 5 and ctx.comm.rank == 0:
            signal.raise_signal(signal.SIGUSR1)

    monkeypatch.setattr(faults, "inject_nan", signal_at_step_5)
    with pytest.raises(Preempted, match="at step 8"):
        run(scene, cut, comm=comm, progress=False)
    monkeypatch.setattr(faults, "inject_nan", inject)
    run(scene, cut, comm=comm, progress=False, restart=os.path.join(cut, "checkpoint.h5"))
    run(scene, whole, comm=comm, progress=False)
    if comm.rank == 0:
        a, b = last_frame(cut), last_frame(whole)
        for key in ("id", "x", "v", "p", "rho"):
            assert np.array_equal(a[key], b[key]), key
