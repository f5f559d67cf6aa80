"""The matrix side of :class:`solvers.system.LinearSystem`: assembly, pattern reuse, null space.

Bulk assembly from triplets or a CSR block, the exact preallocation, the work arrays of
the matrices built on arrays, the null space and the product operator of the strong
coupling.

Notes
-----
Assembly is bulk, never entry by entry. petsc4py 3.18 has no COO interface
(``Mat.setPreallocationCOO`` / ``setValuesCOO`` arrive in later releases), so the
triplets are turned into a CSR block of the owned rows with numpy (one sort, duplicates
summed with ``np.bincount``). A new sparsity pattern builds a new matrix whose
preallocation is computed from that CSR block (``MatMPIAIJSetPreallocationCSR``: exact
diagonal and off-diagonal counts, values inserted in the same call). The same pattern
again only rewrites the values (``Mat.setValuesCSR`` into the existing nonzeros, then
assembly), and the KSP is handed the same operator, so the preconditioner is rebuilt on
the new values without any reallocation. When the triplet rows and columns are the very
same arrays as last time (the usual case from step to step), even the sort is skipped.
"""
from __future__ import annotations

import numpy as np

from base import heap
from solvers.csr import (check_block, count_diagonal, prepare_block, row_block_counts,
                         sparsify, split_diagonal_block, split_in_place)
from solvers.errors import SolverError, agree
from solvers.petsc_env import hypre_preallocation as _hypre_preallocation


class MatrixAssembly:
    """Assembly methods of :class:`solvers.system.LinearSystem` (a mixin: it holds no
    state of its own; the attributes are the system's)."""

    def set_nullspace_constant(self) -> None:
        """Collective: declare the constant vector the null space of the operator.

        For a singular operator such as a pure Neumann pressure Poisson problem (not
        parsph's usual case: a free surface gives Dirichlet rows). The null space is
        attached to the current matrix and to every matrix built later; for a
        symmetric system it is also the transpose null space, which makes PETSc
        remove the constant from the right-hand side so that it is consistent.
        """
        if self._nullspace is None:
            self._nullspace = self._PETSc.NullSpace().create(constant=True, comm=self.comm)
        if self._mat is not None:
            self._attach_nullspace(self._mat)

    def _attach_nullspace(self, mat) -> None:
        mat.setNullSpace(self._nullspace)
        if self.symmetric:
            mat.setTransposeNullSpace(self._nullspace)

    def _check_triplets(self, rows, cols, values) -> tuple[type, str] | None:
        """What is wrong with this rank's triplets, or None."""
        if not (rows.ndim == cols.ndim == values.ndim == 1) or not (rows.size == cols.size == values.size):
            return ValueError, (
                f"{self.prefix}: rows, cols and values must be 1-D arrays of one length, got shapes "
                f"{rows.shape}, {cols.shape}, {values.shape}"
            )
        if rows.dtype.kind not in "iu" or cols.dtype.kind not in "iu":
            return ValueError, (
                f"{self.prefix}: rows and cols must be integer arrays (int32 or int64), got "
                f"{rows.dtype} and {cols.dtype}"
            )
        first, stop = self.owned_range
        bad = (rows < first) | (rows >= stop)
        if bad.any():
            owned = f"rows {first}..{stop - 1}" if stop > first else "no rows"
            return ValueError, (
                f"{self.prefix}: {int(bad.sum())} triplets have rows in {int(rows[bad].min())}.."
                f"{int(rows[bad].max())}, but this rank owns {owned} of {self.n_global}; assemble "
                "only owned rows (global row = offset + local index, see global_offset)"
            )
        bad = (cols < 0) | (cols >= self.n_global)
        if bad.any():
            return ValueError, (
                f"{self.prefix}: {int(bad.sum())} triplets have columns in {int(cols[bad].min())}.."
                f"{int(cols[bad].max())}, outside the global range 0..{self.n_global - 1}"
            )
        if not np.isfinite(values).all():
            return SolverError, (
                f"{self.prefix}: {int((~np.isfinite(values)).sum())} matrix values are NaN or "
                "infinite; the fields the matrix is built from have blown up: try a smaller time step"
            )
        return None

    def _pattern_of(self, rows, cols):
        """``(changed, keys, inverse)``: the sorted unique (local row, col) keys of the triplets."""
        last = self._pattern
        if (
            last is not None
            and "rows" in last
            and rows.shape == last["rows"].shape
            and np.array_equal(rows, last["rows"])
            and np.array_equal(cols, last["cols"])
        ):
            return False, last["keys"], last["inverse"]
        key = (rows.astype(np.int64) - self.offset) * self.n_global + cols.astype(np.int64)
        keys, inverse = np.unique(key, return_inverse=True)
        changed = last is None or "keys" not in last or not np.array_equal(keys, last["keys"])
        return changed, keys, inverse.reshape(-1)

    def assemble(self, rows, cols, values) -> None:
        """Collective: set the matrix from global triplets; duplicates are summed.

        Parameters
        ----------
        rows, cols : numpy.ndarray of int32 or int64, shape (nnz,)
            Global scalar row and column indices. Every row must be owned by this rank
            (see :attr:`owned_range`); columns may belong to any rank.
        values : numpy.ndarray of float64, shape (nnz,)
            Matrix entries (units of the equation). Entries with the same (row, col)
            are added together.

        Raises
        ------
        ValueError
            On every rank, if some rank passes a row it does not own (the message
            names the offending row range), a column outside the global range, or
            arrays of different lengths.
        SolverError
            On every rank, if some rank passes NaN or infinite values.

        Notes
        -----
        If the pattern (the set of distinct (row, col) pairs) is the same on every rank
        as in the previous call, the matrix object is kept and only its values are
        rewritten; if it changed on any rank, a new matrix is built on all ranks and the
        KSP is reset onto it. One ``allgather`` of a flag decides this and agrees on
        errors.
        """
        rows = np.asarray(rows)
        cols = np.asarray(cols)
        values = np.asarray(values, dtype=np.float64)
        error = self._check_triplets(rows, cols, values)
        changed, keys, inverse = (False, None, None) if error else self._pattern_of(rows, cols)
        rebuild = agree(self.comm, error, changed) or self._mat is None
        data = np.bincount(inverse, weights=values, minlength=keys.size).astype(np.float64, copy=False)
        self._lag(False)
        if rebuild:
            self._build(rows, cols, keys, inverse, data)
        else:
            pattern = self._pattern
            if pattern["inverse"] is not inverse:  # same pattern reached through other triplets
                pattern.update(rows=rows.copy(), cols=cols.copy(), inverse=inverse)
            self._mat.setValuesCSR(pattern["indptr"], pattern["indices"], data,
                                   addv=self._PETSc.InsertMode.INSERT_VALUES)
            self._mat.assemble()
        self._drop_product()
        self._ksp.setOperators(self._mat)

    def assemble_csr(self, indptr, cols, values, same_unknowns: bool = False) -> None:
        """Collective: set the matrix from a CSR block of this rank's owned scalar rows.

        Parameters
        ----------
        indptr : numpy.ndarray of int, shape (n_local + 1,)
            Row pointers of the owned rows (local row ``i`` is global row ``offset + i``),
            ``indptr[0] == 0``.
        cols : numpy.ndarray of int, shape (indptr[-1],)
            Global column indices, sorted and distinct within each row.
        values : numpy.ndarray of float64, shape (indptr[-1],)
            Matrix entries.
        same_unknowns : bool, optional
            The caller's promise that the unknowns are the ones of the last assembly
            (the same points in the same order, e.g. the same particle ids). Only then,
            on every rank, may the last preconditioner set-up be kept (see
            ``reuse_preconditioner``).

        Raises
        ------
        ValueError, SolverError
            On every rank, as :meth:`assemble` (bad shapes or columns; NaN values).

        Notes
        -----
        The fast path of the fluid stage: no sort of triplets. If ``indptr`` and ``cols``
        equal the last pattern on every rank, only the values are rewritten; otherwise a
        new matrix is built, preallocated exactly from this block.
        """
        int_type = self._PETSc.IntType
        indptr = np.asarray(indptr)
        cols = np.asarray(cols)
        values = np.asarray(values, dtype=np.float64)
        error = self._check_csr(indptr, cols, values)
        last = self._pattern
        changed = error is None and (
            last is None or last["indptr"].shape != indptr.shape
            or last["indices"].shape != cols.shape
            or not np.array_equal(last["indptr"], indptr)
            or not np.array_equal(last["indices"], cols))
        bits = agree(self.comm, error, int(changed) | (0 if same_unknowns else 2))
        rebuild = bool(bits & 1) or self._mat is None
        self._lag(not bits & 2)
        if rebuild:  # copies: the pattern is kept, and callers reuse their arrays
            self._build_csr(np.asarray(indptr, dtype=int_type), np.asarray(cols, dtype=int_type),
                            values)
        else:
            self._mat.setValuesCSR(last["indptr"], last["indices"], values,
                                   addv=self._PETSc.InsertMode.INSERT_VALUES)
            self._mat.assemble()
        self._drop_product()
        self._ksp.setOperators(self._mat)

    def _check_csr(self, indptr, cols, values):
        """``(exception type, message)`` for a bad CSR block of the owned rows, else None."""
        bad = self._bad_shape(indptr, cols, values)
        return bad if bad is not None else self._bad_values(cols.size,
                                                             *check_block(cols, values))

    def _bad_shape(self, indptr, cols, values):
        """:meth:`_check_csr` of the block's shapes."""
        if indptr.shape != (self.n_local + 1,) or cols.shape != values.shape or cols.ndim != 1 \
                or indptr[0] != 0 or indptr[-1] != cols.size:
            return ValueError, (
                f"{self.prefix}: need indptr of {self.n_local + 1} entries from 0 to len(cols) and "
                f"cols, values of one length; got {indptr.shape}, {cols.shape}, {values.shape}")
        return None

    def _bad_values(self, nnz, lo, hi, bad):
        """:meth:`_check_csr` of the block's figures (:func:`solvers.csr.check_block`)."""
        if nnz and (lo < 0 or hi >= self.n_global):
            return ValueError, (
                f"{self.prefix}: columns in {int(lo)}..{int(hi)}, outside the global range "
                f"0..{self.n_global - 1}")
        if bad:
            return SolverError, (
                f"{self.prefix}: {bad} matrix values are NaN or infinite; the fields the "
                "matrix is built from have blown up: try a smaller time step")
        return None

    def set_up_preconditioner_csr(self, indptr, cols, values) -> None:
        """Collective: set the preconditioner up afresh on a CSR block of this rank's owned
        rows (as :meth:`assemble_csr` takes it) that serves no other purpose: a BoomerAMG
        preconditioner of an operator applied otherwise (:class:`solvers.OperatorSystem`).

        The block becomes a PETSc matrix over the caller's arrays and is converted in
        place to hypre's ParCSR matrix, on which PCHYPRE sets up without a copy of its
        own. On several ranks the arrays are split in place into the diagonal block
        (:func:`solvers.csr.split_in_place`): **they are overwritten**. After the call
        nothing refers to them, and no AIJ copy is kept: the system holds hypre's matrix
        and its AMG hierarchy only (an AIJ kept beside them cost 12 bytes per entry on
        one rank and 28 on several, 380 bytes per particle of a 3D coupled tank on one
        rank; docs/solvers.md). The KSP of this system can only apply its
        preconditioner (``ksp.getPC().apply``): a hypre matrix provides no vectors to a
        Krylov method.

        Raises
        ------
        ValueError, SolverError
            On every rank, as :meth:`assemble_csr`.
        """
        arrays = self._csr_arrays(indptr, cols, values)
        agree(self.comm, self._check_csr(*arrays), 0)
        self.release()  # the last matrix and its hierarchy go first
        mat = self._hypre_over(*arrays)
        self._mat = mat
        self._ksp.getPC().setReusePreconditioner(False)
        self._ksp.setOperators(mat)
        self._ksp.getPC().setUp()
        self.n_builds += 1

    def release(self) -> None:
        """Collective: free the matrix and the preconditioner set up on it (hypre's copy,
        the AMG hierarchy) now, not at the next assembly; no solve before that."""
        self._drop_product()
        if self._mat is not None:
            self._ksp.reset()
            self._mat.destroy()
            self._mat = None
        if self._pmat is not None:
            self._pmat.destroy()
            self._pmat = None
        self._held = self._pattern = None
        self._pc_age = 0

    def assemble_csr_over(self, indptr, cols, values, same_unknowns: bool = False,
                          drop: float = 0.0, unit_diagonal: bool = False):
        """Collective: :meth:`assemble_csr` with the matrix built over the caller's arrays.

        PETSc takes the arrays as the matrix's storage (on several ranks after a split in
        place into the diagonal block: **they are overwritten**), so the system keeps no
        copy of its own. The caller must leave them untouched until the solves on this
        matrix are done, and assemble again before the next solve once it has written to
        them; the system keeps them alive meanwhile. Every call builds a new matrix (no
        pattern is kept to compare with). A lagged preconditioner set-up
        (``reuse_preconditioner``, ``same_unknowns``) holds hypre's copy of an earlier
        matrix and reads none of these arrays.

        The PPE's CSR block and the viscous preconditioner's share one caller buffer
        this way (``parsph/fluid/stage.py``): a copy per system had cost 12 bytes per
        entry on one rank and 28 on several (docs/solvers.md).

        ``unit_diagonal``: each row is first scaled in place to a unit diagonal
        (:func:`solvers.csr.unit_diagonal`) and the row scale returned (else None). The
        scaling, the checks and the split are one pass over the block
        (:func:`solvers.csr.prepare_block`).

        ``drop`` > 0: a fresh BoomerAMG set-up is made on a sparser copy of the block
        (:func:`solvers.csr.sparsify`: each row keeps the entries of at least ``drop``
        times its largest off-diagonal magnitude, the others added to its diagonal),
        converted in place to hypre's matrix; the copy's arrays are freed and no copy of
        the whole matrix is made for hypre. The operator stays the whole matrix. A
        lagged set-up makes no copy; a lagged set-up that fails is set up again on the
        whole matrix.

        Raises
        ------
        ValueError, SolverError
            On every rank, as :meth:`assemble_csr`.
        """
        indptr, cols, values = self._csr_arrays(indptr, cols, values)
        first, stop = self.owned_range
        int_type = indptr.dtype
        problem = self._bad_shape(indptr, cols, values)
        if problem is None:
            if self.comm.size > 1:
                n_off = cols.size - count_diagonal(cols, first, stop)
                off = (np.empty_like(indptr), np.empty(n_off, dtype=int_type), np.empty(n_off))
            else:  # the block is its diagonal part
                off = (np.empty(0, dtype=int_type), np.empty(0, dtype=int_type), np.empty(0))
            scale, lo, hi, bad, p, q = prepare_block(indptr, cols, values, first, stop,
                                                     unit_diagonal, *off)
            problem = self._bad_values(cols.size, lo, hi, bad)
        bits = agree(self.comm, problem, 0 if same_unknowns else 2)
        if not off[0].size:
            off = (np.zeros_like(indptr), off[1], off[2])
        diag, off = (indptr, cols[:p], values[:p]), (off[0], off[1][:q], off[2][:q])
        self._lag(not bits & 2)
        sparse = None
        if self._pc_age == 0 and self._mat is not None:  # the last set-up goes first
            self._ksp.reset()
        if self._pmat is not None:  # a lagged set-up holds its own reference
            self._pmat.destroy()
            self._pmat = None
        if drop > 0.0 and self._pc_age == 0:
            # the copy and hypre's matrix made of it are the PPE's largest allocations
            heap.release_free_pages(self.n_local_rows)
            sparse = (np.empty_like(indptr), np.empty(p + q, dtype=int_type), np.empty(p + q))
            k = sparsify(*diag, *off, first, drop, *sparse)
            sparse = (sparse[0], sparse[1][:k], sparse[2][:k])
        sizes = ((self.n_local, self.n_global), (self.n_local, self.n_global))
        self._finish_build(self._PETSc.Mat().createAIJWithArrays(
            sizes, (diag, off) if self.comm.size > 1 else diag, comm=self.comm))
        if sparse is not None:
            self._pmat = self._hypre_over(*sparse)
            del sparse
            heap.release_free_pages(self.n_local_rows)  # the copy and hypre's row arrays
        self._held = diag + off
        self._pattern = None
        self._drop_product()
        self._ksp.setOperators(self._mat, self._amg_matrix())
        return scale if unit_diagonal else None

    def _amg_matrix(self):
        """The matrix a fresh preconditioner set-up is made on: the sparser copy of
        ``assemble_csr_over(..., drop)`` if there is one, else the operator's."""
        return self._pmat if self._pmat is not None else self._mat

    def _csr_arrays(self, indptr, cols, values):
        """The CSR block as PETSc takes it (the caller's arrays where their types fit)."""
        int_type = self._PETSc.IntType
        return (np.ascontiguousarray(indptr, dtype=int_type),
                np.ascontiguousarray(cols, dtype=int_type),
                np.ascontiguousarray(values, dtype=np.float64))

    def _hypre_over(self, indptr, cols, values):
        """Collective: hypre's ParCSR matrix (``MATHYPRE``) of a checked CSR block of the
        owned rows, made as such: preallocated per row (``MatHYPRESetPreallocation``,
        :func:`solvers.petsc_env.hypre_preallocation`), ``SORTED_FULL`` (whole sorted
        rows: hypre writes them straight into its diagonal and off-diagonal blocks) and
        filled from the arrays, after which nothing refers to them.

        PETSc's conversion of an AIJ matrix (:meth:`_hypre_converted`, the fallback where
        the preallocation cannot be called) passes through hypre's auxiliary per-row
        arrays, 61 bytes per entry at its peak against 15 kept; made as such, 20. That
        conversion of the PPE's sparser copy, every fresh set-up, had become the peak RSS
        of the 3D tank of ``jobs/bench_memory.py`` once the heap's free pages were handed
        back before it (:mod:`base.heap`; docs/performance.md)."""
        preallocate = _hypre_preallocation()
        if preallocate is None:
            return self._hypre_converted(indptr, cols, values)
        PETSc = self._PETSc
        first, stop = self.owned_range
        d = np.empty(indptr.size - 1, dtype=indptr.dtype)
        o = np.empty_like(d)
        row_block_counts(indptr, cols, first, stop, d, o)
        mat = PETSc.Mat().create(comm=self.comm)
        mat.setSizes(((self.n_local, self.n_global), (self.n_local, self.n_global)))
        mat.setType(PETSc.Mat.Type.HYPRE)
        mat.setOptionsPrefix(self.prefix)
        mat.setOption(PETSc.Mat.Option.SORTED_FULL, True)
        code = preallocate(mat.handle, 0, d.ctypes.data, 0, o.ctypes.data)
        if code:
            raise SolverError(f"{self.prefix}: MatHYPRESetPreallocation failed (PETSc "
                              f"error {code})")
        mat.setValuesCSR(indptr, cols, values)
        mat.assemble()
        return mat

    def _hypre_converted(self, indptr, cols, values):
        """Collective: :meth:`_aij_over` converted in place to hypre's ParCSR matrix
        (petsc4py's ``convert`` without ``out``): a copy in hypre, after which nothing
        refers to the arrays.

        PETSc's assembly of a hypre matrix (inside the conversion) builds hypre's
        auxiliary per-row arrays anew, for values set later, unless the matrix is
        ``SORTED_FULL``: 16 bytes per entry and two allocations per row beside the
        ParCSR's 12 bytes per entry. No value is set later, so a second assembly with
        that option frees them: 33 -> 13 bytes per entry of the PPE's AMG matrix, 240
        bytes per particle of the 3D tank of ``jobs/bench_memory.py``
        (docs/performance.md; the matrix and the AMG's iterations are the same)."""
        PETSc = self._PETSc
        mat = self._aij_over(indptr, cols, values)
        mat.setOptionsPrefix(self.prefix)
        mat.convert(PETSc.Mat.Type.HYPRE)
        mat.setOption(PETSc.Mat.Option.SORTED_FULL, True)
        mat.assemble()
        return mat

    def _aij_over(self, indptr, cols, values):
        """Collective: an AIJ matrix over a checked CSR block of the owned rows (PETSc's
        index type), split in place on several ranks (see :meth:`assemble_csr_over`)."""
        PETSc = self._PETSc
        sizes = ((self.n_local, self.n_global), (self.n_local, self.n_global))
        if self.comm.size == 1:
            return PETSc.Mat().createAIJWithArrays(sizes, (indptr, cols, values),
                                                   comm=self.comm)
        first, stop = self.owned_range
        n_off = cols.size - count_diagonal(cols, first, stop)
        oi = np.empty_like(indptr)
        oj, ov = np.empty(n_off, dtype=indptr.dtype), np.empty(n_off)
        p, _ = split_in_place(indptr, cols, values, first, stop, oi, oj, ov)
        return PETSc.Mat().createAIJWithArrays(
            sizes, ((indptr, cols[:p], values[:p]), (oi, oj, ov)), comm=self.comm)

    def _build(self, rows, cols, keys, inverse, data) -> None:
        """Collective: a new matrix preallocated exactly from the CSR block of the owned rows."""
        int_type = self._PETSc.IntType
        local_row = keys // self.n_global
        indptr = np.zeros(self.n_local + 1, dtype=int_type)
        np.cumsum(np.bincount(local_row, minlength=self.n_local), out=indptr[1:])
        indices = (keys % self.n_global).astype(int_type)
        self._build_csr(indptr, indices, data, fresh=True)
        self._pattern.update(rows=rows.copy(), cols=cols.copy(), keys=keys, inverse=inverse)

    def _build_csr(self, indptr, indices, data, fresh: bool = False) -> None:
        """Collective: a new matrix preallocated exactly from a sorted CSR block
        (``indptr``, ``indices`` of PETSc's index type). The pattern is kept for the next
        assembly: copied unless ``fresh`` (arrays nobody else holds)."""
        PETSc = self._PETSc
        sizes = ((self.n_local, self.n_global), (self.n_local, self.n_global))
        if self.block_size == 1:
            # PETSc takes the arrays as they are (MatCreateSeqAIJWithArrays, or
            # MatCreateMPIAIJWithSplitArrays after a numba split into the diagonal and
            # off-diagonal blocks): no row-by-row insertion. 2.0e5 rows: 33 -> 4 ms on 1
            # rank, 23 -> 9 ms on 2. The matrix keeps references to its arrays, which are
            # the last matrix's (see _array): that one is destroyed below, unread since.
            nnz = indices.size
            if self.comm.size == 1:
                ptr = self._array("ptr", indptr.size, indptr.dtype)
                cols = self._array("cols", nnz, indices.dtype)
                vals = self._array("vals", nnz, np.float64)
                np.copyto(ptr, indptr)
                np.copyto(cols, indices)
                np.copyto(vals, data)
                csr = (ptr, cols, vals)
                indptr, indices = ptr, cols
            else:
                first, stop = self.owned_range
                di, oi = (self._array(k, indptr.size, indptr.dtype) for k in ("di", "oi"))
                # each part sized to its count (room for the whole block in both had
                # cost 12 bytes per entry more)
                n_diag = count_diagonal(indices, first, stop)
                dj = self._array("dj", n_diag, indices.dtype)
                dv = self._array("dv", n_diag, np.float64)
                oj = self._array("oj", nnz - n_diag, indices.dtype)
                ov = self._array("ov", nnz - n_diag, np.float64)
                pattern = self._array("pattern", nnz, indices.dtype)
                p, q = split_diagonal_block(indptr, indices, data, first, stop,
                                            di, dj, dv, oi, oj, ov, pattern)
                csr = ((di, dj[:p], dv[:p]), (oi, oj[:q], ov[:q]))
                indptr, indices = indptr.copy(), pattern
            mat = PETSc.Mat().createAIJWithArrays(sizes, csr, comm=self.comm)
        else:  # keeps the block size (BoomerAMG's number of functions)
            if not fresh:
                indptr, indices = indptr.copy(), indices.copy()
            mat = PETSc.Mat().create(comm=self.comm)
            mat.setSizes(sizes, bsize=self.block_size)
            mat.setType(PETSc.Mat.Type.AIJ)
            mat.setOptionsPrefix(self.prefix)
            mat.setPreallocationCSR((indptr, indices, data))  # inserts the values and assembles
        self._finish_build(mat)
        self._held = None
        self._pattern = dict(indptr=indptr, indices=indices)

    def _finish_build(self, mat) -> None:
        """Collective: options of a new matrix; it replaces the last one (whose
        preconditioner set-up goes too unless it is lagged)."""
        PETSc = self._PETSc
        mat.setOptionsPrefix(self.prefix)
        mat.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        mat.setOption(PETSc.Mat.Option.NO_OFF_PROC_ENTRIES, True)
        if self.symmetric:
            mat.setOption(PETSc.Mat.Option.SYMMETRIC, True)
            mat.setOption(PETSc.Mat.Option.SYMMETRY_ETERNAL, True)
        if self._nullspace is not None:
            self._attach_nullspace(mat)

        if self._mat is not None:
            if self._pc_age == 0:  # no lagged preconditioner to keep
                self._ksp.reset()  # frees the preconditioner built on the old pattern
            self._mat.destroy()
        self._mat = mat
        self.n_builds += 1

    def _array(self, name: str, size: int, dtype) -> np.ndarray:
        """Work array ``name`` of ``size`` entries for the matrix of this build.

        One set of arrays serves every build: the new matrix is written over the last
        one's arrays. That matrix is destroyed in the same build and nothing reads it
        after the new values are written (the KSP gets the new operator before its next
        set-up or solve; a lagged BoomerAMG set-up and the coupled product hold copies of
        their own). A second set, used in turn, had cost 12 bytes per entry on one rank
        and 28 on several, for each system (docs/solvers.md). Reused arrays spare the
        page faults of fresh ones (see :func:`solvers.csr.split_diagonal_block`). Grown
        by a quarter when too small."""
        store = self._arrays
        a = store.get(name)
        if a is None or a.size < size or a.dtype != np.dtype(dtype):
            a = np.empty(size + size // 4, dtype=dtype)
            store[name] = a
        return a[:size]

    def _lag(self, same_unknowns: bool) -> None:
        """Keep the last preconditioner set-up for the next solve, or ask for a fresh one.

        The inputs are the same on every rank (agreed flags, global iteration counts), so
        every rank decides alike."""
        keep = (same_unknowns and self._mat is not None
                and 0 < self._pc_age < self.reuse_preconditioner)
        if not keep:
            self._pc_age = 0
        self._ksp.getPC().setReusePreconditioner(keep)

    def set_product(self, ptr, cols, left, right, near, row_scale=None) -> None:
        """Collective: the operator of the next solve is the assembled matrix plus
        ``S left^T right`` minus ``near``; the preconditioner stays built on the matrix.

        Parameters
        ----------
        ptr, cols : numpy.ndarray of int
            CSR pattern of this rank's rows of ``left`` and ``right`` (any number of
            rows, ``ptr[0] == 0``), columns global unknowns of this system.
        left, right : numpy.ndarray of float64
            The values of the two blocks on that pattern.
        near : tuple of numpy.ndarray
            ``(indptr, cols, values)``: a CSR block of this rank's rows of the system
            (``n_local + 1`` row pointers, global columns sorted in each row), the part
            of ``left^T right`` the caller already added to the assembled matrix (so the
            operator is the matrix without it, plus the whole product).
        row_scale : numpy.ndarray of float64, optional
            ``S``, one factor per owned row (default 1): the caller scaled the rows of
            the assembled matrix and of ``near`` by it (e.g.
            :func:`solvers.csr.unit_diagonal`), and the product's rows get it too.

        Notes
        -----
        Call it after each :meth:`assemble_csr` whose operator should carry the product
        (an assembly drops it). If no rank has a row of ``left``, the operator is the
        matrix. See :mod:`solvers.product`.
        """
        from solvers.product import ProductOperator

        n_rows = ptr.shape[0] - 1
        self._drop_product()
        if (n_rows if self.comm.size == 1 else self.comm.allreduce(n_rows)) == 0:
            return
        self._product = ProductOperator(self._PETSc, self.comm, self._mat, n_rows, ptr, cols,
                                        left, right, near, row_scale)
        self._ksp.setOperators(self._product.mat, self._amg_matrix())

    def _drop_product(self) -> None:
        if getattr(self, "_product", None) is not None:
            self._product.free()
        self._product = None
