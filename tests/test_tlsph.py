"""TLSPH solid: corrected gradient, elastic plate, triaxial path, 1 vs 2 ranks by global id."""
import csv
import os

import numpy as np
import pytest

from jobs.figures import record
from parsph.io import read_frame
from parsph.core.neighbours import build_csr
from parsph.step.run import run
from parsph.scene.loader import load_scene
from parsph.solid import kernels
from parsph.verify.solid import csl_distance
from parsph.solid.stage import TLSPH
from tests.scenes import (assert_energy_balance, first_and_last, hencky, initial, last_frame,
                          load_shared, run_on_one_and_two, scene_text, stats_rows, wall, write)


def _lattice(dim, n, d, jitter=0.0, seed=1):
    g = np.stack(np.meshgrid(*[np.arange(n)] * dim, indexing="ij"), -1).reshape(-1, dim)
    x = (g + 0.5) * d
    if jitter:
        x += np.random.default_rng(seed).uniform(-jitter, jitter, x.shape) * d
    return x


@pytest.mark.parametrize("dim,jitter", [(2, 0.0), (3, 0.0), (2, 0.2), (3, 0.15)])
def test_corrected_gradient_reproduces_linear_fields(dim, jitter):
    """grad of a linear field and F-dot of a linear velocity are exact everywhere."""
    d = 0.1
    h = 1.2 * d
    X = _lattice(dim, 7 if dim == 2 else 5, d, jitter)
    n = len(X)
    indptr, indices = build_csr(X, n, 2 * h)
    sel = np.ones(n, dtype=bool)
    vol = np.full(n, d ** dim)
    L = np.zeros((n, 3, 3))
    clamped = kernels.correction_matrices(X, vol, sel, n, indptr, indices, h, dim, 0.05, L)
    assert clamped == 0
    a = np.array([0.3, -1.7, 2.2])[:dim]
    f = X @ a + 4.0
    grad = np.zeros((n, dim))
    kernels.gradient(f, X, vol, L, sel, n, indptr, indices, h, dim, grad)
    assert np.allclose(grad, a, rtol=0, atol=1e-10)  # boundary rows included
    A = np.array([[0.1, -0.4, 0.3], [0.7, 0.2, -0.5], [0.0, 0.6, 0.9]])[:dim, :dim]
    X3 = TLSPH._pad(X)
    v3 = TLSPH._pad(X @ A.T)
    fp = kernels.pair_factors(X, sel, n, indptr, indices, h, dim)
    fdot = np.zeros((n, 3, 3))
    kernels.velocity_gradient(v3, X3, vol, L, fp, n, indptr, indices, fdot)
    assert np.allclose(fdot[:, :dim, :dim], A, rtol=0, atol=1e-10)


def test_stress_divergence_conserves_momentum():
    """Pair forces are antisymmetric: the total internal force vanishes for any stress."""
    d, dim = 0.1, 2
    h = 1.2 * d
    X = _lattice(dim, 6, d, 0.2)
    n = len(X)
    indptr, indices = build_csr(X, n, 2 * h)
    sel = np.ones(n, dtype=bool)
    fp = kernels.pair_factors(X, sel, n, indptr, indices, h, dim)
    Q = np.random.default_rng(3).normal(size=(n, 3, 3))
    Q[:, 2, :] = Q[:, :, 2] = 0.0
    out = np.zeros((n, 3))
    m = np.full(n, 2.0)
    kernels.stress_divergence(Q, TLSPH._pad(X), m, fp, n, indptr, indices, out)
    force = (m[:, None] * out).sum(axis=0)
    assert np.abs(force).max() < 1e-10 * np.abs(m[:, None] * out).max()




@pytest.mark.parametrize("dim", [2, 3])
def test_jst_fourth_order_pass_from_stored_pairs(dim):
    """The nabla^4 pass of eq. (12) over the pair terms the nabla^2 pass stored equals the
    Laplacian applied to its own output, on a stretched lattice (some reference pairs now
    beyond 2h), with two densities; the first pass is unchanged by storing."""
    d = 0.1
    h = 1.2 * d
    X = _lattice(dim, 7 if dim == 2 else 5, d, 0.2)
    n = len(X)
    indptr, indices = build_csr(X, n, 2 * h)
    sel = np.ones(n, dtype=bool)
    fp = kernels.pair_factors(X, sel, n, indptr, indices, h, dim)
    rng = np.random.default_rng(5)
    x = TLSPH._pad(X * rng.uniform(0.9, 1.15, dim))
    v = TLSPH._pad(rng.normal(size=(n, dim)))
    m = np.full(n, 2.0)
    rho = np.where(np.arange(n) % 3 == 0, 1800.0, 1000.0)
    args = (fp, n, indptr, indices, h, dim)
    lap, plain, lap4, ref = (np.zeros((n, 3)) for _ in range(4))
    coef = np.full(len(indices), np.nan)
    kernels.laplacian(v, x, m, rho, *args, lap, coef)
    kernels.laplacian(v, x, m, rho, *args, plain, np.empty(0))
    assert np.array_equal(lap, plain) and not np.isnan(coef).any()
    assert (coef == 0.0).sum() > (fp == 0.0).sum()  # pairs stretched beyond 2h
    kernels.laplacian_stored(lap, x, coef, n, indptr, indices, lap4)
    kernels.laplacian(lap, x, m, rho, *args, ref, np.empty(0))
    assert np.abs(lap4 - ref).max() <= 1e-12 * np.abs(ref).max()
PLATE_H12 = 0.02 / 12  # particle size of the plate test: 12 particles across H


@pytest.mark.mpi(min_size=2)  # the 2-rank session (CI time: the same physics on 1 rank)
def test_elastic_plate_period_and_energy(comm, mpi_tmp_path):
    """Half a period of the clamped plate (d = H/12) vs 2D elasticity; energy bounded."""
    from parsph.verify.solid import plate_period_error, plate_reference_period, \
        thin_plate_period, tip_period

    scene = load_scene("elastic_plate", [f"domain.particle_size={PLATE_H12!r}",
                                         "run.end_time=0.16", "output.every=0.004",
                                         "output.progress=false"])
    out = os.path.join(mpi_tmp_path, "plate")
    run(scene, out, comm=comm, progress=False)
    if comm.rank == 0:
        period = plate_reference_period(scene)
        assert period == pytest.approx(1.0047 * thin_plate_period(2e6, 0.3975, 1e3, 0.02, 0.2))
        measured = tip_period(out)
        # +3.2 % at H/12 (+6.1 % at H/8, +2.0 % at H/16: first-order surface error of the
        # corrected gradient, docs/tlsph.md); converges from above
        assert period < measured < 1.04 * period
        assert plate_period_error(scene, out) == pytest.approx(measured / period - 1.0)
        rows = stats_rows(out)
        energy = np.array([float(r["kinetic_energy"]) + float(r["elastic_energy"]) for r in rows])
        assert energy.max() <= energy[0] * 1.005  # never grows
        assert energy[-1] >= energy[0] * 0.97     # JST removes little
        # the balance (kinetic + elastic + hourglass): the symplectic step's O((omega
        # dt)^2) error of the fastest modes, measured 6.8e-6 of the peak kinetic energy
        assert_energy_balance(rows, 2e-5, 2e-5, "elastic plate, H/12")


def _zero_crossings(run_dir):
    """Times of the downward zero crossings of the plate tip's transverse displacement
    (the tip of :func:`parsph.verify.solid.tip_period`), linear between frames."""
    from parsph.io import read_frames

    h5 = os.path.join(run_dir, "particles.h5")
    first = read_frame(h5, 0)
    X = first["x"][np.argsort(first["id"])]
    tip = np.argmin(np.abs(X[:, 0] - X[:, 0].max()) + np.abs(X[:, 1]))
    t, y = [], []
    for step, time in read_frames(h5):
        f = read_frame(h5, step)
        t.append(time)
        y.append(f["x"][np.argsort(f["id"])][tip, 1] - X[tip, 1])
    t, y = np.array(t), np.array(y)
    k = np.nonzero((y[:-1] > 0) & (y[1:] <= 0))[0]
    return t[k] + (t[k + 1] - t[k]) * y[k] / (y[k] - y[k + 1])


@pytest.mark.slow
@pytest.mark.mpi(min_size=2)
def test_elastic_plate_scene_over_three_periods(comm, mpi_tmp_path):
    """The built-in ``elastic_plate`` as it is (d = H/12, to 0.75 s, about three periods;
    the README's figures): the period from the first crossing is long by less than 4 %
    against 2D plane-strain elasticity (first-order surface error, converging from above;
    measured +3.2 %) and the same from every later crossing to 0.1 %; the energy (kinetic
    + Hencky) never rises above its start by more than 0.5 % and loses at most 2 % over the
    three periods (twice the 1 % stated; JST's loss, docs/tlsph.md)."""
    from parsph.verify.solid import plate_reference_period, tip_period

    scene = load_scene("elastic_plate", ["output.progress=false"])
    out = os.path.join(mpi_tmp_path, "plate")
    run(scene, out, comm=comm, progress=False)
    if comm.rank != 0:
        return
    reference = plate_reference_period(scene)
    error = tip_period(out) / reference - 1.0
    crossings = _zero_crossings(out)
    periods = np.diff(crossings)
    rows = stats_rows(out)
    energy = np.array([float(r["kinetic_energy"]) + float(r["elastic_energy"]) for r in rows])
    t = np.array([float(r["time"]) for r in rows])
    record("elastic_plate", {
        "particles": int(rows[-1]["n_particles"]), "steps": len(rows), "end_time_s": t[-1],
        "reference_period_s": reference, "period_s": tip_period(out),
        "period_error_pc": 100 * error, "crossings": len(crossings),
        "period_spread_pc": 100 * (periods.max() - periods.min()) / reference,
        "periods_run": t[-1] / reference,
        "energy_max_rise_pc": 100 * (energy.max() / energy[0] - 1),
        "energy_change_end_pc": 100 * (energy[-1] / energy[0] - 1)}, ranks=comm.size)
    assert 0.0 < error < 0.04
    assert t[-1] >= 2.9 * reference and len(crossings) >= 3
    assert np.all(np.abs(periods / (2 * crossings[0]) - 1) < 1e-3)
    assert energy.max() <= 1.005 * energy[0]
    assert energy.min() >= 0.98 * energy[0]


TRIAXIAL_FAST = ["domain.particle_size=0.01", "constraints.1.velocity=[0.0, 0.0, -0.25]",
                 "run.end_time=0.12", "output.every=0.06", "output.progress=false"]


@pytest.mark.parametrize("scene_name,p0", [("triaxial_light", 400e3), ("triaxial_heavy", 100e3)])
def test_triaxial_drained_path(comm, mpi_tmp_path, scene_name, p0):
    """Coarse, faster triaxial: q = 3 (p' - p'0) all along; ends near the CSL q = M p'."""
    scene = load_scene(scene_name, TRIAXIAL_FAST)
    out = os.path.join(mpi_tmp_path, scene_name)
    run(scene, out, comm=comm, progress=False)
    if comm.rank == 0:
        rows = stats_rows(out)
        p = np.array([float(r["p_eff"]) for r in rows])
        q = np.array([float(r["q"]) for r in rows])
        strain = np.array([float(r["axial_strain"]) for r in rows])
        assert 0.28 < strain[-1] < 0.35  # platen travel over the distance between platens
        # (5 % of p0: the start-up wave of the abrupt, 5x faster platen of this test)
        assert np.allclose(q, 3 * (p - p0), rtol=0, atol=0.05 * p0 + 0.02 * q)
        M = float(rows[-1]["M"])
        if p0 == 400e3:  # hardening: approaches (600, 600) kPa from below
            assert csl_distance(p[-1], q[-1], M) < 0.08
            assert q.max() <= 1.02 * M * 600e3
        else:  # over-consolidated: peaks above the CSL, then softens towards it
            assert q.max() > 1.2 * M * p[np.argmax(q)]
            assert q[-1] < 0.9 * q.max()
        from parsph.verify.solid import triaxial_csl_error, triaxial_end
        from parsph.solid.triaxial import HEADER, write_from_stats

        with open(write_from_stats(out)) as fh:
            table = list(csv.reader(fh))
        assert tuple(table[0]) == HEADER and len(table) == len(rows) + 1
        assert triaxial_end(out)["q"] == pytest.approx(q[-1])
        assert triaxial_csl_error(scene, out) == pytest.approx(csl_distance(p[-1], q[-1], M))
        v = np.array([float(r["spec_volume"]) for r in rows])
        assert v[0] == pytest.approx(2.0, rel=1e-3)
        assert (v[-1] > v[0]) == (p0 == 100e3)  # heavy dilates, light compacts


def _yield_on_the_drained_path(p0, pc, M):
    """``(p', q)`` where q = 3 (p' - p'0) meets the initial modified Cam-Clay surface
    q^2 = M^2 p' (pc - p'): the peak of a single material point of the heavy test."""
    # 9 (p - p0)^2 = M^2 p (pc - p):  (9 + M^2) p^2 - (18 p0 + M^2 pc) p + 9 p0^2 = 0; the
    # larger root is on the compression side of the path (p' > p'0, q > 0)
    a, b, c = 9.0 + M * M, -(18.0 * p0 + M * M * pc), 9.0 * p0 * p0
    p = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    return p, 3.0 * (p - p0)


@pytest.mark.slow
@pytest.mark.mpi(min_size=2)
@pytest.mark.parametrize("scene_name,p0", [("triaxial_light", 400e3), ("triaxial_heavy", 100e3)])
def test_triaxial_scenes_follow_the_drained_path(comm, mpi_tmp_path, scene_name, p0):
    """The built-in triaxial scenes as they are (d = 5 mm, 30 % axial strain; the README's
    figures): q = 3 (p' - p'0) within 2.4 kPa all along (twice the 1.2 kPa stated), the end
    point within twice its measured distance from the critical state line (light 0.04,
    heavy 0.02: at most 0.08 and 0.04), the light specimen compacts, the heavy one peaks
    within 8 % below where the drained path meets the initial yield surface (281 kPa; a
    single material point peaks there, the specimen's mean a little lower, measured 270
    kPa), then softens and dilates."""
    scene = load_scene(scene_name, ["output.progress=false"])
    out = os.path.join(mpi_tmp_path, scene_name)
    run(scene, out, comm=comm, progress=False)
    if comm.rank != 0:
        return
    rows = stats_rows(out)
    p, q, v, strain = (np.array([float(r[k]) for r in rows])
                       for k in ("p_eff", "q", "spec_volume", "axial_strain"))
    M = float(rows[-1]["M"])
    path = np.abs(q - 3 * (p - p0)).max()
    end = csl_distance(p[-1], q[-1], M)
    peak = int(np.argmax(q))
    record(scene_name, {"particles": int(rows[-1]["n_particles"]), "steps": len(rows),
                        "path_error_kpa": path / 1e3, "end_axial_strain": strain[-1],
                        "end_p_kpa": p[-1] / 1e3, "end_q_kpa": q[-1] / 1e3,
                        "end_q_over_mp": q[-1] / (M * p[-1]), "csl_distance": end,
                        "peak_q_kpa": q[peak] / 1e3, "peak_p_kpa": p[peak] / 1e3,
                        "peak_axial_strain": strain[peak], "end_spec_volume": v[-1]},
           ranks=comm.size)
    assert 0.28 < strain[-1] < 0.32
    assert path < 2.4e3
    if p0 == 400e3:  # hardening towards (600, 600) kPa, compacting
        assert end < 0.08 and q.max() <= 1.02 * M * 600e3 and v[-1] < v[0]
    else:  # peaks near first yield, then softens towards the CSL, dilating
        _, q_yield = _yield_on_the_drained_path(p0, scene.materials["clay"].preconsolidation, M)
        assert 0.92 * q_yield < q[peak] <= q_yield
        assert end < 0.04 and q[-1] < 0.9 * q[peak] and v[-1] > v[0]


BLOCK = scene_text(
    "block", 0.05, [-0.2, -0.3], [1.4, 1.0], 0.02, 0.01, run={"max_steps": 40},
    solid={"wall_friction": 0.3},
    materials={"soil": {"model": "drucker_prager", "density": 2000.0, "poisson_ratio": 0.3,
                        "young_modulus": 5.0e6, "friction_angle": 30.0, "cohesion": 2.0e3,
                        "hardening": -1.0e3}},
    bodies=[{"name": "block", "material": "soil", "shape": "polygon",
             "vertices": [[0.0, 0.0], [1.2, 0.0], [1.2, 0.4], [0.3, 0.8], [0.0, 0.8]],
             "velocity": [0.5, -0.3]}],
    walls=[wall("floor", [-0.15, -0.15], [1.35, 0.0])],
    constraints=[initial("spin", "rigid_rotation", [0.0, 0.3], [1.2, 0.8], centre=[0.6, 0.4],
                         omega=3.0)])


@pytest.mark.mpi
def test_deforming_block_one_vs_two_ranks(comm, mpi_tmp_path):
    """The keystone comparison on a deforming, yielding block touching a wall: positions
    by global id to 1e-10 relative (the README's figure: round-off only; an explicit
    TLSPH step sums the same terms on either rank count, in another order)."""
    scene = load_shared(comm, mpi_tmp_path, BLOCK, name="block.toml")
    one, two = run_on_one_and_two(comm, scene, mpi_tmp_path)
    if comm.rank == 0:
        a, b = last_frame(one), last_frame(two)
        record("one_vs_two_tlsph", {"max_dx_m": np.abs(a["x"] - b["x"]).max(),
                                    "max_dv_m_s": np.abs(a["v"] - b["v"]).max()},
               ranks=comm.size)
        assert np.array_equal(a["id"], b["id"])
        start = read_frame(os.path.join(one, "particles.h5"), 0)
        moved = np.abs(a["x"] - start["x"][np.argsort(start["id"])]).max()
        assert moved > 0.005
        assert np.allclose(a["x"], b["x"], rtol=1e-10, atol=1e-12)
        assert np.allclose(a["v"], b["v"], rtol=1e-8, atol=1e-10)
        assert np.allclose(a["p"], b["p"], rtol=1e-7, atol=1e-4)
        assert a["eps_p"].max() > 0
        assert set(np.unique(b["rank"])) == {0, 1}


HELD_BASE = scene_text(
    "held_base", 0.05, [-0.1, -0.1], [1.1, 1.0], 0.05, g=[0.0, -9.81],
    materials={"soft": hencky(1000.0, 1.0e5)},
    bodies=[{"name": "base", "material": "soft", "shape": "polygon",
             "vertices": [[0.0, 0.0], [1.0, 0.0], [1.0, 0.1], [0.0, 0.3]]},
            {"name": "block", "material": "soft", "shape": "box", "lo": [0.0, 0.3],
             "hi": [1.0, 0.6]}],
    constraints=[{"name": "rock", "bodies": ["base"], "velocity": [0.0, 0.0]}])


def test_constraint_selects_named_bodies(comm, mpi_tmp_path):
    """``[[constraints]] bodies``: every particle of the named body is held, whatever its
    shape (the ``aso`` scene's bedrock follows the terrain: no box selects it), and no
    other; a box and bodies together select their intersection; an unknown body is
    refused naming the key."""
    from parsph.errors import SceneError
    from parsph.scene.params_solid import Constraint
    from parsph.solid.boundary import velocity_masks

    scene = load_shared(comm, mpi_tmp_path, HELD_BASE, name="held.toml")
    run(scene, os.path.join(mpi_tmp_path, "out"), comm=comm, progress=False)
    if comm.rank == 0:
        start, end = first_and_last(os.path.join(mpi_tmp_path, "out"))
        base = start["x"][:, 1] < 0.3  # the polygon's points
        moved = np.linalg.norm(end["x"] - start["x"], axis=1)
        assert moved[base].max() == 0.0
        assert moved[~base].max() > 1e-3  # the block settles under gravity
    x = np.array([[0.5, 0.1], [0.5, 0.5], [1.5, 0.1]])
    c = Constraint(name="c", lo=(0.0, 0.0), hi=(1.0, 1.0), bodies=("base",), velocity=(0.0, 0.0))
    mask, _ = velocity_masks([c], x, np.ones(3, bool), np.array([0, 1, 0]), ["base", "block"])
    assert mask[:, 0].tolist() == [True, False, False]  # in the box and in the body
    bad = HELD_BASE.replace('bodies = ["base"]', 'bodies = ["bedrock"]')
    with pytest.raises(SceneError, match=r"constraints\[0\]\.bodies'.*no body 'bedrock'"):
        load_scene(write(mpi_tmp_path, bad, f"bad{comm.rank}.toml"))
    none = HELD_BASE.replace('bodies = ["base"]\n', "")
    with pytest.raises(SceneError, match=r"constraints\[0\]\.lo'.*in a box \(lo and hi\) or"):
        load_scene(write(mpi_tmp_path, none, f"none{comm.rank}.toml"))
