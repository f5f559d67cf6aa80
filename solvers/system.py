"""A distributed sparse linear system ``A x = b`` solved with a PETSc KSP.

The system knows no particles: the caller hands in global (row, column, value) triplets
and right-hand sides as local numpy arrays, and gets local numpy arrays back. The rows
of a rank are one contiguous block of the global numbering
(:func:`decomposition.numbering.global_offset`), which is the layout PETSc's MPIAIJ
matrices and MPI vectors use.

This module owns the system's set-up and the solve side (KSP and preconditioner options,
the hypre defaults, the lagged preconditioner, the solve and its failure report); the
matrix side is :mod:`solvers.matrix`, failures agreed on by every rank
:mod:`solvers.errors`.
"""
from __future__ import annotations

import logging
import time

import numpy as np

from decomposition.numbering import global_offset
from decomposition.reduce import global_any
from solvers import petsc_env
from solvers.errors import SolverError, agree
from solvers.matrix import MatrixAssembly

log = logging.getLogger(__name__)

#: Largest global index a 32-bit ``PetscInt`` can hold.
_INT32_MAX = 2**31 - 1

#: Krylov methods that need a symmetric operator (used for the default of ``symmetric``).
_SYMMETRIC_KSP = ("cg", "minres", "cr", "pipecg", "pipecr", "groppcg", "nash", "stcg")


def _reason_names(PETSc) -> dict[int, str]:
    """``KSP.ConvergedReason`` value → name (aliases resolved to the first name in order)."""
    names: dict[int, str] = {}
    reasons = PETSc.KSP.ConvergedReason
    for name in sorted(dir(reasons)):
        value = getattr(reasons, name)
        if name.isupper() and isinstance(value, int):
            names.setdefault(int(value), name)
    return names


#: BoomerAMG options parsph sets under each system's prefix unless they are given.
_HYPRE_DEFAULTS = {"pc_hypre_boomeramg_relax_type_down": "l1-Gauss-Seidel",
                   "pc_hypre_boomeramg_relax_type_up": "backward-l1-Gauss-Seidel"}


def _normalise_prefix(prefix: str) -> str:
    """``"ppe"`` and ``"-ppe_"`` both become ``"ppe_"``; ``""`` stays empty."""
    prefix = str(prefix).lstrip("-")
    if prefix and not prefix.endswith("_"):
        prefix += "_"
    return prefix


class LinearSystem(MatrixAssembly):
    """A sparse system with an options prefix, assembled in bulk and solved by a KSP.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
        Communicator of the system; every method is collective on it.
    prefix : str
        PETSc options prefix, e.g. ``"ppe_"`` or ``"visc_"`` (a missing trailing ``_``
        is added). Options ``-{prefix}ksp_*`` and ``-{prefix}pc_*`` override the
        defaults below.
    n_local_rows : int
        Number of points (block rows) this rank owns, ≥ 0. The rank owns
        ``n_local_rows * block_size`` scalar unknowns.
    block_size : int, optional
        Scalar unknowns per point: 1 for the pressure Poisson equation, ``dim`` for the
        vector unknowns of the viscous predictor. Unknowns are interleaved by point:
        component ``c`` of global point ``p`` is global row ``p * block_size + c``.
    ksp_type : str, optional
        Default Krylov method (``"cg"``; ``"gmres"`` for non-symmetric operators).
    pc_type : str, optional
        Default preconditioner (``"hypre"`` = BoomerAMG). If this PETSc build has no
        hypre, ``"gamg"`` is used instead and a warning logged.
    rtol, atol : float, optional
        Default relative and absolute tolerances of the KSP convergence test
        (dimensionless and in the units of the residual norm).
    max_it : int, optional
        Default maximum number of iterations.
    symmetric : bool or None, optional
        Declare the operator symmetric (sets ``MAT_SYMMETRIC`` and
        ``MAT_SYMMETRY_ETERNAL``, and makes the constant null space also the transpose
        null space). None means True for symmetric Krylov methods (``cg``, ``minres``…)
        and False otherwise. It is a promise, not checked.
    reuse_preconditioner : int, optional
        Solves that may share one preconditioner set-up (1: a fresh set-up for every new
        matrix). A set-up is only kept for a matrix whose caller declares the same
        unknowns (``assemble_csr(..., same_unknowns=True)``); see Notes.
    hypre_options : dict of str to str, optional
        More BoomerAMG defaults of this system, e.g. ``{"pc_hypre_boomeramg_agg_nl":
        "1"}`` (without the prefix), set like the smoother's: options given in the
        database win.
    pc_side : str, optional
        ``"left"`` (PETSc's default: the KSP tests the preconditioned residual) or
        ``"right"``: it tests the true residual ``b - A x``, whose norm an ``atol`` in the
        equation's own units can bound (the PPE's density error, docs/iisph.md); the
        options database wins (``-{prefix}ksp_pc_side``).
    options : dict of str to str, optional
        More defaults of this system's options, without the prefix (e.g.
        ``{"sub_pc_type": "icc"}``); options given in the database win.

    Attributes
    ----------
    offset : int
        First global scalar row of this rank (a multiple of ``block_size``).
    n_local : int
        Scalar unknowns of this rank, ``n_local_rows * block_size``.
    n_global : int
        Scalar unknowns of all ranks.
    n_builds : int
        How many times a matrix was (re)built because the sparsity pattern changed.
    n_setups : int
        How many fresh preconditioner set-ups were asked for (one per new matrix when
        ``reuse_preconditioner`` is 1).
    fresh_setup : bool
        Whether the last :meth:`solve` set its preconditioner up afresh.

    Notes
    -----
    Rank ``r`` owns global rows ``offset … offset + n_local − 1`` where ``offset`` is
    the exclusive prefix sum of ``n_local`` over ranks
    (:func:`decomposition.numbering.global_offset`); a rank owning no row takes part in
    every call. Defaults are set in code first, then the options prefix, then
    ``KSP.setFromOptions()``, so the options database wins, for example::

        -ppe_ksp_rtol 1e-10 -ppe_ksp_monitor -ppe_pc_hypre_boomeramg_strong_threshold 0.5

    The object owns its PETSc objects: call :meth:`destroy` (or use it as a context
    manager) on every rank.

    *Lagged preconditioner.* With ``reuse_preconditioner = k > 1`` the AMG hierarchy of
    a matrix serves as preconditioner of the next ``k - 1`` matrices over the same
    unknowns (``PCSetReusePreconditioner``): the Krylov method works on the new matrix,
    so the solution meets the same tolerance; only the iteration count may grow. A lagged
    solve may take at most ``REUSE_GROWTH`` times the iterations of the solve after the
    last set-up (plus 2); one that has not converged by then is solved again from its
    initial guess with a fresh set-up and the full ``max_it``.
    """

    #: A lagged solve may take this factor times the iterations of the first solve after
    #: its set-up (plus 2); beyond, the preconditioner is set up afresh.
    REUSE_GROWTH = 1.5

    def __init__(
        self,
        comm,
        prefix: str,
        n_local_rows: int,
        block_size: int = 1,
        ksp_type: str = "cg",
        pc_type: str = "hypre",
        rtol: float = 1e-8,
        atol: float = 1e-50,
        max_it: int = 1000,
        symmetric: bool | None = None,
        reuse_preconditioner: int = 1,
        hypre_options: dict | None = None,
        pc_side: str = "left",
        options: dict | None = None,
    ):
        PETSc = petsc_env.petsc()
        self._PETSc = PETSc
        self.comm = comm
        self.prefix = _normalise_prefix(prefix)
        self.block_size = int(block_size)
        if self.block_size < 1:
            raise ValueError(f"{self.prefix}: need block_size >= 1, got {block_size}")
        self._set_sizes(n_local_rows)
        self.symmetric = ksp_type in _SYMMETRIC_KSP if symmetric is None else bool(symmetric)
        self.n_builds = 0
        self.reuse_preconditioner = max(1, int(reuse_preconditioner))
        self.n_setups = 0
        self.fresh_setup = True
        self._pc_age = 0  # solves since the last fresh set-up (0: the next one sets up)
        self._pc_iterations = 0  # iterations of the first solve after that set-up
        self._reasons = _reason_names(PETSc)

        self._b = self._x = None
        self._create_vectors()
        self._mat = None
        self._product = None  # an operator matrix + L^T R (set_product)
        self._nullspace = None
        self._pattern = None  # indptr, indices (+ keys, inverse, rows, cols from triplets) of the last assembly
        self._arrays = {}  # arrays of the matrices built on arrays, see _array
        self._held = None  # the caller's arrays a matrix is built over (assemble_csr_over)
        self._pmat = None  # a sparser matrix BoomerAMG was set up on (assemble_csr_over)
        if options:  # the system's own defaults; options given in the database win
            opts = PETSc.Options()
            for key, value in options.items():
                if not opts.hasName(self.prefix + key):
                    opts.setValue(self.prefix + key, value)
        self._ksp = self._create_ksp(ksp_type, pc_type, rtol, atol, max_it,
                                     {**_HYPRE_DEFAULTS, **(hypre_options or {})}, pc_side)

    # -- set-up ---------------------------------------------------------------------

    def _set_sizes(self, n_local_rows) -> None:
        """Collective: this rank's rows and the global layout (offset, total)."""
        n_local_rows = int(n_local_rows)
        bad = n_local_rows < 0
        self.n_local_rows = max(n_local_rows, 0)
        self.n_local = self.n_local_rows * self.block_size
        self.offset, self.n_global = global_offset(self.comm, self.n_local)
        if global_any(self.comm, bad):
            raise ValueError(f"{self.prefix}: need n_local_rows >= 0 on every rank, got "
                             f"{n_local_rows} on this one" if bad else
                             f"{self.prefix}: another rank asked for a negative number of rows")
        if self.n_global == 0:
            raise ValueError(f"{self.prefix}: the system has no unknowns on any rank")
        if np.dtype(self._PETSc.IntType).itemsize == 4 and self.n_global > _INT32_MAX:
            raise ValueError(
                f"{self.prefix}: {self.n_global} unknowns exceed this PETSc's 32-bit indices; "
                "use a PETSc built with --with-64-bit-indices or a coarser particle size"
            )

    def _create_vectors(self) -> None:
        for v in (self._b, self._x):
            if v is not None:
                v.destroy()
        sizes = (self.n_local, self.n_global)
        self._b = self._PETSc.Vec().createMPI(sizes, bsize=self.block_size, comm=self.comm)
        self._x = self._b.duplicate()

    def resize(self, n_local_rows: int) -> None:
        """Collective: the same system over a new number of rows on this rank (particles
        moved between ranks). The matrix and the preconditioner set-up are dropped (the
        next :meth:`assemble` builds anew, the next solve sets up afresh); the KSP with
        its options and the work arrays of the matrices are kept. A new system instead
        faults in fresh pages for its work arrays on its first two builds: the two steps
        after the first migration of the 2-rank dam break at 2.0e5 particles took 463 and
        389 ms with new systems, 387-438 and 325 ms resized (a step: 320 ms).

        A block system (``block_size > 1``) also gets a new BoomerAMG object: hypre keeps
        the function of each unknown (its ``dof_func``, built at the first set-up for
        that many rows) across set-ups and reads it past its end for rows added later.
        On that uninitialised memory a block system grown from 36 to 400 points took 23
        GMRES iterations where a new one took 7 (tests/test_solvers.py), and one-rank
        runs of ``slope_failure`` (whose viscous system grows as particles fluidise)
        differed from run to run.

        Raises
        ------
        ValueError
            On every rank, as the constructor (negative rows, no rows anywhere, too many
            for 32-bit indices).
        """
        self.release()
        self._set_sizes(n_local_rows)
        self._create_vectors()
        if self.block_size > 1:
            self._renew_boomeramg()

    def _renew_boomeramg(self) -> None:
        """Collective: replace the KSP's hypre preconditioner by a new one, configured as
        before from the options database (where :meth:`_create_ksp` put the defaults)."""
        PETSc = self._PETSc
        pc = self._ksp.getPC()
        if pc.getType() != PETSc.PC.Type.HYPRE:
            return
        pc.setType(PETSc.PC.Type.NONE)  # destroys the hypre solver with its dof_func
        pc.setType(PETSc.PC.Type.HYPRE)
        pc.setHYPREType("boomeramg")
        pc.setFromOptions()

    def _create_ksp(self, ksp_type, pc_type, rtol, atol, max_it, hypre_defaults, pc_side):
        """Defaults in code, then the options prefix, then ``setFromOptions``."""
        if pc_side not in ("left", "right"):
            raise ValueError(f"{self.prefix}: pc_side is 'left' or 'right', got {pc_side!r}")
        PETSc = self._PETSc
        ksp = PETSc.KSP().create(comm=self.comm)
        ksp.setType(ksp_type)
        if pc_type == "hypre" and not petsc_env.has_hypre():
            log.warning("%s: this PETSc has no hypre; using -%spc_type gamg", self.prefix, self.prefix)
            pc_type = "gamg"
        pc = ksp.getPC()
        pc.setType(pc_type)
        if pc_type == "hypre":
            pc.setHYPREType("boomeramg")
            # Smoother: one forward l1-Gauss-Seidel sweep down, one backward sweep up (a
            # symmetric V-cycle). PETSc's default, hybrid symmetric SOR, sweeps both ways
            # on each visit: at 2.0e5 PPE rows the same iterations (5-11), 35 % less time
            # per solve. The options database still wins (also ..._relax_type_all).
            opts = PETSc.Options()
            relax_all = opts.hasName(self.prefix + "pc_hypre_boomeramg_relax_type_all")
            for key, value in hypre_defaults.items():
                if relax_all and key.startswith("pc_hypre_boomeramg_relax_type_"):
                    continue
                if not opts.hasName(self.prefix + key):
                    opts.setValue(self.prefix + key, value)
        ksp.setTolerances(rtol=rtol, atol=atol, max_it=max_it)
        if pc_side == "right":
            ksp.setPCSide(PETSc.PC.Side.RIGHT)
        ksp.setOptionsPrefix(self.prefix)
        ksp.setFromOptions()
        return ksp

    @property
    def mat(self):
        """The current ``PETSc.Mat`` (None before the first :meth:`assemble`); destroyed,
        and its arrays reused, when a later assembly builds a new matrix."""
        return self._mat

    @property
    def index_dtype(self) -> np.dtype:
        """numpy dtype of PETSc's indices (``PetscInt``: int32, or int64 in a 64-bit build);
        CSR blocks of this type reach PETSc without a conversion."""
        return np.dtype(self._PETSc.IntType)

    @property
    def ksp(self):
        """The ``PETSc.KSP`` (type, tolerances and preconditioner after the options)."""
        return self._ksp

    @property
    def owned_range(self) -> tuple[int, int]:
        """``(first, last + 1)`` global scalar rows owned by this rank."""
        return self.offset, self.offset + self.n_local

    # -- assembly: solvers.matrix.MatrixAssembly ------------------------------------

    # -- solve ----------------------------------------------------------------------

    def solve(self, rhs, x0=None):
        """Collective: solve ``A x = rhs`` for this rank's unknowns.

        Parameters
        ----------
        rhs : numpy.ndarray of float64
            Right-hand side of the owned rows, ``n_local`` values in any shape (e.g.
            ``(n_local_rows, block_size)``).
        x0 : numpy.ndarray of float64, optional
            Initial guess of the same size (e.g. the previous step's pressure); without
            it the KSP starts from zero.

        Returns
        -------
        x : numpy.ndarray of float64
            Solution of the owned rows, same shape as ``rhs`` (a copy).
        info : dict
            ``iterations`` (int), ``residual_norm`` (float: the norm the KSP tests, the
            preconditioned residual for CG by default), ``reason`` (int, > 0),
            ``reason_name`` (str, e.g. ``"CONVERGED_RTOL"``), ``time_s`` (float: wall
            time of ``KSPSolve`` on this rank, seconds), ``fresh_setup`` (bool: the
            preconditioner was set up for this matrix, not lagged).

        Raises
        ------
        SolverError
            On every rank if the KSP did not converge (``reason <= 0``).
        ValueError
            On every rank if some rank's ``rhs`` or ``x0`` has the wrong size.
        RuntimeError
            If called before :meth:`assemble`.
        """
        if self._mat is None:
            raise RuntimeError(f"{self.prefix}: call assemble() before solve()")
        rhs = np.asarray(rhs, dtype=np.float64)
        x0 = None if x0 is None else np.asarray(x0, dtype=np.float64)
        error = None
        for name, array in (("rhs", rhs), ("x0", x0)):
            if array is not None and array.size != self.n_local:
                error = ValueError, (
                    f"{self.prefix}: {name} has {array.size} values, this rank owns {self.n_local} "
                    f"unknowns ({self.n_local_rows} points x block size {self.block_size})"
                )
        agree(self.comm, error)

        self._b.setArray(rhs.reshape(-1))
        if x0 is None:
            self._x.set(0.0)
        else:
            self._x.setArray(x0.reshape(-1))
        self._ksp.setInitialGuessNonzero(x0 is not None)
        self.fresh_setup = self._pc_age == 0
        start = time.perf_counter()
        if self.fresh_setup:
            self._ksp.solve(self._b, self._x)
        else:
            # a lagged preconditioner gets at most REUSE_GROWTH times the iterations of the
            # solve after its set-up (+2); a matrix that changed too much for it (one step
            # of a 4e5-particle dam break took 180 lagged iterations against 21 fresh) is
            # solved again from x0 with a fresh set-up
            max_it = self._ksp.getTolerances()[3]
            cap = min(max_it, int(self.REUSE_GROWTH * self._pc_iterations) + 2)
            self._ksp.setTolerances(max_it=cap)
            try:
                self._ksp.solve(self._b, self._x)
            finally:
                self._ksp.setTolerances(max_it=max_it)
            if int(self._ksp.getConvergedReason()) <= 0:
                self._ksp.getPC().setReusePreconditioner(False)
                self._ksp.setOperators(self._ksp.getOperators()[0], self._mat)
                self._pc_age = 0
                self._x.set(0.0) if x0 is None else self._x.setArray(x0.reshape(-1))
                self._ksp.solve(self._b, self._x)
                self.fresh_setup = True
        reason = int(self._ksp.getConvergedReason())
        if reason == int(self._PETSc.KSP.ConvergedReason.DIVERGED_DTOL) and x0 is not None:
            # the initial guess was far off (the last step's pressure after a violent
            # step: 6e10 Pa where 6e3 were wanted): solved again from zero
            self._x.set(0.0)
            self._ksp.solve(self._b, self._x)
            reason = int(self._ksp.getConvergedReason())
        elapsed = time.perf_counter() - start

        iterations = int(self._ksp.getIterationNumber())
        if self.fresh_setup:
            self.n_setups += 1
            self._pc_iterations = iterations
        self._pc_age += 1
        info = dict(
            iterations=iterations,
            residual_norm=float(self._ksp.getResidualNorm()),
            reason=reason,
            reason_name=self._reasons.get(reason, f"UNKNOWN_{reason}"),
            time_s=elapsed,
            fresh_setup=self.fresh_setup,
        )
        if reason <= 0:
            raise SolverError(self._failure_message(info))
        return self._x.getArray(readonly=True).copy().reshape(rhs.shape), info

    def _failure_message(self, info: dict) -> str:
        p = self.prefix
        rtol, atol, _, max_it = self._ksp.getTolerances()
        return (
            f"linear solve '{p}' did not converge: {info['reason_name']} ({info['reason']}) after "
            f"{info['iterations']} iterations, residual norm {info['residual_norm']:.3e} "
            f"(rtol {rtol:g}, atol {atol:g}, max_it {max_it}; ksp {self._ksp.getType()}, "
            f"pc {self._ksp.getPC().getType()}). Try a smaller time step; or another solver or "
            f"preconditioner, e.g. -{p}ksp_type gmres, -{p}pc_type gamg or -{p}pc_type lu "
            f"(small runs); or -{p}ksp_max_it N; watch it with -{p}ksp_monitor -{p}ksp_converged_reason"
        )

    # -- clean-up -------------------------------------------------------------------

    def destroy(self) -> None:
        """Collective: free the PETSc objects; safe to call more than once."""
        if not self._PETSc.Sys.isFinalized():
            self._drop_product()
            for obj in (self._ksp, self._mat, self._pmat, self._nullspace, self._x, self._b):
                if obj is not None:
                    obj.destroy()
        self._ksp = self._mat = self._pmat = self._nullspace = self._x = self._b = None
        self._pattern = None
        self._arrays = {}
        self._held = None

    def __enter__(self) -> "LinearSystem":
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()

    def __repr__(self) -> str:
        return (
            f"LinearSystem(prefix={self.prefix!r}, rows {self.offset}..{self.offset + self.n_local - 1} "
            f"of {self.n_global}, block_size={self.block_size})"
        )
