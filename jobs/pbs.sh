#!/bin/bash
# parsph on PBS Pro / Torque: one run, re-run from its last checkpoint when pre-empted.
#
#   qsub -v SCENE=slope_failure,OUT=/scratch/$USER/parsph/slope jobs/pbs.sh
#
# PBS sends SIGTERM some time (kill_delay) before killing a job at its limit or on
# pre-emption; parsph then goes on to the next sync step, writes OUT/checkpoint.h5 and
# exits with 4, and the script asks PBS to run the job again (it is re-runnable: -r y), restarting from it.
#PBS -N parsph
#PBS -l select=2:ncpus=32:mpiprocs=32
#PBS -l walltime=04:00:00
#PBS -r y
#PBS -j oe
set -uo pipefail
cd "${PBS_O_WORKDIR:-$PWD}"

SCENE="${SCENE:-slope_failure}"
OUT="${OUT:-${SCRATCH:-$PWD}/parsph/$(basename "$SCENE" .toml)}"
VENV="${VENV:-$HOME/parsph/.venv}"
EXIT_PREEMPTED=4
NP=$(wc -l < "${PBS_NODEFILE:-/dev/null}" 2>/dev/null || echo 2)
[ "$NP" -gt 0 ] || NP=2

# module load openmpi petsc hdf5-parallel python
[ -f "$VENV/bin/activate" ] && source "$VENV/bin/activate"
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$HOME/.cache/parsph/numba}"
export H5PY_ALWAYS_USE_MPI=1
# one thread per rank (PETSc's OpenBLAS/OpenMP workers would spin on the ranks' cores)
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"

args=(run "$SCENE" --out "$OUT" --no-progress)
for kv in ${SET:-}; do args+=(--set "$kv"); done
[ -f "$OUT/checkpoint.h5" ] && args+=(--restart "$OUT/checkpoint.h5")

mpirun -n "$NP" parsph "${args[@]}" &
pid=$!
trap 'kill -USR1 "$pid"' TERM USR1
rc=0
while :; do
    wait "$pid"
    rc=$?
    kill -0 "$pid" 2>/dev/null || break
done
if [ "$rc" -eq "$EXIT_PREEMPTED" ]; then
    qrerun "${PBS_JOBID:?}"
    exit 0
fi
exit "$rc"
