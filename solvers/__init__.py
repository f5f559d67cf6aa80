"""Implicit linear systems on PETSc: the only package of parsph that imports petsc4py.

It knows no particles, only global indices and values. petsc4py is imported lazily, on
the first :func:`init`, :class:`LinearSystem` or :func:`petsc_env.info` call, so
``import solvers`` does not load PETSc.

Typical use::

    import solvers
    solvers.init(["-ppe_ksp_monitor"])          # once, before the first system
    with solvers.LinearSystem(comm, "ppe_", n_owned) as ppe:
        ppe.assemble(rows, cols, values)         # global triplets of owned rows
        p, info = ppe.solve(rhs, x0=p_old)       # local arrays

See ``docs/solvers.md``.
"""
from solvers.petsc_env import init
from solvers.errors import SolverError
from solvers.system import LinearSystem
from solvers.operator import OperatorSystem

__all__ = ["init", "LinearSystem", "OperatorSystem", "SolverError"]
