"""A block system whose operator is applied matrix-free, preconditioned by scalar AMG.

The implicit viscous predictor of eq. (34) has ``dim x dim`` blocks ``c r r^T`` per
neighbour pair: assembled in 3D (~57 neighbours) that is ~510 entries per point, held
three times (the caller's CSR work arrays, PETSc's AIJ, hypre's ParCSR) plus the AMG
hierarchy on it, 7.5 of the 12.9 KB per particle a 3D coupled step needed
(docs/performance.md). Here the Krylov method applies the operator through a callback
(the caller's pair loop over its own coefficients, one per pair) and BoomerAMG works on
one *scalar* matrix of the same pairs (one entry per pair: the blocks' traces over
``dim``), applied to each component in turn. The communication of the operator is one
PETSc scatter of the other ranks' unknowns the rows reach, as ``MatMult`` of an MPIAIJ
matrix does.
"""
from __future__ import annotations

import numpy as np

from solvers.system import LinearSystem

#: GMRES restart of the solves :meth:`OperatorSystem.set_jacobi` preconditions (unless an
#: ``-{prefix}ksp_gmres_restart`` option is given). Their operator is close to the identity
#: and they take 2-4 iterations, but PETSc allocates GMRES's directions ten at a time: a
#: third iteration held 15 vectors of the system, 226 bytes per particle in the 3D tank of
#: ``jobs/bench_memory.py``, 118 with this restart (docs/performance.md).
JACOBI_RESTART = 3
#: PETSc's GMRES restart, that of the AMG-preconditioned solves.
GMRES_RESTART = 30


class _Operator:
    """Context of the PETSc Python matrix: ``y = A x`` through the caller's callback."""

    def __init__(self, system):
        self.system = system

    def mult(self, mat, x, y) -> None:
        s = self.system
        u = s._u
        n = s.n_local_rows
        u[:n] = x.getArray(readonly=True).reshape(n, s.block_size)
        if s._scatter is not None:
            s._scatter.scatter(x, s._ghost_vec, addv=s._PETSc.InsertMode.INSERT_VALUES,
                               mode=s._PETSc.ScatterMode.FORWARD)
        s._apply(u, y.getArray().reshape(n, s.block_size))


class _ComponentAMG:
    """Context of the PETSc Python preconditioner: the scalar matrix's BoomerAMG applied
    to each component of the block vector."""

    def __init__(self, system):
        self.system = system

    def apply(self, pc, b, x) -> None:
        s = self.system
        inner = s.scalar
        n, bs = s.n_local_rows, s.block_size
        B = b.getArray(readonly=True).reshape(n, bs)
        X = x.getArray().reshape(n, bs)
        if s._inv_diag is not None:  # Jacobi (set_jacobi)
            np.multiply(B, s._inv_diag[:, None], out=X)
        else:
            amg = inner.ksp.getPC()
            for a in range(bs):
                inner._b.getArray()[:] = B[:, a]
                amg.apply(inner._b, inner._x)
                X[:, a] = inner._x.getArray(readonly=True)
        if s._correct is not None:  # rows the caller solves exactly, given the others
            u = s._u
            u[:n] = X
            if s._scatter is not None:
                s._scatter.scatter(x, s._ghost_vec, addv=s._PETSc.InsertMode.INSERT_VALUES,
                                   mode=s._PETSc.ScatterMode.FORWARD)
            s._correct(u, B, X)


class OperatorSystem(LinearSystem):
    """A block system ``A x = b`` (``block_size`` unknowns per point) whose operator is a
    callback and whose preconditioner is BoomerAMG on a scalar matrix of the points.

    Parameters are those of :class:`solvers.LinearSystem` (the Krylov method defaults to
    GMRES, preconditioned from the right, so the tolerance is on the true residual).
    The scalar matrix is a :class:`~solvers.LinearSystem` of its own with the options
    prefix ``{prefix}amg_`` (e.g. ``-visc_amg_pc_hypre_boomeramg_strong_threshold 0.5``).

    Use: :meth:`set_operator` with the callback and the points of other ranks it reads,
    :meth:`assemble_preconditioner` with the scalar matrix (or :meth:`set_jacobi` with its
    inverse diagonal, for an operator close to the identity), then :meth:`solve`;
    :meth:`release` frees what the solves used (the AMG set-up, the operator and the
    caller's arrays it holds, the Krylov vectors) when none will follow before the next
    :meth:`set_operator`.
    """

    def __init__(self, comm, prefix, n_local_rows, block_size, ksp_type="gmres",
                 rtol=1e-8, atol=1e-50, max_it=1000, hypre_options=None):
        super().__init__(comm, prefix, n_local_rows, block_size=block_size,
                         ksp_type=ksp_type, pc_type="none", rtol=rtol, atol=atol,
                         max_it=max_it, symmetric=False, pc_side="right")
        PETSc = self._PETSc
        self.scalar = LinearSystem(comm, self.prefix + "amg_", n_local_rows, block_size=1,
                                   ksp_type="preonly", pc_type="hypre", symmetric=False,
                                   hypre_options=hypre_options)
        pc = self._ksp.getPC()
        pc.setType(PETSc.PC.Type.PYTHON)
        pc.setPythonContext(_ComponentAMG(self))
        self._ksp.setFromOptions()  # the options database still wins
        opts = self._PETSc.Options()
        self._restart = None if self._ksp.getType() != "gmres" or opts.hasName(
            self.prefix + "ksp_gmres_restart") else GMRES_RESTART
        self._apply = self._correct = self._inv_diag = None
        self._scatter = self._ghost_vec = self._ghost_is = None
        self._u = np.empty((0, self.block_size))

    def set_operator(self, apply, ghost_points, correct=None) -> None:
        """Collective: the operator of the next solves.

        Parameters
        ----------
        apply : callable
            ``apply(u, out)``: writes ``A u`` for the owned rows into ``out`` (shape
            (n_local_rows, block_size)); ``u`` holds the owned rows' unknowns (rows
            ``0 .. n_local_rows - 1``) followed by those of ``ghost_points`` in order.
        correct : callable, optional
            ``correct(u, b, out)``, run after each BoomerAMG application ``out = M b``
            with ``u`` holding ``out`` as ``apply`` reads it: rewrites, in ``out``, rows
            the caller solves exactly given the others (a block Gauss-Seidel step after
            the AMG; the preconditioner stays linear).
        ghost_points : numpy.ndarray of int
            Global point indices (rows of block ``block_size``) of other ranks (or of
            this one: periodic images) whose unknowns ``apply`` reads.
        """
        PETSc = self._PETSc
        ghost_points = np.ascontiguousarray(ghost_points, dtype=self.index_dtype)
        n, bs = self.n_local_rows, self.block_size
        self._free_operator()
        self._u = np.empty((n + ghost_points.size, bs))
        if self.comm.size > 1 or ghost_points.size:  # (creating a scatter is collective)
            self._ghost_vec = PETSc.Vec().createWithArray(self._u[n:].reshape(-1),
                                                          comm=PETSc.COMM_SELF)
            self._ghost_is = PETSc.IS().createBlock(bs, ghost_points, comm=PETSc.COMM_SELF)
            self._scatter = PETSc.Scatter().create(self._b, self._ghost_is, self._ghost_vec,
                                                   None)
        self._apply = apply
        self._correct = correct
        if self._mat is None:
            self._mat = PETSc.Mat().createPython(
                ((self.n_local, self.n_global), (self.n_local, self.n_global)),
                context=_Operator(self), comm=self.comm)
            self._mat.setUp()
        self._lag(False)
        self._ksp.setOperators(self._mat)

    def assemble_preconditioner(self, indptr, cols, values) -> None:
        """Collective: the scalar matrix (one row per point, global point columns; see
        :meth:`solvers.LinearSystem.assemble_csr`) BoomerAMG is set up on, afresh."""
        self._inv_diag = None
        self._set_restart(GMRES_RESTART)
        self.scalar.set_up_preconditioner_csr(indptr, cols, values)

    def set_jacobi(self, inverse_diagonal) -> None:
        """Collective: precondition the next solves by Jacobi instead, ``x = b / d`` per
        point and component (``inverse_diagonal``: ``1 / d``, one value per owned point;
        then ``correct``, as after the AMG): no matrix, no set-up. For an operator close
        to the identity (a viscous step at a small viscous number, whose rows are ``1 +
        S`` on the diagonal and ``S`` off it: Jacobi's error falls by ``S / (1 + S)`` per
        sweep), where an AMG set-up costs more than it saves."""
        self.scalar.release()
        self._set_restart(JACOBI_RESTART)
        self._inv_diag = np.ascontiguousarray(inverse_diagonal, dtype=np.float64)

    def _set_restart(self, k: int) -> None:
        """GMRES's restart for the next solves (PETSc frees its vectors on a change), unless
        the method is not GMRES or the options database sets the restart."""
        if self._restart is not None and self._restart != k:
            self._ksp.setGMRESRestart(k)
            self._restart = k

    def release(self) -> None:
        """Collective: free what the last solves used, now: the scalar matrix and its AMG
        hierarchy, the operator's callback (and with it the caller's arrays it reads), the
        scatter of the other ranks' unknowns and the Krylov method's vectors. The next
        :meth:`set_operator` and :meth:`assemble_preconditioner` (or :meth:`set_jacobi`)
        set them up again; no solve before them. Held until then, they sat beside the
        pressure system's and the next step's neighbour lists: 3D coupled steps
        peaked with both (docs/performance.md)."""
        self.scalar.release()
        self._free_operator()
        self._apply = self._correct = self._inv_diag = None
        self._u = np.empty((0, self.block_size))
        super().release()  # the KSP's vectors and the operator's PETSc matrix

    def resize(self, n_local_rows: int) -> None:
        """Collective: the same system over a new number of rows (see
        :meth:`solvers.LinearSystem.resize`); the operator must be set again."""
        super().resize(n_local_rows)  # (and release())
        self.scalar.resize(n_local_rows)

    def _free_operator(self) -> None:
        for obj in (self._scatter, self._ghost_vec, self._ghost_is):
            if obj is not None:
                obj.destroy()
        self._scatter = self._ghost_vec = self._ghost_is = None

    def destroy(self) -> None:
        """Collective: free the PETSc objects; safe to call more than once."""
        if not self._PETSc.Sys.isFinalized():
            self._free_operator()
            if getattr(self, "scalar", None) is not None:
                self.scalar.destroy()
        self.scalar = None
        super().destroy()

    def __repr__(self) -> str:
        return "Operator" + super().__repr__()
