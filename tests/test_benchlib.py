"""The benchmark jobs read their workers' output robustly (terminal codes from Open MPI's
pseudo-terminal, a missing line)."""
import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "jobs"))
from benchlib import worker_line  # noqa: E402


def test_worker_line_survives_terminal_codes():
    out = ("numba warming up\r\n\x1b[0mPARSPH 0.0123 8000 53.2 1800\r\n"
           "\x1b]0;title\x07\x1b[?25h\n")
    assert worker_line(out, "PARSPH ", "worker").split() == ["0.0123", "8000", "53.2", "1800"]
    # the last such line wins, and a tag in the middle of a line is found
    out = "PARSPH 1 2 3 4\n[1,0]<stdout>: \x1b[1mPARSPH 5 6 7 8\x1b[0m\n"
    assert worker_line(out, "PARSPH ", "worker") == "5 6 7 8"


def test_worker_line_names_the_worker_and_shows_its_output():
    with pytest.raises(SystemExit) as err:
        worker_line("Traceback (most recent call last):\n  boom\n", "PARSPH ", "parsph worker")
    text = str(err.value)
    assert "parsph worker" in text and "'PARSPH'" in text and "boom" in text


def test_done_line_gives_the_runs_figures_and_each_ranks_peak_memory():
    """jobs/benchlib.py reads a parsph run's ``done:`` line (from ranks' pseudo-terminals)
    for its steps, time, wall time and the peak memory of every rank; a line without the
    memory (an older parsph) is refused by name."""
    from benchlib import done_figures

    log = ("\x1b[0m12:00:01 0/2 INFO done: 168 steps to t = 0.100235 s in 21.84 s wall; "
           "peak memory 412 / 398 MiB per rank; output in out/db\r\n")
    assert done_figures(log, "run") == {"steps": 168, "t_end": 0.100235, "run_s": 21.84,
                                        "peak_rss_mib": [412.0, 398.0]}
    with pytest.raises(SystemExit, match="peak memory"):
        done_figures("INFO done: 3 steps to t = 0.1 s in 2.0 s wall; output in x\n", "run")


def test_splishsplash_fluid_block_matches_the_parsph_column(comm, tmp_path):
    """jobs/bench_splishsplash.py: both codes get n x n x 2n fluid particles at the same
    centres (k + 1/2) d (SPlisHSPlasH: x along, y up, z across; parsph: z up)."""
    import numpy as np

    from bench_splishsplash import A, block_axes, column_divisions, fluid_block, parsph_scene
    from parsph.scene.geometry import generate
    from parsph.scene.materials import PHASE_FLUID
    from parsph.scene.loader import load_scene
    from tests.scenes import gather_particles, write

    assert column_divisions(24000) == 23 and column_divisions(spacing=A / 37) == 37
    n, d = 5, A / 5
    axes = block_axes(*fluid_block(n), 0.5 * d)
    assert [len(a) for a in axes] == [n, 2 * n, n]
    _, x, phase = gather_particles(comm, generate(comm, load_scene(
        write(tmp_path, parsph_scene(n, 0.01)))))
    fluid = x[phase == PHASE_FLUID]
    assert len(fluid) == 2 * n ** 3
    for ax, block_ax in zip(range(3), (0, 2, 1)):
        assert np.allclose(np.unique(fluid[:, ax].round(12)), axes[block_ax])
        assert np.allclose(axes[block_ax], (np.arange(len(axes[block_ax])) + 0.5) * d)


def test_splishsplash_times_parsph_over_steps_2_to_n_as_the_peer(tmp_path):
    """jobs/bench_splishsplash.py times parsph as SPlisHSPlasH: the N steps at the mean cost
    of steps 2..N, from stats.csv's elapsed_s (here 3.0 s of build and a first step of
    1.0 s, then 0.5 s a step: 4 steps cost 2.0 s, not parsph's own 4.5 s)."""
    from bench_splishsplash import steps_time

    path = tmp_path / "stats.csv"
    path.write_text("step,time,elapsed_s\n1,0.1,4.0\n2,0.2,4.5\n3,0.3,5.0\n4,0.4,5.5\n")
    assert steps_time(str(path)) == pytest.approx(2.0)
    path.write_text("step,time,elapsed_s\n1,0.1,4.0\n")
    with pytest.raises(SystemExit, match="1 step"):
        steps_time(str(path))


def test_splishsplash_density_errors_read_the_peers_tolerance():
    """jobs/bench_splishsplash.py --density-error: 'peer' is SPlisHSPlasH's maxError (a
    percentage) as a fraction, 0 is parsph's rtol alone; anything else is refused."""
    from bench_splishsplash import density_errors, splishsplash_scene

    iisph = splishsplash_scene(5, "UnitBox.obj")["Configuration"]["IISPH"]
    assert density_errors("peer,1e-6,0", iisph) == [pytest.approx(1e-4), 1e-6, 0.0]
    assert density_errors("peer", {"maxError": 0.1}) == [pytest.approx(1e-3)]
    for bad in ("1", "-1e-4", "tight", "peer,,0"):
        with pytest.raises(SystemExit, match="--density-error"):
            density_errors(bad, iisph)


def test_splishsplash_flow_extent_is_not_moved_by_a_leading_particle():
    """jobs/bench_splishsplash.py compares where the two flows are: one particle that left
    the flow moves ``front`` (the largest x) but not ``front_p999``; ``top`` is read on the
    axis named up (parsph: z, SPlisHSPlasH: y)."""
    import numpy as np

    from bench_splishsplash import boundary_box, flow_extent

    x = np.zeros((4000, 3))
    x[:, 0] = np.linspace(0.0, 0.2, 4000)
    x[:, 2] = np.linspace(0.0, 0.1, 4000)
    base = flow_extent(x, up=2)
    x[-1, 0] = 0.5
    moved = flow_extent(x, up=2)
    assert moved["front"] == 0.5 and base["front"] == pytest.approx(0.2)
    assert moved["front_p999"] == pytest.approx(base["front_p999"], rel=1e-3)
    assert base["top"] == pytest.approx(0.1) and flow_extent(x[:, [0, 2, 1]], up=1) == moved
    lo, hi = boundary_box(10, 0.6)  # the peer's box 0.6 d outside parsph's wall planes
    assert lo[0] == pytest.approx(-0.6 * 0.146 / 10) and hi[1] == pytest.approx(0.35)


def test_splishsplash_record_keeps_both_tolerances(tmp_path, monkeypatch):
    """jobs/bench_splishsplash.py writes its own figures record: parsph at its default
    tolerance and at the peer's beside SPlisHSPlasH's, on the peer's core count only."""
    import argparse
    import json

    from bench_splishsplash import write_record

    monkeypatch.setenv("PARSPH_FIGURES", str(tmp_path))
    keys = ("steps", "run_s", "front", "front_p999", "top", "ratio_vs_splishsplash",
            "core_time_ratio_vs_splishsplash", "front_vs_splishsplash",
            "front_p999_vs_splishsplash", "top_vs_splishsplash", "peak_rss_mib_max",
            "bytes_per_particle_peak_rss")
    peer = dict({k: 1.0 for k in keys}, code="splishsplash", cores=1, fluid=24334,
                ppe_density_error=1e-4, initial_density_max=1.02, initial_density_floor=0.99)
    rows = [peer] + [dict({k: 2.0 + eta for k in keys}, code="parsph", cores=c,
                          ppe_density_error=eta) for c in (1, 2) for eta in (1e-4, 0.0)]
    args = argparse.Namespace(wall_offset=0.6, end_time=0.1, repeats=3, density_error="peer,0")
    write_record(rows, args, 23)
    rec = json.loads((tmp_path / "bench_splishsplash.json").read_text())
    fig = rec["figures"]
    assert fig["steps_peer"] == 1.0 and fig["steps_default"] == 2.0
    assert fig["core_time_ratio_vs_splishsplash_peer_eta"] == pytest.approx(2.0001)
    assert fig["initial_density_max_peer"] == 1.02 and rec["ranks"] == 1
    assert "--fluid-particles 24334" in rec["command"] and "venv" not in rec["command"]


def test_tlsph_and_memory_jobs_write_their_records(tmp_path, monkeypatch):
    """jobs/bench_tlsph.py and jobs/bench_memory.py write their own figures records: per
    rank count, from the rows they print (no figure typed in by hand)."""
    import argparse
    import json

    import bench_memory
    import bench_tlsph

    monkeypatch.setenv("PARSPH_FIGURES", str(tmp_path))
    rows = {(code, r): {"s_per_step": s, "bytes_per_particle": 1000.0, "particles": 97336,
                        "neighbours_per_particle": 53.0,
                        "ratio_vs_lammps": (0.5 / s if code == "parsph" else 1.0),
                        "speedup_1_to_2": (2.0 if code == "parsph" and r == 2 else "")}
            for code, r, s in (("parsph", 1, 0.14), ("parsph", 2, 0.07), ("lammps", 1, 0.5),
                               ("lammps", 2, 0.25))}
    bench_tlsph.write_record(rows, argparse.Namespace(particles=1e5, repeats=3, ranks="1,2"))
    fig = json.loads((tmp_path / "bench_tlsph.json").read_text())["figures"]
    assert fig["ratio_r1"] == pytest.approx(0.5 / 0.14) and fig["speedup_1_to_2"] == 2.0
    assert fig["lammps_s_per_step_r2"] == 0.25 and fig["particles"] == 97336

    runs = {(2, 1e6): (996454, {"s_per_step": 8.0, "bytes_per_particle_peak_rss": 1900.0}),
            (2, 1e5): (112761, {"s_per_step": 0.5, "bytes_per_particle_peak_rss": 4000.0})}
    bench_memory.write_record(runs, argparse.Namespace(particles=[1e5, 1e6], ranks=[2], steps=4))
    rec = json.loads((tmp_path / "bench_memory.json").read_text())
    assert rec["figures"] == {"particles": 996454, "s_per_step_r2": 8.0,
                              "bytes_per_particle_peak_rss_r2": 1900.0}
    assert rec["ranks"] == 2 and "--particles 1000000 --ranks 2" in rec["command"]


def test_overhead_fit_recovers_the_fixed_cost_and_the_slope():
    """jobs/bench_overhead.py: the intercept of s/step against particles is the fixed cost."""
    from bench_overhead import fit
    a, b = fit([(n, 2e-3 + 5e-6 * n) for n in (500, 1000, 2000, 4000)])
    assert a == pytest.approx(2e-3) and b == pytest.approx(5e-6)


@pytest.mark.parametrize("target", [2e4, 2e5, 1e6])
def test_memory_tank_has_about_the_particles_asked_for(tmp_path, target):
    """jobs/bench_memory.py: the 3D coupled tank at the size asked for (within the
    rounding of d to a whole number of particles across 0.1 m), both phases in it."""
    from bench_memory import scene

    from parsph.scene.geometry import estimate_count
    from parsph.step.pipeline import plan
    from parsph.scene.loader import load_scene

    text, d = scene(target)
    path = tmp_path / "tank.toml"
    path.write_text(text)
    sc = load_scene(str(path))
    assert sc.domain.dim == 3 and sc.domain.particle_size == d
    assert 0.6 * target < estimate_count(sc) < 1.6 * target
    assert [s.name for s in plan(sc)] == ["coupled"]


def test_landslide_parts_keep_each_ranks_rows_of_one_phase_and_the_walls(tmp_path):
    """jobs/bench_landslide.py: the solid-alone and fluid-alone checkpoints keep the rows
    of that phase and the walls, each in its writing rank's segment (counts recounted),
    and every other group (partitions, stage states) as it was."""
    import h5py
    import numpy as np

    from bench_landslide import derive
    from parsph.scene.materials import PHASE_FLUID, PHASE_SOLID, PHASE_WALL

    src, dst = str(tmp_path / "checkpoint.h5"), str(tmp_path / "solid.h5")
    phase = np.array([PHASE_SOLID, PHASE_FLUID, PHASE_WALL, PHASE_FLUID, PHASE_SOLID,
                      PHASE_SOLID, PHASE_WALL])
    with h5py.File(src, "w") as f:
        f.attrs["step"] = 7
        f.create_dataset("counts", data=np.array([4, 3]))
        f.create_dataset("fields/phase", data=phase)
        f.create_dataset("fields/id", data=np.arange(7) + 10)
        f.create_dataset("fields/x", data=np.arange(14.0).reshape(7, 2))
        f.create_dataset("rcb/cuts", data=np.array([0.5]))
        f.create_dataset("stages/coupled/n_fluidised", data=2)
    assert derive(src, dst, PHASE_SOLID) == 5
    with h5py.File(dst, "r") as g:
        assert g.attrs["step"] == 7
        assert list(g["counts"][...]) == [2, 3]  # rank 0 kept rows 0, 2; rank 1 rows 4-6
        assert list(g["fields/id"][...]) == [10, 12, 14, 15, 16]
        assert np.array_equal(g["fields/x"][...], np.arange(14.0).reshape(7, 2)[[0, 2, 4, 5, 6]])
        assert g["rcb/cuts"][0] == 0.5 and g["stages/coupled/n_fluidised"][()] == 2
    assert derive(src, dst, PHASE_FLUID) == 4
    with h5py.File(dst, "r") as g:
        assert list(g["counts"][...]) == [3, 1]
        assert list(g["fields/id"][...]) == [11, 12, 13, 16]


def test_landslide_record_merges_the_rank_counts(tmp_path, monkeypatch):
    """jobs/bench_landslide.py writes its own figures record: a 2-rank run's figures as
    r2_*, a 1-rank run's as r1_* beside them, and the speedup from the two once both
    are there from the same day; a rerun at one rank count replaces only its own."""
    import json

    from bench_landslide import STAGES, write_record

    monkeypatch.setenv("PARSPH_FIGURES", str(tmp_path))

    def figs(s):
        coupled = {"s_per_step_mean": s, "s_per_step_median": 0.9 * s,
                   "moving_particle_steps_per_s_per_core": 1e5 / s, "bytes_per_particle": 9e3,
                   "particles": 1000, "moving_particles": 700.0, "fluid_particles": 50.0,
                   "peak_rss_mib_rank0": 400.0, **{f"s_per_step_{k}": 0.01 for k in STAGES}}
        return {"coupled": coupled, "solid_alone": {"s_per_step_mean": s / 2},
                "fluid_alone": {"s_per_step_mean": s / 4}}

    def figures():
        with open(tmp_path / "bench_landslide.json") as fh:
            rec = json.load(fh)
        return rec["ranks"], rec["figures"]

    write_record(2, figs(0.3), 1.5, 1.9)
    ranks, fig = figures()
    assert ranks == 2 and fig["r2_s_per_step"] == 0.3 and "speedup_1_to_2" not in fig
    assert fig["r2_over_parts"] == 1.5 and fig["r2_solid_alone_s_per_step"] == 0.15
    write_record(1, figs(0.48), 1.2, 1.4)
    ranks, fig = figures()
    assert ranks == 2 and fig["r2_s_per_step"] == 0.3 and fig["r1_s_per_step"] == 0.48
    assert abs(fig["speedup_1_to_2"] - 1.6) < 1e-12
    write_record(2, figs(0.24), 1.5, 1.9)
    ranks, fig = figures()
    assert fig["r2_s_per_step"] == 0.24 and abs(fig["speedup_1_to_2"] - 2.0) < 1e-12
