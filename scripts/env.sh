# Sourced by the scripts: the project's environment for Open MPI and numba.
# Open MPI as root, and more ranks than cores when asked for.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
export OMPI_MCA_rmaps_base_oversubscribe=1
# Compiled numba kernels live outside the clone, so a fresh clone reuses them.
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$HOME/.cache/parsph/numba}"
export H5PY_ALWAYS_USE_MPI=1
# One thread per rank: PETSc's OpenBLAS and OpenMP would otherwise start a worker per
# core that spins in sched_yield after each call, taking the core of the other rank.
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
PY="${VENV:-.venv}/bin/python"
