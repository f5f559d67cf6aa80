"""PETSc start-up and what the PETSc build offers.

petsc4py is imported here, lazily, and nowhere else in parsph: ``import solvers`` does
not load PETSc. The first call to :func:`init` (or to :func:`petsc`, which calls it
with no options) initialises PETSc with the command-line style options it is given, so
a job can pass ``-ppe_ksp_rtol 1e-10 -ppe_ksp_monitor``. Later calls, or a call after
somebody else already initialised PETSc, add their options to the global options
database instead, so they still reach every solver created afterwards.
"""
from __future__ import annotations

import functools
import sys
from typing import Sequence

#: Program name put in front of the options handed to ``petsc4py.init`` (PETSc's argv[0]).
_ARGV0 = "parsph"


def _quote(token: str) -> str:
    """One option token as PETSc's option-string parser reads it."""
    return f'"{token}"' if any(c.isspace() for c in token) else token


def init(petsc_args: Sequence[str] = ()):
    """Initialise PETSc once with command-line style options; return the PETSc module.

    Parameters
    ----------
    petsc_args : sequence of str
        Option tokens as on a command line, e.g. ``["-ppe_ksp_rtol", "1e-10",
        "-ppe_ksp_monitor"]``. A leading program name (a token not starting with
        ``-`` before the first option, as in ``sys.argv``) is harmless: PETSc skips it.

    Returns
    -------
    module
        ``petsc4py.PETSc``.

    Raises
    ------
    RuntimeError
        If PETSc was already finalised (the interpreter is shutting down).

    Notes
    -----
    ``petsc4py.init`` must run before the first ``from petsc4py import PETSc``, because
    importing the module initialises PETSc without options. If PETSc is already
    initialised (by an earlier call, or by a library that imported ``petsc4py.PETSc``
    itself) the options are inserted into the global options database with
    ``PETSc.Options().insertString``: they then act on every object configured with
    ``setFromOptions()`` afterwards, which is all that parsph's solvers need.
    Collective on ``MPI.COMM_WORLD`` the first time (``PetscInitialize``).
    """
    args = [str(a) for a in petsc_args]
    PETSc = sys.modules.get("petsc4py.PETSc")
    if PETSc is not None and PETSc.Sys.isFinalized():
        raise RuntimeError(
            "PETSc is already finalised; create solvers before the interpreter shuts down"
        )
    if PETSc is None or not PETSc.Sys.isInitialized():
        import petsc4py

        petsc4py.init([_ARGV0, *args])
        from petsc4py import PETSc
    elif args:
        PETSc.Options().insertString(" ".join(_quote(a) for a in args))
    return PETSc


def petsc():
    """The ``petsc4py.PETSc`` module, initialising PETSc without options if needed."""
    PETSc = sys.modules.get("petsc4py.PETSc")
    if PETSc is not None and PETSc.Sys.isInitialized() and not PETSc.Sys.isFinalized():
        return PETSc
    return init(())


def has_hypre() -> bool:
    """Whether this PETSc build was configured with hypre (``-pc_type hypre`` works)."""
    PETSc = petsc()
    has_package = getattr(PETSc.Sys, "hasExternalPackage", None)
    if has_package is not None:
        return bool(has_package("hypre"))
    pc = PETSc.PC().create(comm=PETSc.COMM_SELF)
    try:
        pc.setType("hypre")
    except PETSc.Error:
        return False
    finally:
        pc.destroy()
    return True


@functools.lru_cache(maxsize=None)
def hypre_preallocation():
    """PETSc's ``MatHYPRESetPreallocation`` as a ctypes function ``(Mat handle, dnz, dnnz
    pointer, onz, onnz pointer)``, or None where it cannot be found (a PETSc without
    hypre, or no shared library of PETSc among the process's mappings).

    petsc4py does not wrap it, and its ``setPreallocationNNZ`` does not reach a hypre
    matrix; without it hypre gives each row a default room that a longer row overflows.
    """
    import ctypes

    PETSc = petsc()
    paths = []
    try:
        with open("/proc/self/maps") as fh:
            paths = [line.split()[-1] for line in fh if "libpetsc" in line]
    except OSError:
        pass
    for path in dict.fromkeys(paths):
        try:
            fn = ctypes.CDLL(path).MatHYPRESetPreallocation
        except (OSError, AttributeError):
            continue
        index = ctypes.c_int64 if PETSc.IntType(0).itemsize == 8 else ctypes.c_int32
        fn.argtypes = [ctypes.c_void_p, index, ctypes.c_void_p, index, ctypes.c_void_p]
        fn.restype = ctypes.c_int
        return fn
    return None


def info() -> dict:
    """What ``parsph info`` prints about PETSc.

    Returns
    -------
    dict
        ``petsc_version`` (str, e.g. ``"3.18.5"``), ``petsc4py_version`` (str),
        ``hypre`` (bool: BoomerAMG available), ``int_size`` (int: bits of ``PetscInt``,
        32 or 64, which bounds the global number of unknowns), ``scalar_type`` (str:
        numpy name of ``PetscScalar``, ``"float64"`` for a real build),
        ``complex`` (bool) and ``release`` (bool: a release, not a development build).
    """
    import numpy as np
    import petsc4py

    PETSc = petsc()
    version = PETSc.Sys.getVersion()
    scalar = np.dtype(PETSc.ScalarType)
    return {
        "petsc_version": ".".join(str(v) for v in version),
        "petsc4py_version": str(petsc4py.__version__),
        "hypre": has_hypre(),
        "int_size": 8 * np.dtype(PETSc.IntType).itemsize,
        "scalar_type": scalar.name,
        "complex": scalar.kind == "c",
        "release": bool(PETSc.Sys.getVersionInfo().get("release", True)),
    }
