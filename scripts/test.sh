#!/usr/bin/env bash
# The whole test suite: set-up if needed, then pytest at 1 rank and under mpirun -n 2.
# Fails if any rank fails; every run has a deadline so a hung collective cannot hang CI.
# The one-rank session runs as two shards at once, one per core (tests/conftest.py deals
# the test modules to them whole); each shard's output is printed when it ends.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
echo "== tests on 1 rank (two shards at once)"
logs=$(mktemp -d)
trap 'rm -rf "$logs"' EXIT
pids=()
for k in 0 1; do
    PARSPH_TEST_SHARD="$k/2" timeout --kill-after=30 1200 "$PY" -m pytest -q "$@" \
        >"$logs/$k" 2>&1 &
    pids+=($!)
done
status=0 empty=0
for k in 0 1; do
    rc=0
    wait "${pids[$k]}" || rc=$?
    echo "-- shard $((k + 1)) of 2 (exit $rc)"
    cat "$logs/$k"
    if [ "$rc" = 5 ]; then  # pytest: no test of this shard was selected
        empty=$((empty + 1))
    elif [ "$rc" != 0 ]; then
        status=$rc
    fi
done
[ "$status" = 0 ] || exit "$status"
[ "$empty" -lt 2 ] || exit 5
echo "== tests on 2 ranks (mpirun -n 2)"
timeout --kill-after=30 1200 mpirun -n 2 bash scripts/rank-output.sh "$PY" -m mpi4py -m pytest -q "$@"
