"""``parsph info``: versions of the stack parsph runs on."""
from __future__ import annotations

import platform


def info() -> dict:
    """Versions of Python, MPI, mpi4py, PETSc (and hypre), HDF5 (and parallel), numba, numpy."""
    import h5py
    import mpi4py
    import numba
    import numpy
    from mpi4py import MPI

    import parsph
    import solvers.petsc_env as petsc_env

    lib = MPI.Get_library_version().strip().splitlines()[0]
    pinfo = petsc_env.info()
    return {
        "parsph": parsph.__version__,
        "python": platform.python_version(),
        "MPI": f"{lib} (standard {'.'.join(map(str, MPI.Get_version()))})",
        "mpi4py": mpi4py.__version__,
        "PETSc": pinfo.get("petsc_version", "?"),
        "petsc4py": pinfo.get("petsc4py_version", "?"),
        "hypre": "yes" if pinfo.get("hypre") else "no",
        "HDF5": f"{h5py.version.hdf5_version} ({'parallel' if h5py.get_config().mpi else 'serial'})",
        "h5py": h5py.__version__,
        "numba": numba.__version__,
        "numpy": numpy.__version__,
    }
