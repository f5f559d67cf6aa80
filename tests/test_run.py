"""The run driver on a moving particle set: 1 rank and 2 ranks agree by global id."""
import os

import numpy as np
import pytest

from parsph.io import read_frame, read_frames
from parsph.step.run import run
from parsph.scene.loader import load_scene
from tests.scenes import (MOVING_2D, MOVING_3D, by_id, last_frame, load_shared,
                          run_on_one_and_two, stats_rows, write)


@pytest.mark.parametrize("text", [MOVING_2D, MOVING_3D], ids=["2d", "3d"])
def test_kinematic_run_moves_and_conserves(comm, mpi_tmp_path, text):
    scene = load_shared(comm, mpi_tmp_path, text)
    out = os.path.join(mpi_tmp_path, "out")
    summary = run(scene, out, comm=comm, progress=False)
    end = summary["time"]  # the first step at or after run.end_time: no step is clipped
    assert end >= scene.run.end_time
    if comm.rank == 0:
        steps = [s for s, _ in read_frames(os.path.join(out, "particles.h5"))]
        assert steps[0] == 0 and len(steps) == 3
        first = by_id(read_frame(os.path.join(out, "particles.h5"), steps[0]))
        last = by_id(read_frame(os.path.join(out, "particles.h5"), steps[-1]))
        assert np.array_equal(first["id"], last["id"])  # no particle lost or duplicated
        # positions moved by v t, wrapped into the periodic box
        moved = first["x"] + end * first["v"]
        lo, hi = np.array(scene.domain.lo), np.array(scene.domain.hi)
        for ax, per in enumerate(scene.domain.periodic):
            if per:
                moved[:, ax] = lo[ax] + np.mod(moved[:, ax] - lo[ax], hi[ax] - lo[ax])
        assert np.allclose(last["x"], moved, atol=1e-9)
        assert np.all(last["rho"] > 0)
        rows = stats_rows(out)
        assert len(rows) == summary["steps"]
        assert all(int(r["n_particles"]) == len(first["id"]) for r in rows)
        assert float(rows[-1]["time"]) == end < scene.run.end_time + float(rows[-1]["dt"])
        # the wall seconds since the start, at the end of each step: rising, within the run's
        elapsed = [float(r["elapsed_s"]) for r in rows]
        assert 0 < elapsed[0] and all(b >= a for a, b in zip(elapsed, elapsed[1:]))
        assert elapsed[-1] <= summary["wall_s"]


@pytest.mark.mpi
@pytest.mark.parametrize("text", [MOVING_2D, MOVING_3D], ids=["2d", "3d"])
def test_density_on_moving_set_one_vs_two_ranks(comm, mpi_tmp_path, text):
    """The keystone comparison: the same scene on 1 and on 2 ranks, compared by global id."""
    scene = load_shared(comm, mpi_tmp_path, text)
    one, two = run_on_one_and_two(comm, scene, mpi_tmp_path)
    if comm.rank == 0:
        a, b = last_frame(one), last_frame(two)
        assert np.array_equal(a["id"], b["id"])
        assert np.allclose(a["x"], b["x"], rtol=0, atol=1e-12)
        assert np.allclose(a["rho"], b["rho"], rtol=1e-12)
        assert set(np.unique(b["rank"])) == {0, 1}  # both ranks owned particles
        if scene.domain.dim == 2:  # the blocks overlap at the end: density rises there
            assert a["rho"].max() > 1.2 * np.median(a["rho"])


@pytest.mark.mpi
def test_a_failure_on_one_rank_only_fails_every_rank_at_once(comm, mpi_tmp_path, monkeypatch):
    """``run_on_one_and_two``: rank 0's one-rank run stops on a NaN (a fault injected in
    runs on one rank only), so rank 0 raises there while rank 1 has not run at all. Every
    rank must raise the error, at once: before the ranks agreed on it, rank 1 went on into
    the two-rank run and waited for rank 0 in its first collective for ever. The deadline
    (faulthandler, 120 s against a few seconds of work) turns such a hang back into a
    failure with every thread's stack instead of the suite's timeout."""
    import faulthandler

    from parsph.errors import NumericalError
    from parsph.step import faults

    def nan_on_one_rank(ctx):
        if ctx.comm.size == 1 and ctx.step == 1:
            ctx.particles["v"][0, 0] = float("nan")

    scene = load_shared(comm, mpi_tmp_path, MOVING_2D)
    monkeypatch.setattr(faults, "inject_nan", nan_on_one_rank)
    faulthandler.dump_traceback_later(120, exit=True)
    try:
        with pytest.raises(NumericalError, match="non-finite v of particle id .* at step 1"):
            run_on_one_and_two(comm, scene, mpi_tmp_path)
    finally:
        faulthandler.cancel_dump_traceback_later()
    assert not os.path.exists(os.path.join(mpi_tmp_path, "two", "stats.csv"))  # never started


@pytest.mark.mpi
def test_rebalancing_follows_a_moving_body(comm, mpi_tmp_path):
    """All particles drift into one half of the domain: the partition follows them."""
    scene = load_shared(comm, mpi_tmp_path, MOVING_2D)
    scene = load_scene(scene.source, ["bodies.0.velocity=[0, 0]", "bodies.1.velocity=[0, 0]",
                                      "walls.0.hi=[0.2, 0.0]", "bodies.1.vertices=[[0.1, 0.6], "
                                      "[0.9, 0.6], [0.5, 1.0]]", "bodies.0.velocity=[3, 0]",
                                      "bodies.1.velocity=[3, 0]", "run.end_time=0.3"])
    out = os.path.join(mpi_tmp_path, "out")
    run(scene, out, comm=comm, progress=False)
    if comm.rank == 0:
        rows = stats_rows(out)
        worst = max(int(r["n_owned_max"]) / max(int(r["n_owned_min"]), 1) for r in rows)
        # without re-partitioning one rank would end up with (nearly) everything
        assert worst <= scene.run.rebalance_tolerance * 1.3
        assert int(rows[-1]["n_owned_min"]) > 0


@pytest.mark.mpi
def test_a_rank_without_particles(comm, mpi_tmp_path):
    """One particle on two ranks: the empty rank takes part in every collective."""
    text = MOVING_2D.replace("hi = [0.9, 0.5]", "hi = [0.15, 0.05]")
    scene = load_shared(comm, mpi_tmp_path, text, name="one.toml")
    scene = load_scene(scene.source, ["walls.0.hi=[0.05, 0.0]", "walls.0.lo=[0.0, -0.05]",
                                      "bodies.1.vertices=[[1.0, 0.0], [1.05, 0.0], [1.0, 0.05]]"])
    summary = run(scene, os.path.join(mpi_tmp_path, "out"), comm=comm, progress=False)
    assert summary["particles"] <= 3
    assert summary["time"] >= scene.run.end_time


ONLY_WHAT_IS_NEEDED = [
    # (scene, overrides, module prefixes that must not be imported)
    ("moving", ["run.end_time=0.05", "output.every=0.05"],
     ("parsph.solid", "parsph.fluid", "solvers", "petsc4py")),
    ("hydrostatic", ["domain.particle_size=0.1", "run.end_time=0.02", "output.every=0.02"],
     ("parsph.solid",)),
    ("elastic_plate", ["domain.particle_size=0.005", "run.end_time=0.002",
                       "output.every=0.002"], ("parsph.fluid", "solvers", "petsc4py")),
]


@pytest.mark.parametrize("name,overrides,forbidden", ONLY_WHAT_IS_NEEDED,
                         ids=[c[0] for c in ONLY_WHAT_IS_NEEDED])
def test_only_the_stages_a_scene_needs_are_imported(tmp_path, name, overrides, forbidden):
    """A fluid scene never imports the solid; a solid or kinematic scene never imports
    solvers or petsc4py (checked in a fresh interpreter)."""
    import subprocess
    import sys

    scene = write(tmp_path, MOVING_2D) if name == "moving" else name
    code = (f"import sys; from parsph.scene.loader import load_scene; from parsph.step.run import run; "
            f"run(load_scene({scene!r}, {overrides!r}), {str(tmp_path / 'out')!r}, "
            f"progress=False); print(sorted(m for m in sys.modules "
            f"if m.startswith({forbidden!r})))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env={k: v for k, v in os.environ.items() if not k.startswith(("OMPI_",
                            "PMIX_", "OPAL_", "PRTE_", "HYDRA_", "PMI_"))})
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "[]"


def test_state_check_names_the_first_fault():
    """check_state's one pass: a non-finite position before a non-finite velocity, then a
    position outside the closed box on a non-periodic axis only, the first such row."""
    from decomposition.box import Box
    from parsph.step.refresh import _first_non_finite
    rng = np.random.default_rng(3)
    x, v = rng.uniform(0.1, 0.9, (8, 2)), rng.normal(size=(8, 2))
    box = Box(lo=(0.0, 0.0), hi=(1.0, 1.0), periodic=(False, True))
    assert _first_non_finite(x, v, 8) == (0, 0) and box.first_outside(x) == -1
    x[6, 1] = 1.5  # beyond hi on the periodic axis: not a fault
    assert box.first_outside(x) == -1
    x[5, 0], x[4, 0] = -0.1, 1.0  # the closed box holds hi itself
    assert box.first_outside(x) == 5
    assert np.array_equal(box.outside(x), np.arange(8) == 5)  # the same rule, as a mask
    v[3, 1] = np.inf
    assert _first_non_finite(x, v, 8) == (2, 3)
    x[7, 0] = np.nan
    assert _first_non_finite(x, v, 8) == (1, 7)
    assert box.first_outside(x) == 5 and box.outside(x)[7]  # NaN is outside too
    assert _first_non_finite(x, v, 3) == (0, 0)  # rows past n are not looked at


def test_stats_sums_and_cfl_speed_agree_with_numpy():
    """The stats row's one-pass sums (counts, kinetic energy, mass, front, top speed of
    the moving rows) and the stages' CFL speed, against the numpy formulas."""
    from parsph.core.particles import max_speed
    from parsph.step.stats import _row_sums
    rng = np.random.default_rng(5)
    n, dim = 200, 3
    phase = rng.integers(0, 3, n + 7).astype(np.int8)
    v, x, m = rng.normal(size=(n + 7, dim)), rng.normal(size=(n + 7, dim)), rng.uniform(1, 2, n + 7)
    e = np.array([0.6, 0.0, 0.8])
    got = _row_sums(phase, v, m, x, n, e)
    moving = phase[:n] != 2
    speed2 = (v[:n] ** 2).sum(axis=1)
    want = (n, (phase[:n] == 0).sum(), (phase[:n] == 1).sum(), (phase[:n] == 2).sum(),
            0.5 * (m[:n] * speed2)[moving].sum(), m[:n][moving].sum(),
            (x[:n] @ e)[moving].max(), speed2[moving].max())
    assert np.allclose(got, want, rtol=1e-13, atol=0.0)
    assert _row_sums(np.full(n, 2, np.int8), v, m, x, n, e)[6] == -np.inf  # nothing moves
    assert max_speed(v, n) == np.sqrt(speed2.max())
    assert max_speed(v, n, phase, 1) == np.sqrt(speed2[phase[:n] == 1].max())
    assert max_speed(v, n, phase[:n] == 0, True) == np.sqrt(speed2[phase[:n] == 0].max())
    assert max_speed(v, n, np.zeros(n, np.int8), 1) == 0.0
