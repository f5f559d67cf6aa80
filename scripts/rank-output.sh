#!/usr/bin/env bash
# Run a command under mpirun so that rank 0 prints as usual and other ranks print only when
# they fail (their output would otherwise interleave with rank 0's). The exit status is kept.
rank="${OMPI_COMM_WORLD_RANK:-${PMI_RANK:-0}}"
if [ "$rank" = 0 ]; then
    exec "$@"
fi
log=$(mktemp)
"$@" >"$log" 2>&1
rc=$?
if [ "$rc" != 0 ]; then
    echo "===== rank $rank failed (exit $rc); its output: ====="
    cat "$log"
fi
rm -f "$log"
exit "$rc"
