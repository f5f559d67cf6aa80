"""solvers: distributed sparse systems on PETSc, checked against scipy direct solves.

Every rank builds the triplets of its own contiguous block of rows; the reference matrix
is built identically, in full, on every rank. Assertions hold at any rank count.
"""
import os
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import solvers
from parsph.errors import NumericalError
from solvers import LinearSystem, SolverError, petsc_env

pytestmark = pytest.mark.petsc

#: Tolerance of the KSP when a test compares with a direct solve, and of the comparison.
KSP_RTOL_EXACT = 1e-13
COMPARE_RTOL = 1e-10


def block_rows(comm, n_points):
    """Points owned by this rank when ``n_points`` are split in contiguous blocks."""
    return n_points // comm.size + (comm.rank < n_points % comm.size)


def poisson_triplets(n, rows, neumann=False):
    """Rows ``rows`` of the 5-point Laplacian on an ``n`` x ``n`` grid (unit spacing).

    Dirichlet (diagonal 4) by default; ``neumann`` puts the neighbour count on the
    diagonal, which makes the constant the null space.
    """
    rows = np.asarray(rows, dtype=np.int64)
    i, j = np.divmod(rows, n)
    r, c, v = [], [], []
    degree = np.zeros(rows.size)
    for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        ii, jj = i + di, j + dj
        inside = (ii >= 0) & (ii < n) & (jj >= 0) & (jj < n)
        degree += inside
        r.append(rows[inside])
        c.append((ii * n + jj)[inside])
        v.append(np.full(inside.sum(), -1.0))
    r.append(rows)
    c.append(rows)
    v.append(degree if neumann else np.full(rows.size, 4.0))
    return np.concatenate(r), np.concatenate(c), np.concatenate(v)


def full_matrix(n_global, triplets):
    rows, cols, values = triplets
    return sp.coo_matrix((values, (rows, cols)), shape=(n_global, n_global)).tocsr()


def rhs_of(n_global):
    return np.random.default_rng(7).uniform(-1.0, 1.0, n_global)


def assert_matches(x, reference):
    scale = np.abs(reference).max(initial=0.0)
    np.testing.assert_allclose(x, reference, rtol=COMPARE_RTOL, atol=COMPARE_RTOL * scale)


def solve_poisson(comm, n, **kwargs):
    """Assemble and solve the Dirichlet Poisson problem; return (system, x, info, slice)."""
    system = LinearSystem(comm, "tst_", block_rows(comm, n * n), **kwargs)
    first, stop = system.owned_range
    system.assemble(*poisson_triplets(n, np.arange(first, stop)))
    x, info = system.solve(rhs_of(n * n)[first:stop])
    return system, x, info, slice(first, stop)


@pytest.mark.serial_only
def test_import_does_not_load_petsc():
    code = "import sys, solvers; assert 'petsc4py' not in sys.modules, sorted(sys.modules)"
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


def test_cg_boomeramg_matches_direct_solve(comm):
    n = 64
    system, x, info, owned = solve_poisson(comm, n, rtol=KSP_RTOL_EXACT)
    with system:
        assert system.ksp.getType() == "cg"
        assert system.ksp.getPC().getType() == "hypre"
        reference = spla.spsolve(full_matrix(n * n, poisson_triplets(n, np.arange(n * n))), rhs_of(n * n))
        assert_matches(x, reference[owned])
        assert info["reason"] > 0 and info["reason_name"].startswith("CONVERGED")
        assert info["iterations"] <= 20
        assert info["time_s"] >= 0.0 and info["residual_norm"] >= 0.0


def test_boomeramg_iterations_flat_under_refinement(comm):
    iterations = []
    for n in (64, 256):
        system, _, info, _ = solve_poisson(comm, n)
        system.destroy()
        iterations.append(info["iterations"])
    assert iterations[1] <= 1.5 * iterations[0], iterations


def test_duplicates_are_summed(comm):
    n = 24
    with LinearSystem(comm, "tst_", block_rows(comm, n * n), rtol=KSP_RTOL_EXACT) as system:
        first, stop = system.owned_range
        rows, cols, values = poisson_triplets(n, np.arange(first, stop))
        order = np.random.default_rng(comm.rank).permutation(2 * rows.size)
        doubled = (np.concatenate([rows, rows])[order].astype(np.int32),
                   np.concatenate([cols, cols])[order].astype(np.int32),
                   np.concatenate([0.25 * values, 0.75 * values])[order])
        system.assemble(*doubled)
        x, _ = system.solve(rhs_of(n * n)[first:stop])
        reference = spla.spsolve(full_matrix(n * n, poisson_triplets(n, np.arange(n * n))), rhs_of(n * n))
        assert_matches(x, reference[first:stop])


def coupled_triplets(n, points, coupling):
    """Rows of points ``points`` of kron(L, coupling): a 2-component operator, interleaved."""
    r, c, v = poisson_triplets(n, points)
    bs = coupling.shape[0]
    a, b = np.divmod(np.arange(bs * bs), bs)
    rows = (r[:, None] * bs + a).ravel()
    cols = (c[:, None] * bs + b).ravel()
    values = (v[:, None] * coupling.ravel()).ravel()
    return rows, cols, values


def test_block_size_two_gmres_matches_direct_solve(comm):
    n, bs = 24, 2
    coupling = np.array([[2.0, -1.0], [0.5, 2.0]])  # not symmetric: GMRES
    n_points = block_rows(comm, n * n)
    with LinearSystem(comm, "tst_", n_points, block_size=bs, ksp_type="gmres",
                      rtol=KSP_RTOL_EXACT) as system:
        assert system.symmetric is False
        first, stop = system.owned_range
        assert (first % bs, stop - first) == (0, n_points * bs)
        system.assemble(*coupled_triplets(n, np.arange(first // bs, stop // bs), coupling))
        assert system.mat.getBlockSize() == bs
        rhs = rhs_of(bs * n * n)[first:stop].reshape(-1, bs)
        x, info = system.solve(rhs)
        assert x.shape == rhs.shape
        full = full_matrix(bs * n * n, coupled_triplets(n, np.arange(n * n), coupling))
        assert_matches(x.ravel(), spla.spsolve(full, rhs_of(bs * n * n))[first:stop])


def test_same_pattern_reuses_matrix(comm):
    n = 32
    total = n * n
    with LinearSystem(comm, "tst_", block_rows(comm, total), rtol=KSP_RTOL_EXACT) as system:
        first, stop = system.owned_range
        rows, cols, values = poisson_triplets(n, np.arange(first, stop))
        system.assemble(rows, cols, values)
        system.solve(rhs_of(total)[first:stop])
        mat, ksp = system.mat, system.ksp

        new_values = 2.0 * values + (rows == cols) * 0.5  # same pattern, new values
        system.assemble(rows, cols, new_values)
        assert system.mat is mat and system.ksp is ksp and system.n_builds == 1
        x, _ = system.solve(rhs_of(total)[first:stop])
        full_rows, full_cols, full_values = poisson_triplets(n, np.arange(total))
        reference = spla.spsolve(
            full_matrix(total, (full_rows, full_cols, 2.0 * full_values + (full_rows == full_cols) * 0.5)),
            rhs_of(total),
        )
        assert_matches(x, reference[first:stop])

        order = np.random.default_rng(1 + comm.rank).permutation(rows.size)  # same pattern, reordered
        system.assemble(rows[order], cols[order], new_values[order])
        assert system.mat is mat and system.n_builds == 1
        x, _ = system.solve(rhs_of(total)[first:stop])
        assert_matches(x, reference[first:stop])


def test_pattern_change_on_one_rank_rebuilds_everywhere(comm):
    n = 32
    total = n * n
    with LinearSystem(comm, "tst_", block_rows(comm, total), ksp_type="gmres", rtol=KSP_RTOL_EXACT) as system:
        first, stop = system.owned_range
        system.assemble(*poisson_triplets(n, np.arange(first, stop)))
        system.solve(rhs_of(total)[first:stop])
        old = system.mat

        last_first = comm.allgather(first)[-1]  # the last rank adds couplings (i, i + 2)

        def with_extra(rows_wanted):
            rows, cols, values = poisson_triplets(n, rows_wanted)
            extra = rows_wanted[(rows_wanted >= last_first) & (rows_wanted + 2 < total)]
            return (np.concatenate([rows, extra]), np.concatenate([cols, extra + 2]),
                    np.concatenate([values, np.full(extra.size, 0.3)]))

        system.assemble(*with_extra(np.arange(first, stop)))
        assert system.mat is not old and system.n_builds == 2
        x, _ = system.solve(rhs_of(total)[first:stop])
        reference = spla.spsolve(full_matrix(total, with_extra(np.arange(total))), rhs_of(total))
        assert_matches(x, reference[first:stop])


def test_options_prefix_overrides_defaults(comm):
    PETSc = petsc_env.petsc()
    options = PETSc.Options()
    options.setValue("tst_ksp_type", "gmres")
    options.setValue("tst_ksp_rtol", "1e-9")
    try:
        with LinearSystem(comm, "tst", 4) as system:
            assert system.prefix == "tst_"
            assert system.ksp.getOptionsPrefix() == "tst_"
            assert system.ksp.getType() == "gmres"
            assert system.ksp.getTolerances()[0] == pytest.approx(1e-9)
    finally:
        options.delValue("tst_ksp_type")
        options.delValue("tst_ksp_rtol")
    with LinearSystem(comm, "tst_", 4) as system:
        assert system.ksp.getType() == "cg"


def test_non_convergence_raises_on_every_rank(comm):
    n = 32
    with LinearSystem(comm, "tst_", block_rows(comm, n * n), pc_type="jacobi", rtol=1e-14, max_it=1) as system:
        first, stop = system.owned_range
        system.assemble(*poisson_triplets(n, np.arange(first, stop)))
        with pytest.raises(SolverError, match="DIVERGED_MAX_IT") as excinfo:
            system.solve(rhs_of(n * n)[first:stop])
    message = str(excinfo.value)
    assert isinstance(excinfo.value, NumericalError)
    assert "'tst_'" in message and "1 iterations" in message and "-tst_pc_type" in message


def test_rows_not_owned_raise_value_error_on_every_rank(comm):
    with LinearSystem(comm, "tst_", block_rows(comm, 100)) as system:
        first, stop = system.owned_range
        rows = np.arange(first, stop + 1)  # one row past the owned block, on every rank
        stop_0 = comm.allgather(stop)[0]  # every rank raises rank 0's error
        with pytest.raises(ValueError, match=f"rank 0: .*rows in {stop_0}..{stop_0}"):
            system.assemble(rows, rows, np.ones(rows.size))
        assert system.mat is None

        rows = np.arange(first, stop) if comm.rank else np.arange(first, stop) - 1
        with pytest.raises(ValueError, match="rank 0: .*rows in -1..-1"):  # rank 0 only
            system.assemble(rows, rows, np.ones(rows.size))

        rows = np.arange(first, stop)
        with pytest.raises(ValueError, match="columns"):
            system.assemble(rows, rows + system.n_global, np.ones(rows.size))
        with pytest.raises(SolverError, match="NaN"):
            system.assemble(rows, rows, np.full(rows.size, np.nan))
        system.assemble(rows, rows, np.ones(rows.size))
        with pytest.raises(ValueError, match="rhs has"):
            system.solve(np.ones(rows.size + 1))


def test_initial_guess_is_used(comm):
    system, x, info, owned = solve_poisson(comm, 32)
    with system:
        assert info["iterations"] > 0
        x_again, info_again = system.solve(rhs_of(32 * 32)[owned], x0=x)
        assert info_again["iterations"] == 0
        np.testing.assert_array_equal(x_again, x)


def test_right_preconditioned_solve_stops_at_an_absolute_true_residual(comm):
    """pc_side="right": the KSP tests the true residual, so an atol in the equation's
    units bounds ||b - A x|| (the PPE's density-error tolerance); the left side's test
    is on the preconditioned residual. A bad side is refused before any work."""
    n = 32
    full = full_matrix(n * n, poisson_triplets(n, np.arange(n * n)))
    b = rhs_of(n * n)
    for side, atol in (("right", 1e-3), ("right", 1e-6), ("left", 1e-50)):
        system = LinearSystem(comm, "tst_", block_rows(comm, n * n), ksp_type="gmres",
                              rtol=1e-12, atol=atol, pc_side=side)
        with system:
            first, stop = system.owned_range
            system.assemble(*poisson_triplets(n, np.arange(first, stop)))
            x, info = system.solve(b[first:stop])
            whole = np.concatenate(comm.allgather(x))
            true = np.linalg.norm(b - full @ whole)
            if side == "right":
                assert info["reason_name"] == "CONVERGED_ATOL"
                assert true <= atol * (1 + 1e-6)
                assert info["residual_norm"] == pytest.approx(true, rel=1e-6)
            else:
                assert info["reason_name"] == "CONVERGED_RTOL"
                assert info["residual_norm"] != pytest.approx(true, rel=1e-2)
    with pytest.raises(ValueError, match="pc_side is 'left' or 'right'"):
        LinearSystem(comm, "tst_", 4, pc_side="up")


def test_constant_nullspace_neumann(comm):
    n = 16
    total = n * n
    with LinearSystem(comm, "tst_", block_rows(comm, total), rtol=KSP_RTOL_EXACT) as system:
        system.set_nullspace_constant()
        first, stop = system.owned_range
        system.assemble(*poisson_triplets(n, np.arange(first, stop), neumann=True))
        rhs = rhs_of(total)  # not consistent: PETSc removes the constant part
        x, _ = system.solve(rhs[first:stop])
        x -= comm.allreduce(x.sum()) / total
        dense = full_matrix(total, poisson_triplets(n, np.arange(total), neumann=True)).toarray()
        reference = np.linalg.lstsq(dense, rhs - rhs.mean(), rcond=None)[0]
        assert_matches(x, reference[first:stop] - reference.mean())


def test_rank_without_rows_takes_part(comm):
    n = 16
    total = n * n
    n_local = total  # one rank: it owns everything; more ranks: rank 0 owns nothing
    if comm.size > 1:
        others, rank = comm.size - 1, comm.rank - 1
        n_local = 0 if comm.rank == 0 else total // others + (rank < total % others)
    with LinearSystem(comm, "tst_", n_local, rtol=KSP_RTOL_EXACT) as system:
        assert system.n_global == total
        first, stop = system.owned_range
        system.assemble(*poisson_triplets(n, np.arange(first, stop)))
        x, _ = system.solve(rhs_of(total)[first:stop])
        assert x.size == n_local
        reference = spla.spsolve(full_matrix(total, poisson_triplets(n, np.arange(total))), rhs_of(total))
        assert_matches(x, reference[first:stop])


def test_resize_keeps_the_ksp_and_solves_over_the_new_rows(comm):
    """``resize`` (particles moved between ranks): new row counts per rank, a new global
    size too, the same KSP object; the next assembly builds, the next solve sets up."""
    with LinearSystem(comm, "rsz_", block_rows(comm, 12 * 12), rtol=KSP_RTOL_EXACT,
                      reuse_preconditioner=4) as system:
        ksp = system.ksp
        for n, shift in ((12, 0), (16, 1)):  # 144 then 256 points, split unevenly
            total = n * n
            if n == 16:  # rank 0 takes 7 rows of rank 1
                moved = {0: 7, 1: -7}.get(comm.rank, 0) if comm.size > 1 else 0
                system.resize(block_rows(comm, total) + moved)
            assert system.n_global == total and system.ksp is ksp
            first, stop = system.owned_range
            setups = system.n_setups
            system.assemble(*poisson_triplets(n, np.arange(first, stop)))
            x, info = system.solve(rhs_of(total)[first:stop])
            assert info["fresh_setup"] and system.n_setups == setups + 1
            reference = spla.spsolve(full_matrix(total, poisson_triplets(n, np.arange(total))),
                                     rhs_of(total))
            assert_matches(x, reference[first:stop])
        with pytest.raises(ValueError, match="n_local_rows >= 0|negative number of rows"):
            system.resize(-1 if comm.rank == 0 else 5)


def test_destroy_is_idempotent_and_solve_needs_assembly(comm):
    system = LinearSystem(comm, "tst_", 3)
    with pytest.raises(RuntimeError, match="assemble"):
        system.solve(np.zeros(3))
    with system:
        pass
    assert system.ksp is None and system.mat is None
    system.destroy()


def test_info_and_late_init(comm):
    info = petsc_env.info()
    assert info["petsc_version"].count(".") == 2
    assert isinstance(info["hypre"], bool)
    assert info["int_size"] in (32, 64) and info["scalar_type"] == "float64"
    PETSc = solvers.init(["-tst_late_option", "3"])  # already initialised: goes to the database
    try:
        assert PETSc.Options().getInt("tst_late_option") == 3
    finally:
        PETSc.Options().delValue("tst_late_option")


def test_assemble_csr_matches_triplets_and_reuses_the_pattern(comm):
    """The CSR path (assemble_csr of the owned rows' block) gives the triplet path's
    matrix; the same pattern rewrites values only, a new pattern rebuilds."""
    n = 24
    total = n * n
    with LinearSystem(comm, "tst_", block_rows(comm, total), rtol=KSP_RTOL_EXACT) as system:
        first, stop = system.owned_range
        rows, cols, values = poisson_triplets(n, np.arange(first, stop))
        order = np.random.default_rng(3 + comm.rank).permutation(rows.size)
        # duplicates: the diagonal split in two halves
        rows = np.concatenate([rows[order], np.arange(first, stop)])
        cols = np.concatenate([cols[order], np.arange(first, stop)])
        values = np.concatenate([values[order], np.full(stop - first, -2.0)])
        values[-(stop - first):] = 2.0
        values[np.flatnonzero(rows[: order.size] == cols[: order.size])] = 2.0
        block = sp.csr_matrix((values, (rows - first, cols)), shape=(stop - first, total))
        block.sum_duplicates()
        block.sort_indices()
        indptr, c, v = block.indptr, block.indices, block.data
        assert np.all(np.diff(indptr) >= 0) and indptr[-1] == c.size
        for i in range(stop - first):
            assert np.all(np.diff(c[indptr[i]:indptr[i + 1]]) > 0)  # sorted, no duplicates
        system.assemble_csr(indptr, c, v)
        x, _ = system.solve(rhs_of(total)[first:stop])
        reference = spla.spsolve(full_matrix(total, poisson_triplets(n, np.arange(total))),
                                 rhs_of(total))
        assert_matches(x, reference[first:stop])
        mat = system.mat
        system.assemble_csr(indptr, c, 2.0 * v)
        assert system.mat is mat and system.n_builds == 1
        x, _ = system.solve(rhs_of(total)[first:stop])
        assert_matches(x, 0.5 * reference[first:stop])
        nl = stop - first  # a new pattern (the identity) builds a new matrix
        system.assemble_csr(np.arange(nl + 1), np.arange(first, stop), np.ones(nl))
        assert system.n_builds == 2
        x, _ = system.solve(rhs_of(total)[first:stop])
        assert_matches(x, rhs_of(total)[first:stop])
        with pytest.raises(ValueError, match="global range"):
            system.assemble_csr(indptr, c + system.n_global, v)
        with pytest.raises(ValueError, match="global range"):
            system.assemble_csr(indptr, c - system.n_global, v)
        with pytest.raises(SolverError, match="NaN"):
            system.assemble_csr(indptr, c, np.full(v.size, np.nan))
        inf = v.copy()
        inf[-1:] = -np.inf
        with pytest.raises(SolverError, match="NaN or infinite"):
            system.assemble_csr(indptr, c, inf)


def _poisson_csr(n, first, stop, shift=0.0, extra=False):
    """CSR block of rows first..stop-1 of the Dirichlet Laplacian plus ``shift`` on the
    diagonal; ``extra`` adds a zero entry (i, i + 2) to every row: a new pattern."""
    rows, cols, values = poisson_triplets(n, np.arange(first, stop))
    values = np.where(rows == cols, values + shift, values)
    if extra:
        far = np.arange(first, stop)
        keep = far + 2 < n * n
        rows = np.concatenate([rows, far[keep]])
        cols = np.concatenate([cols, far[keep] + 2])
        values = np.concatenate([values, np.zeros(keep.sum())])
    block = sp.csr_matrix((values, (rows - first, cols)), shape=(stop - first, n * n))
    block.sort_indices()
    return block.indptr, block.indices, block.data, block


def _residual(comm, block, x, b):
    """Global relative residual ||b - A x|| / ||b|| of a row-distributed system."""
    full = np.concatenate(comm.allgather(x))
    r2 = comm.allreduce(float(((b - block @ full) ** 2).sum()))
    return np.sqrt(r2 / comm.allreduce(float((b ** 2).sum())))


def test_preconditioner_set_up_on_hypre_matrix_keeps_no_copy(comm):
    """set_up_preconditioner_csr: BoomerAMG set up on the block made a hypre matrix
    applies as the one PCHYPRE sets up on an AIJ copy (to round-off: hypre orders the
    rows' entries its own way); the system keeps no AIJ (its matrix is hypre's), nothing
    refers to the caller's arrays, and the next set-up replaces the last."""
    n = 30
    with LinearSystem(comm, "hyp_", block_rows(comm, n * n), ksp_type="preonly") as system, \
            LinearSystem(comm, "aij_", block_rows(comm, n * n), ksp_type="preonly") as ref:
        first, stop = system.owned_range
        for k in range(2):
            indptr, cols, vals, block = _poisson_csr(n, first, stop, shift=0.5 * k,
                                                     extra=k == 1)
            ref.assemble_csr(indptr, cols, vals)
            ref.ksp.getPC().setUp()
            given = [np.array(a, copy=True) for a in (indptr, cols, vals)]
            arrays = [np.ascontiguousarray(a, dtype=t) for a, t in
                      ((indptr, system.index_dtype), (cols, system.index_dtype), (vals, float))]
            system.set_up_preconditioner_csr(*arrays)
            assert system._mat.getType() == "hypre" and system.n_builds == k + 1
            assert system._arrays == {} and system._pattern is None
            if petsc_env.hypre_preallocation() is not None:  # made as such: not read after
                assert all(np.array_equal(a, g) for a, g in zip(arrays, given))
            elif comm.size > 1:  # converted from an AIJ split in place: the copy is spent
                assert not all(np.array_equal(a, g) for a, g in zip(arrays, given))
            del arrays  # PETSc refers to none of them: freeing them is safe
            b = ref._b.duplicate()
            b.setArray(rhs_of(n * n)[first:stop])
            x, y = b.duplicate(), b.duplicate()
            system.ksp.getPC().apply(b, x)
            ref.ksp.getPC().apply(b, y)
            assert np.abs(x.getArray()).max() > 0.0
            np.testing.assert_allclose(x.getArray(), y.getArray(), rtol=1e-12, atol=1e-14)


def test_hypre_matrix_made_as_such_is_the_converted_one(comm):
    """A hypre matrix made from a CSR block as such (preallocated per row through
    MatHYPRESetPreallocation, SORTED_FULL) is the block, as PETSc's conversion of it is, rows longer than hypre's default room and entries on other ranks'
    columns included (unpreallocated, hypre's SetValues had failed on such a row on two
    ranks)."""
    from solvers.system import LinearSystem as System

    assert petsc_env.hypre_preallocation() is not None  # this PETSc has hypre
    n = 30
    total = n * n
    with System(comm, "made_", block_rows(comm, total), ksp_type="preonly") as system:
        first, stop = system.owned_range
        indptr, cols, vals, block = _poisson_csr(n, first, stop, extra=True)
        long = sp.lil_matrix(block.shape)  # row 0 of each rank: every 7th column
        long[0, ::7] = 0.01 * np.arange(1, len(range(0, total, 7)) + 1)
        block = (block + long.tocsr()).tocsr()
        block.sort_indices()
        assert np.diff(block.indptr).max() > 100
        csr = [np.ascontiguousarray(a, dtype=t) for a, t in
               ((block.indptr, system.index_dtype), (block.indices, system.index_dtype),
                (block.data, float))]
        made = system._hypre_over(*[a.copy() for a in csr])
        converted = system._hypre_converted(*[a.copy() for a in csr])
        assert made.getType() == converted.getType() == "hypre"
        u = made.createVecRight()
        u.setArray(rhs_of(total)[first:stop])
        y, z = made.createVecLeft(), converted.createVecLeft()
        made.mult(u, y)
        converted.mult(u, z)
        full = np.concatenate(comm.allgather(u.getArray()))
        for out in (y, z):  # (hypre sums a row in its own order: equal to round-off)
            np.testing.assert_allclose(out.getArray(), block @ full, rtol=1e-13, atol=1e-13)
        made.destroy()
        converted.destroy()


def test_split_in_place_is_the_split_of_a_copy():
    """split_in_place writes the diagonal block over the CSR block it reads, with the
    same parts as split_diagonal_block writes to separate arrays."""
    from solvers.csr import count_diagonal, split_diagonal_block, split_in_place

    n, first, stop = 12, 40, 100
    indptr, cols, vals, _ = _poisson_csr(n, first, stop, extra=True)
    indptr, cols = indptr.astype(np.int32), cols.astype(np.int32)
    nnz = cols.size
    p_diag = count_diagonal(cols, first, stop)
    assert 0 < p_diag < nnz
    ref = [np.zeros(stop - first + 1, np.int32), np.zeros(nnz, np.int32), np.zeros(nnz),
           np.zeros(stop - first + 1, np.int32), np.zeros(nnz, np.int32), np.zeros(nnz)]
    p, q = split_diagonal_block(indptr, cols, vals, first, stop, *ref, np.zeros(nnz, np.int32))
    assert (p, q) == (p_diag, nnz - p_diag)
    ip, c, v = indptr.copy(), cols.copy(), vals.copy()
    oi, oj, ov = np.zeros_like(ip), np.zeros(q, np.int32), np.zeros(q)
    assert split_in_place(ip, c, v, first, stop, oi, oj, ov) == (p, q)
    assert np.array_equal(ip, ref[0]) and np.array_equal(c[:p], ref[1][:p])
    assert np.array_equal(v[:p], ref[2][:p]) and np.array_equal(oi, ref[3])
    assert np.array_equal(oj, ref[4][:q]) and np.array_equal(ov, ref[5][:q])


def test_assemble_csr_over_solves_from_one_reused_buffer(comm):
    """assemble_csr_over builds each matrix over the caller's buffer (split in place on
    several ranks), which the caller writes again for the next matrix: every solve
    meets its tolerance, a lagged set-up serves the next matrices as with
    assemble_csr (it reads none of the rewritten arrays), and the system keeps no
    arrays of its own."""
    n = 40
    total = n * n
    with LinearSystem(comm, "over_", block_rows(comm, total), rtol=1e-10,
                      reuse_preconditioner=3) as system:
        first, stop = system.owned_range
        b = rhs_of(total)[first:stop]
        blocks = [_poisson_csr(n, first, stop, shift=0.01 * k, extra=k % 2 == 1)
                  for k in range(5)]
        capacity = max(blk[1].size for blk in blocks)
        ptr = np.zeros(stop - first + 1, dtype=system.index_dtype)
        cols = np.empty(capacity, dtype=system.index_dtype)
        vals = np.empty(capacity)
        fresh = []
        for indptr, c, v, block in blocks:
            ptr[:] = indptr
            cols[:c.size] = c
            vals[:c.size] = v
            system.assemble_csr_over(ptr, cols[:c.size], vals[:c.size], same_unknowns=True)
            assert system._arrays == {} and system._pattern is None
            assert np.shares_memory(system._held[1], cols)
            x, info = system.solve(b)
            fresh.append(info["fresh_setup"])
            assert _residual(comm, block, x, b) < 1e-8
            vals[:] = np.nan  # the caller's next use of its buffer
        assert fresh == [True, False, False, True, False]
        assert system.n_setups == 2 and system.n_builds == 5


@pytest.mark.parametrize("split", [False, True])
def test_sparsify_keeps_large_entries_and_row_sums(split):
    """sparsify, from the block whole (one rank) or split into its diagonal and
    off-diagonal parts (several): each row keeps its diagonal and the entries of at
    least theta times its largest off-diagonal magnitude, in global column order; the
    row sums are those of the block."""
    from solvers.csr import count_diagonal, prepare_block, sparsify

    n, first, stop = 12, 40, 100
    indptr, cols, vals, block = _poisson_csr(n, first, stop, shift=0.3)
    rng = np.random.default_rng(3)
    vals = vals * np.where(cols == np.repeat(np.arange(first, stop), np.diff(indptr)), 1.0,
                           rng.uniform(0.05, 1.0, vals.size))
    full = sp.csr_matrix((vals, cols, indptr), shape=(stop - first, n * n))
    ip, c, v = indptr.copy(), cols.copy(), vals.copy()
    if split:
        n_off = c.size - count_diagonal(c, first, stop)
        off = np.zeros_like(ip), np.zeros(n_off, c.dtype), np.zeros(n_off)
        *_, p, q = prepare_block(ip, c, v, first, stop, False, *off)
        assert q == n_off > 0
        parts = (ip, c[:p], v[:p], *off, first)
    else:  # one rank: the block is its diagonal part, its columns from first = 0
        ip = np.concatenate([[0] * first, ip])
        parts = (ip, c, v, np.zeros_like(ip), c[:0], v[:0], 0)
    out = np.zeros_like(ip), np.zeros_like(cols), np.zeros(vals.size)
    k = sparsify(*parts, 0.5, *out)
    assert 0 < k < cols.size
    thin = sp.csr_matrix((out[2][:k], out[1][:k], out[0][-(stop - first + 1):]),
                         shape=(stop - first, n * n))
    assert thin.has_sorted_indices
    np.testing.assert_allclose(thin.sum(axis=1), full.sum(axis=1), rtol=1e-13, atol=1e-13)
    for r in range(stop - first):
        row, kept = full.getrow(r).toarray()[0], thin.getrow(r).toarray()[0]
        off = np.arange(n * n) != first + r
        big = np.abs(row[off]).max()
        assert np.array_equal(kept[off], np.where(np.abs(row[off]) >= 0.5 * big, row[off], 0.0))


def test_prepare_block_is_the_scaling_checks_and_split_of_a_copy():
    """prepare_block in one pass: the row scale and values of unit_diagonal, the figures
    of check_block (a NaN counted), the parts of split_in_place; unsplit, the block
    scaled in place."""
    from solvers.csr import (check_block, count_diagonal, prepare_block, split_in_place,
                             unit_diagonal)

    n, first, stop = 12, 40, 100
    indptr, cols, vals, _ = _poisson_csr(n, first, stop, shift=0.2, extra=True)
    indptr, cols = indptr.astype(np.int32), cols.astype(np.int32)
    vals = vals * np.random.default_rng(5).uniform(0.5, 2.0, vals.size)
    vals[7] = np.nan
    ref = [indptr.copy(), cols.copy(), vals.copy()]
    ref_scale = unit_diagonal(*ref, first)
    lo, hi, bad = check_block(ref[1], ref[2])
    q_ref = cols.size - count_diagonal(cols, first, stop)
    oi, oj, ov = np.zeros_like(indptr), np.zeros(q_ref, np.int32), np.zeros(q_ref)
    p_ref, _ = split_in_place(*ref, first, stop, oi, oj, ov)
    for split in (True, False):
        ip, c, v = indptr.copy(), cols.copy(), vals.copy()
        off = (np.zeros_like(ip), np.zeros(q_ref, np.int32), np.zeros(q_ref)) if split \
            else (ip[:0], c[:0], v[:0])
        scale, *figures, p, q = prepare_block(ip, c, v, first, stop, True, *off)
        assert np.array_equal(scale, ref_scale) and figures == [lo, hi, bad] == [
            cols.min(), cols.max(), 1]
        if split:
            assert (p, q) == (p_ref, q_ref)
            for got, want in zip((ip, c[:p], v[:p], *off), (*ref, oi, oj, ov)):
                np.testing.assert_array_equal(got, want[:len(got)])
        else:
            assert (p, q) == (cols.size, 0)
            np.testing.assert_array_equal(v, vals * np.repeat(ref_scale, np.diff(indptr)))


def test_preconditioner_on_a_sparser_copy_solves_the_whole_matrix(comm):
    """assemble_csr_over(drop=...): BoomerAMG set up on a sparser copy (a hypre matrix of
    its own, made only for a fresh set-up); the Krylov method solves the whole matrix to
    its tolerance, lagged set-ups make no copy."""
    n = 40
    total = n * n
    with LinearSystem(comm, "thin_", block_rows(comm, total), ksp_type="gmres", rtol=1e-10,
                      reuse_preconditioner=2) as system, \
            LinearSystem(comm, "full_", block_rows(comm, total), ksp_type="preonly") as ref:
        first, stop = system.owned_range
        b = rhs_of(total)[first:stop]
        for k in range(4):
            indptr, cols, vals, block = _poisson_csr(n, first, stop, shift=0.01 * k,
                                                     extra=k == 2)
            # the far entries small: a sparser copy for the set-up
            far = np.abs(cols - np.repeat(np.arange(first, stop), np.diff(indptr))) > 1
            vals = np.where(far, 0.05 * vals, vals)
            block = sp.csr_matrix((vals, cols, indptr), shape=block.shape)
            given = indptr.copy(), cols.copy(), vals.copy()  # several ranks: split in place
            arrays = [np.array(a, dtype=t) for a, t in
                      ((indptr, system.index_dtype), (cols, system.index_dtype), (vals, float))]
            system.assemble_csr_over(*arrays, same_unknowns=True, drop=0.1)
            fresh = k % 2 == 0
            assert (system._pmat is not None) == fresh
            x, info = system.solve(b)
            if fresh:  # BoomerAMG on the copy: not the one on the whole matrix
                assert system._pmat.getType() == "hypre"
                ref.assemble_csr(*given)
                ref.ksp.getPC().setUp()
                u, w, y = (ref._b.duplicate() for _ in range(3))
                u.setArray(b)
                system.ksp.getPC().apply(u, w)
                ref.ksp.getPC().apply(u, y)
                assert not np.allclose(w.getArray(), y.getArray(), rtol=1e-6, atol=0.0)
            assert info["fresh_setup"] == fresh
            assert _residual(comm, block, x, b) < 1e-8


def test_lagged_preconditioner_serves_k_solves_over_the_same_unknowns(comm):
    """reuse_preconditioner = 3: one AMG set-up per three matrices of the same unknowns,
    new patterns included; every solve still meets its tolerance. Different unknowns
    (on any rank) always get a fresh set-up."""
    n = 40
    total = n * n
    with LinearSystem(comm, "lag_", block_rows(comm, total), rtol=1e-10,
                      reuse_preconditioner=3) as system:
        first, stop = system.owned_range
        b = rhs_of(total)[first:stop]
        fresh = []
        for k in range(7):
            indptr, cols, vals, block = _poisson_csr(n, first, stop, shift=0.01 * k,
                                                     extra=k % 2 == 1)
            system.assemble_csr(indptr, cols, vals, same_unknowns=True)
            x, info = system.solve(b)
            fresh.append(info["fresh_setup"])
            assert _residual(comm, block, x, b) < 1e-8
        assert fresh == [True, False, False, True, False, False, True]
        assert system.n_setups == 3 and system.n_builds == 7
        # a rank that declares new unknowns forces a fresh set-up on every rank
        indptr, cols, vals, block = _poisson_csr(n, first, stop, shift=0.1)
        system.assemble_csr(indptr, cols, vals, same_unknowns=comm.rank != comm.size - 1)
        x, info = system.solve(b)
        assert info["fresh_setup"] and system.n_setups == 4
        assert _residual(comm, block, x, b) < 1e-8


def test_lagged_preconditioner_is_dropped_when_it_fails_or_degrades(comm):
    """The hierarchy of a strongly shifted Laplacian is a poor preconditioner of the plain
    one. A lagged solve gets 1.5x (+2) the iterations of the solve after its set-up; there
    it stops and the same call solves again with a fresh set-up, within max_it, to the
    tolerance: no error, and fewer iterations than the lagged solve would have needed."""
    n = 40
    total = n * n
    rows_here = block_rows(comm, total)
    with LinearSystem(comm, "lagf_", rows_here, rtol=1e-10, max_it=1000,
                      reuse_preconditioner=10) as system:
        first, stop = system.owned_range
        b = rhs_of(total)[first:stop]
        easy = _poisson_csr(n, first, stop, shift=50.0)
        plain = _poisson_csr(n, first, stop)
        system.assemble_csr(*easy[:3], same_unknowns=True)
        _, info = system.solve(b)
        easy_its = info["iterations"]
        system.assemble_csr(*plain[:3], same_unknowns=True)
        x, info = system.solve(b)
        assert info["fresh_setup"] and system.n_setups == 2
        assert _residual(comm, plain[3], x, b) < 1e-8
        fresh_its = info["iterations"]
        system.assemble_csr(*plain[:3], same_unknowns=True)
        _, info = system.solve(b)
        assert not info["fresh_setup"] and info["iterations"] <= fresh_its  # a good lag
    # what the lagged solve alone would need: far more than its cap
    with LinearSystem(comm, "lagd_", rows_here, rtol=1e-10, max_it=1000,
                      reuse_preconditioner=10) as system:
        PETSc = petsc_env.petsc()
        system.assemble_csr(*easy[:3], same_unknowns=True)
        system.solve(b)
        system.assemble_csr(*plain[:3], same_unknowns=True)
        system.ksp.getPC().setReusePreconditioner(True)
        system.ksp.setTolerances(max_it=1000)
        system.ksp.setInitialGuessNonzero(False)
        system.ksp.solve(PETSc.Vec().createWithArray(b.copy(), comm=comm),
                         PETSc.Vec().createWithArray(np.zeros_like(b), comm=comm))
        assert system.ksp.getIterationNumber() > max(1.5 * easy_its + 2, fresh_its)


def _smoother(comm, system, tmp):
    """The 'Relax down' line of the KSP's view (the BoomerAMG smoother it uses)."""
    return _view_value(comm, system, tmp, "Relax down")


def _view_value(comm, system, tmp, words):
    """Last word of the first ``KSPView`` line of ``system`` containing ``words``.

    Rank 0 writes the view and reads it back for every rank: when each rank read the file
    itself, rank 0 could truncate it for the next view while another rank still read
    this one; that rank then failed alone and rank 0 hung in the next collective view
    (1 run in 12 of this module's hypre tests on 2 ranks)."""
    PETSc = petsc_env.petsc()
    path = os.path.join(tmp, f"view_{system.prefix}.txt")
    viewer = PETSc.Viewer().createASCII(path, comm=comm)
    system.ksp.view(viewer)
    viewer.destroy()
    values = None
    if comm.rank == 0:
        with open(path) as fh:
            values = [line.split()[-1] for line in fh if words in line]
    return comm.bcast(values, root=0)[0]


def test_hypre_options_are_defaults_the_options_database_overrides(comm, mpi_tmp_path):
    """``LinearSystem(hypre_options=...)`` (the PPE's: aggressive HMIS coarsening, ext+i
    interpolation of at most 4 points) sets BoomerAMG options under the prefix;
    -{prefix}pc_hypre_boomeramg_agg_nl given by the user wins."""
    from parsph.fluid.stage import PPE_HYPRE_OPTIONS

    if not petsc_env.has_hypre():
        pytest.skip("this PETSc has no hypre")
    PETSc = petsc_env.petsc()
    n = 16
    for prefix, asked, expect in (("aggd_", None, "1"), ("aggu_", "0", "0"), ("aggn_", "", "0")):
        if asked:
            PETSc.Options().setValue(prefix + "pc_hypre_boomeramg_agg_nl", asked)
        extra = PPE_HYPRE_OPTIONS if asked != "" else None
        try:
            with LinearSystem(comm, prefix, block_rows(comm, n * n), hypre_options=extra) as system:
                first, stop = system.owned_range
                system.assemble(*poisson_triplets(n, np.arange(first, stop)))
                system.solve(rhs_of(n * n)[first:stop])
                assert _view_value(comm, system, mpi_tmp_path, "aggressive coarsening") == expect
                assert _smoother(comm, system, mpi_tmp_path) == "l1-Gauss-Seidel"
                ppe = (("Coarsen type", "HMIS"), ("Interpolation type", "ext+i"),
                       ("max elements per row", "4"))
                for words, value in ppe:
                    assert (_view_value(comm, system, mpi_tmp_path, words) == value) == (
                        extra is not None), words
        finally:
            if asked:
                PETSc.Options().delValue(prefix + "pc_hypre_boomeramg_agg_nl")


def test_boomeramg_smoother_defaults_to_l1_gauss_seidel_unless_asked(comm, mpi_tmp_path):
    """parsph's default smoother (docs/solvers.md); -{prefix}pc_hypre_* still wins."""
    if not petsc_env.has_hypre():
        pytest.skip("this PETSc has no hypre")
    PETSc = petsc_env.petsc()
    n = 16
    cases = (("smooth_", None, None), ("smoothj_", "relax_type_down", "Jacobi"),
             ("smootha_", "relax_type_all", "Jacobi"))
    for prefix, key, asked in cases:
        if asked:
            PETSc.Options().setValue(prefix + "pc_hypre_boomeramg_" + key, asked)
        try:
            with LinearSystem(comm, prefix, block_rows(comm, n * n)) as system:
                first, stop = system.owned_range
                system.assemble(*poisson_triplets(n, np.arange(first, stop)))
                system.solve(rhs_of(n * n)[first:stop])
                assert _smoother(comm, system, mpi_tmp_path) == (asked or "l1-Gauss-Seidel")
        finally:
            if asked:
                PETSc.Options().delValue(prefix + "pc_hypre_boomeramg_" + key)


def test_block_system_grown_by_resize_solves_as_a_fresh_one(comm, mpi_tmp_path):
    """A block system grown by ``resize`` (fluidised particles joining the viscous
    predictor) solves bit for bit as a new system of that size, with the same BoomerAMG
    options (a code default, a user's option, parsph's smoother). hypre keeps the
    function of each unknown (``dof_func``: x or y) from its first set-up and read it
    past its end for the rows added later: 23 GMRES iterations instead of 7 here, and
    one-rank runs of ``slope_failure`` that differed from run to run."""
    if not petsc_env.has_hypre():
        pytest.skip("this PETSc has no hypre")
    PETSc = petsc_env.petsc()
    bs = 2
    coupling = np.array([[2.0, -1.0], [0.5, 2.0]])
    options = dict(block_size=bs, ksp_type="gmres", rtol=1e-4,
                   hypre_options={"pc_hypre_boomeramg_agg_nl": "1"})

    def settings(system):
        return (_view_value(comm, system, mpi_tmp_path, "aggressive coarsening"),
                _view_value(comm, system, mpi_tmp_path, "Threshold for strong coupling"),
                _smoother(comm, system, mpi_tmp_path))

    PETSc.Options().setValue("grw_pc_hypre_boomeramg_strong_threshold", "0.4")
    try:
        with LinearSystem(comm, "grw_", block_rows(comm, 6 * 6), **options) as grown:
            for n in (6, 20):  # 36 then 400 points: most rows new to the first set-up
                if n != 6:
                    grown.resize(block_rows(comm, n * n))
                first, stop = grown.owned_range
                grown.assemble(*coupled_triplets(n, np.arange(first // bs, stop // bs), coupling))
                rhs = rhs_of(bs * n * n)[first:stop].reshape(-1, bs)
                x, info = grown.solve(rhs)
            views = [settings(grown)]
            with LinearSystem(comm, "grw_", block_rows(comm, 20 * 20), **options) as fresh:
                assert fresh.owned_range == (first, stop)
                fresh.assemble(*coupled_triplets(20, np.arange(first // bs, stop // bs),
                                                 coupling))
                y, fresh_info = fresh.solve(rhs)
                views.append(settings(fresh))
    finally:
        PETSc.Options().delValue("grw_pc_hypre_boomeramg_strong_threshold")
    assert views[0] == views[1] == ("1", "0.4", "l1-Gauss-Seidel")
    assert info["iterations"] == fresh_info["iterations"]
    assert np.array_equal(x, y)


def test_unit_diagonal_scales_rows_and_keeps_the_solution():
    """Each row is divided by its diagonal (rows without a positive one are left alone),
    the returned scale is 1 / diagonal, and the scaled system with the scaled right-hand
    side has the unscaled one's solution."""
    from solvers.csr import scale_rows, unit_diagonal
    n, first = 30, 100  # a block of rows 100..129 of a larger system: global columns
    rng = np.random.default_rng(11)
    a = sp.random(n, n, density=0.2, random_state=12, format="csr")
    diag = 10.0 ** rng.uniform(-9, 2, n)  # diagonals over eleven orders, as at a wall
    diag[7] = 0.0
    a = (a + sp.diags(diag) + sp.diags(np.full(n, 1e-12))).tocsr()
    a.sort_indices()
    a.data[a.indptr[7]:a.indptr[8]][a.indices[a.indptr[7]:a.indptr[8]] == 7] = -1.0
    orig = a.copy()
    cols = a.indices.astype(np.int64) + first
    scale = unit_diagonal(a.indptr.astype(np.int64), cols, a.data, first)
    d = orig.diagonal()
    expect = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 1.0)
    np.testing.assert_allclose(scale, expect, rtol=1e-15)
    np.testing.assert_allclose(a.diagonal()[d > 0], 1.0, rtol=1e-15)
    assert a.diagonal()[7] == -1.0  # not positive: left as it was
    np.testing.assert_allclose(a.toarray(), sp.diags(scale) @ orig.toarray(), rtol=1e-15)
    b = rng.uniform(-1, 1, n)
    np.testing.assert_allclose(spla.spsolve(a.tocsc(), b * scale), spla.spsolve(orig.tocsc(), b),
                               rtol=1e-9)
    twice = orig.copy()
    scale_rows(twice.indptr.astype(np.int64), twice.data, scale)
    np.testing.assert_allclose(twice.toarray(), a.toarray(), rtol=0, atol=0)


def test_product_operator_with_scaled_rows_solves_the_unscaled_system(comm):
    """A + L^T R with the rows of A scaled to a unit diagonal (row_scale) has the solution
    of the unscaled operator; the reference is a direct solve of the whole operator."""
    from solvers.csr import unit_diagonal
    n = 12
    total = n * n
    rng = np.random.default_rng(5)
    m = 6  # interface rows, all on rank 0
    ptr_all = np.arange(m + 1) * 3
    cols_all = np.sort(rng.choice(total, size=(m, 3), replace=False), axis=1).ravel()
    left_all, right_all = rng.uniform(0.5, 1.5, 3 * m), rng.uniform(0.5, 1.5, 3 * m)
    full = full_matrix(total, poisson_triplets(n, np.arange(total)))
    weights = sp.diags(10.0 ** rng.uniform(-6, 3, total))  # rows of any magnitude
    full = (weights @ full).tocsr()
    lmat = sp.csr_matrix((left_all, cols_all, ptr_all), shape=(m, total))
    rmat = sp.csr_matrix((right_all, cols_all, ptr_all), shape=(m, total))
    op = (full + lmat.T @ rmat).tocsc()
    b = rhs_of(total)
    reference = spla.spsolve(op, b)
    with LinearSystem(comm, "tstp_", block_rows(comm, total), ksp_type="gmres",
                      rtol=KSP_RTOL_EXACT, max_it=5000) as system:
        first, stop = system.owned_range
        block = full[first:stop]
        block.sort_indices()
        indptr = block.indptr.astype(np.int64)
        cols = block.indices.astype(np.int64)
        vals = block.data.copy()
        scale = unit_diagonal(indptr, cols, vals, first)
        system.assemble_csr(indptr, cols, vals)
        mine = comm.rank == 0
        ptr = ptr_all if mine else np.zeros(1, dtype=np.int64)
        sel = slice(0, ptr[-1])
        near = (np.zeros(stop - first + 1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                np.zeros(0))
        system.set_product(ptr, cols_all[sel], left_all[sel], right_all[sel], near,
                           row_scale=scale)
        x, _ = system.solve(b[first:stop] * scale)
        assert_matches(x, reference[first:stop])


def _operator_problem(comm, system, n, coupling, eps=None):
    """Give ``system`` (an OperatorSystem over this rank's points of an ``n`` x ``n`` grid)
    the operator kron(L, coupling) (with ``eps``: I + eps kron(L, coupling)) applied
    matrix-free and L as its preconditioner matrix; returns the owned points."""
    bs = coupling.shape[0]
    first, stop = system.offset // bs, system.offset // bs + system.n_local_rows
    points = np.arange(first, stop)
    rows, cols, vals = poisson_triplets(n, points)
    ghosts = np.unique(cols[(cols < first) | (cols >= stop)])
    where = np.full(n * n, -1)
    where[points] = np.arange(points.size)
    where[ghosts] = points.size + np.arange(ghosts.size)
    local = sp.csr_matrix((vals, (rows - first, where[cols])),
                          shape=(points.size, points.size + ghosts.size))

    def apply(u, out):
        out[:] = (local @ u) @ coupling.T
        if eps is not None:
            out *= eps
            out += u[:points.size]

    system.set_operator(apply, ghosts)
    L = sp.csr_matrix((vals, (rows - first, cols)), shape=(points.size, n * n))
    L.sort_indices()
    system.assemble_preconditioner(L.indptr, L.indices, L.data)
    return points


@pytest.mark.parametrize("n", [16, 24])
def test_operator_system_matches_the_assembled_block_system(comm, n, capfd):
    """A block operator applied matrix-free (the other ranks' unknowns by the system's
    scatter), preconditioned by BoomerAMG on a scalar matrix per component, solves
    kron(L, C) as the direct solve does; after a resize to other rows it solves again."""
    from solvers import OperatorSystem
    from solvers.operator import GMRES_RESTART, JACOBI_RESTART

    bs = 2
    coupling = np.array([[2.0, -0.6], [0.3, 1.5]])
    full = full_matrix(bs * n * n, coupled_triplets(n, np.arange(n * n), coupling))
    b = rhs_of(bs * n * n)
    exact = spla.spsolve(full, b)
    with OperatorSystem(comm, "tst_", block_rows(comm, n * n), bs,
                        rtol=KSP_RTOL_EXACT) as system:
        for shift in (0, 7):  # the second pass: other rows on each rank
            if shift:
                mine = block_rows(comm, n * n) + (shift if comm.rank == 0 else -shift)
                system.resize(mine if comm.size > 1 else n * n)
            points = _operator_problem(comm, system, n, coupling)
            x, info = system.solve(b.reshape(-1, bs)[points])
            assert x.shape == (points.size, bs) and info["iterations"] < 40
            assert_matches(x, exact.reshape(-1, bs)[points])
            assert system.ksp.getPC().getType() == "python"
            # what the solve used freed after it (the fluid's viscous step: not held
            # beside the PPE's), and set up again for the next solve
            system.release()
            assert system.scalar._mat is None and system.scalar._held is None
            assert system._apply is None and system._scatter is None
            _operator_problem(comm, system, n, coupling)
            x, _ = system.solve(b.reshape(-1, bs)[points])
            assert_matches(x, exact.reshape(-1, bs)[points])
            assert system._restart == GMRES_RESTART == 30  # an AMG set-up: PETSc's
            # Jacobi instead of the AMG (no set-up) for an operator close to the identity
            # (a viscous step at a small viscous number), GMRES restarted every
            # JACOBI_RESTART iterations; the next AMG set-up (next pass) restores GMRES_RESTART
            eps = 0.02
            _operator_problem(comm, system, n, coupling, eps)
            system.set_jacobi(np.full(points.size, 1.0 / (1.0 + 4.0 * eps)))
            assert system.scalar._mat is None and system._restart == JACOBI_RESTART
            near = (sp.identity(bs * n * n) + eps * full).tocsc()
            x, info_j = system.solve(b.reshape(-1, bs)[points])
            assert_matches(x, spla.spsolve(near, b).reshape(-1, bs)[points])
            assert info_j["iterations"] > JACOBI_RESTART  # (past a restart)
            capfd.readouterr()
            system.ksp.view()  # PETSc's own account (rank 0 prints it)
            if comm.rank == 0:
                assert f"restart={JACOBI_RESTART}," in capfd.readouterr().out


def test_operator_system_correct_solves_its_rows_exactly_after_the_amg(comm):
    """``correct`` rewrites rows the caller solves exactly given the others after each
    BoomerAMG application: extrapolation rows ``u_w + (u_{w+1} + u_{w+n+1}) / 2 = b_w``
    (a no-slip wall's ghost row, its partners not ghost rows) satisfy their equation exactly in the preconditioner's
    output, also where their partner is on another rank, and the solve still matches
    the direct one, in no more iterations than without it."""
    from solvers import OperatorSystem

    n, bs = 20, 2
    r, c, v = poisson_triplets(n, np.arange(n * n))
    i, j = np.divmod(np.arange(n * n), n)
    ghost = (j == 0) & (i < n - 1)
    keep = ~ghost[r]
    g = np.flatnonzero(ghost)
    r = np.concatenate([r[keep], g, g, g])
    c = np.concatenate([c[keep], g, g + n + 1, g + 1])
    v = np.concatenate([v[keep], np.ones(g.size), np.full(g.size, 0.5), np.full(g.size, 0.5)])
    S = sp.csr_matrix((v, (r, c)), shape=(n * n, n * n))
    S.sort_indices()
    full = sp.kron(S, sp.identity(bs)).tocsr()
    b = rhs_of(bs * n * n)
    exact = spla.spsolve(full, b).reshape(-1, bs)
    B = b.reshape(-1, bs)
    iterations = {}
    for corrected in (False, True):
        with OperatorSystem(comm, "tst_", block_rows(comm, n * n), bs,
                            rtol=KSP_RTOL_EXACT) as system:
            first = system.offset // bs
            points = np.arange(first, first + system.n_local_rows)
            mine = S[points]
            cols = mine.indices
            ghosts = np.unique(cols[(cols < points[0]) | (cols > points[-1])]) \
                if points.size else np.zeros(0, dtype=np.int64)
            where = np.full(n * n, -1)
            where[points] = np.arange(points.size)
            where[ghosts] = points.size + np.arange(ghosts.size)
            local = sp.csr_matrix((mine.data, where[cols], mine.indptr),
                                  shape=(points.size, points.size + ghosts.size))
            rows_g = np.flatnonzero(ghost[points])

            def correct(u, rhs, out):
                w = points[rows_g]
                out[rows_g] = rhs[rows_g] - 0.5 * (u[where[w + n + 1]] + u[where[w + 1]])

            system.set_operator(lambda u, out: out.__setitem__(slice(None), local @ u),
                                ghosts, correct if corrected else None)
            # (split in place on several ranks: copies)
            system.assemble_preconditioner(mine.indptr.astype(system.index_dtype),
                                           mine.indices.astype(system.index_dtype),
                                           mine.data.copy())
            x, info = system.solve(B[points])
            assert_matches(x, exact[points])
            iterations[corrected] = info["iterations"]
            if corrected:  # one application of the preconditioner
                bv, xv = system.ksp.getOperators()[0].createVecs()
                bv.getArray()[:] = B[points].ravel()
                system.ksp.getPC().apply(bv, xv)
                out = np.concatenate(comm.allgather(xv.getArray().reshape(-1, bs).copy()))
                wall = g
                np.testing.assert_allclose(out[wall] + 0.5 * (out[wall + n + 1] + out[wall + 1]),
                                           B[wall], rtol=0, atol=1e-12)
                bv.destroy()
                xv.destroy()
    assert iterations[True] <= iterations[False]


def test_sort_neighbours_by_row_keeps_ascending_lists_whose_rows_ascend():
    """``ascending`` (lists in index order, as build_csr gives them): a list within one
    stretch of indices over which the rows in the systems ascend comes back as it is;
    a list across stretches is sorted (by a rotation where it is two stretches, the
    second below the first), as without the flag where every entry has a row. Either
    way its entries of rows >= 0 are in row order. Rows that ascend everywhere (one
    rank), in two stretches (a halo of lower rows stored after the owned particles), or
    in many."""
    from solvers.csr import sort_neighbours_by_row

    rng = np.random.default_rng(11)
    for trial in range(60):
        n_points = int(rng.integers(2, 200))
        lengths = rng.integers(0, 40, 25)
        indices = np.concatenate([np.sort(rng.choice(n_points, min(k, n_points), replace=False))
                                  for k in lengths] + [np.empty(0)]).astype(np.int32)
        indptr = np.concatenate(([0], np.cumsum([min(k, n_points) for k in lengths])))
        inside = rng.random(n_points) < 0.7
        row = np.full(n_points, -1, dtype=np.int64)
        row[inside] = np.cumsum(rng.integers(1, 3, inside.sum()))  # ascending
        if trial % 3 == 1:  # two stretches: the upper part of the rows first
            cut = int(rng.integers(0, inside.sum() + 1))
            row[inside] = np.roll(row[inside], cut)
        elif trial % 3 == 2:  # many
            row[inside] = rng.permutation(row[inside])
        stretch = np.zeros(n_points, dtype=np.int64)  # the stretches, by their definition
        last = -1
        for k in range(n_points):
            if row[k] >= 0:
                stretch[k] = stretch[k - 1] + (row[k] <= last) if k else 0
                last = row[k]
            elif k:
                stretch[k] = stretch[k - 1]
        out = sort_neighbours_by_row(indptr, indices, row, ascending=True)
        plain = sort_neighbours_by_row(indptr, indices, row)
        # the same along a visiting order: the lists and the rows relabelled by it
        visit = rng.permutation(n_points)  # particle k is now visit[k], visited k-th
        row2 = np.empty_like(row)
        row2[visit] = row
        by_visit = sort_neighbours_by_row(indptr, visit[indices], row2, ascending=True,
                                          order=visit)
        assert np.array_equal(by_visit, visit[out]), trial
        for i in range(len(lengths)):
            a, b = indptr[i], indptr[i + 1]
            mine = indices[a:b]
            if b > a and stretch[mine[0]] == stretch[mine[-1]]:
                assert np.array_equal(out[a:b], mine), (trial, i)
            else:  # sorted; rows outside the systems may stay in place (a rotation)
                assert np.array_equal(np.sort(out[a:b]), np.sort(mine)), (trial, i)
                if np.all(row[mine] >= 0):
                    assert np.array_equal(out[a:b], plain[a:b]), (trial, i)
            r = row[out[a:b]]
            assert np.all(np.diff(r[r >= 0]) > 0), (trial, i)


def test_sort_neighbours_by_row_is_a_stable_sort_of_each_list():
    """Each list sorted by the neighbours' rows, ties (periodic images: one row twice) in
    their list order, as a stable argsort per list gives: sorted lists, lists of two
    runs (owned neighbours, then halo ones of lower rows), random lists, empty lists."""
    from solvers.csr import sort_neighbours_by_row

    rng = np.random.default_rng(7)
    for trial in range(60):
        n_rows, n_points = int(rng.integers(1, 40)), int(rng.integers(1, 200))
        lengths = rng.integers(0, 70, n_rows)
        indptr = np.concatenate(([0], np.cumsum(lengths))).astype(np.int64)
        row = rng.integers(-1, 30, n_points).astype(np.int64)  # repeats: ties
        indices = rng.integers(0, n_points, indptr[-1]).astype(np.int32)
        if trial % 3 == 1:  # two runs: high rows first, then low ones
            row = np.arange(n_points, dtype=np.int64)[::-1].copy()
            for i in range(n_rows):
                a, b = indptr[i], indptr[i + 1]
                indices[a:b] = np.sort(indices[a:b])
        out = sort_neighbours_by_row(indptr, indices, row)
        for i in range(n_rows):
            a, b = indptr[i], indptr[i + 1]
            want = indices[a:b][np.argsort(row[indices[a:b]], kind="stable")]
            assert np.array_equal(out[a:b], want), (trial, i)
        assert out.dtype == indices.dtype
