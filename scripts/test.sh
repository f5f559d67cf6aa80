#!/usr/bin/env bash
# The whole test suite: set-up if needed, then pytest at 1 rank and under mpirun -n 2.
# Fails if any rank fails; every run has a deadline so a hung collective cannot hang CI.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
echo "== tests on 1 rank"
timeout --kill-after=30 1200 "$PY" -m pytest -q "$@"
echo "== tests on 2 ranks (mpirun -n 2)"
timeout --kill-after=30 1200 mpirun -n 2 bash scripts/rank-output.sh "$PY" -m mpi4py -m pytest -q "$@"
