"""An operator ``A + L^T R - N``: an assembled matrix plus a product of two sparse blocks.

The strongly coupled pressure step (``parsph/fluid/response.py``) needs
``C + L^T R``, where ``L`` and ``R`` have one row per unknown of a few interface points
(owned by the rank that computes them) and couple unknowns up to two supports apart.
Forming ``L^T R`` explicitly (``MatTransposeMatMult``) costs the square of a row's
length per row and a parallel transpose: 84 ms on 2 ranks for 1.2e4 rows of 10 entries.
Instead the Krylov method applies it (two sparse mat-vecs, ``MatMult`` and
``MatMultTranspose``, in which PETSc does the communication), and the assembled matrix
``A = C + N`` the preconditioner is built on already holds the part ``N`` of the product
that the caller could assemble itself; the operator is exactly ``C + L^T R``.
"""
from __future__ import annotations

import numpy as np


class ProductOperator:
    """Context of a PETSc Python matrix ``y = A x + S L^T (R x) - N x`` (see the module
    docstring), ``S`` an optional diagonal scaling of the rows (``row_scale``: the
    caller scaled the rows of ``A`` and ``N`` by it). Owns ``L``, ``R``, ``N`` and its
    work vectors; :meth:`free` frees them (collective)."""

    def __init__(self, PETSc, comm, A, n_rows, ptr, cols, left, right, near, row_scale=None):
        self.A = A
        int_type = PETSc.IntType
        ptr = np.ascontiguousarray(ptr, dtype=int_type)
        cols = np.ascontiguousarray(cols, dtype=int_type)
        (n_local, n_global) = A.getSizes()[1]
        sizes = ((n_rows, None), (n_local, n_global))
        # the matrices may keep references to their arrays (one rank): hold them here
        self._arrays = (ptr, cols, np.ascontiguousarray(left, dtype=np.float64),
                        np.ascontiguousarray(right, dtype=np.float64))
        self.L = PETSc.Mat().createAIJ(sizes, csr=(ptr, cols, self._arrays[2]), comm=comm)
        self.R = PETSc.Mat().createAIJ(sizes, csr=(ptr, cols, self._arrays[3]), comm=comm)
        nptr, ncols, nvals = near
        self._near = (np.ascontiguousarray(nptr, dtype=int_type),
                      np.ascontiguousarray(ncols, dtype=int_type),
                      np.ascontiguousarray(nvals, dtype=np.float64))
        self.N = PETSc.Mat().createAIJ(A.getSizes(), csr=self._near, comm=comm)
        self._u = self.R.createVecLeft()
        self._t = A.createVecLeft()
        self._s = None
        if row_scale is not None:
            self._s = A.createVecLeft()
            self._s.setArray(np.asarray(row_scale, dtype=np.float64))
        self.mat = PETSc.Mat().createPython(A.getSizes(), context=self, comm=comm)
        self.mat.setUp()

    def mult(self, mat, x, y) -> None:
        """``y = A x - N x + S L^T (R x)``."""
        self.A.mult(x, y)
        self.N.mult(x, self._t)
        y.axpy(-1.0, self._t)
        self.R.mult(x, self._u)
        if self._s is None:
            self.L.multTransposeAdd(self._u, y, y)
        else:
            self.L.multTranspose(self._u, self._t)
            self._t.pointwiseMult(self._t, self._s)
            y.axpy(1.0, self._t)

    def free(self) -> None:
        """Collective: destroy the PETSc objects (``destroy`` is the name petsc4py calls on
        a Python matrix's context)."""
        mat, self.mat = self.mat, None
        for obj in (self.L, self.R, self.N, self._u, self._t, self._s):
            if obj is not None:
                obj.destroy()
        self.A = None
        mat.destroy()
