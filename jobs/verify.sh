#!/usr/bin/env bash
# Every slow test (pytest marker `slow`: the built-in scenes as they are, the experiment
# comparisons and the convergence study CI has no time for) on 2 ranks, one test at a
# time, then a table: test, outcome, wall time and the figures the test recorded (its
# `figures NAME: ...` lines).
#   bash jobs/verify.sh [PYTEST ARGS, e.g. -k gate]
# Each test's whole output is kept in out/verify/<test>.log and its figure records in
# out/verify/figures/ (`python jobs/figures.py --take out/verify/figures` puts them into
# docs/figures/ and rewrites the pages that quote them; docs/figures.md). Exit status
# non-zero if any test fails, errors or is skipped, or any rank fails; every test has a
# deadline (PARSPH_VERIFY_TIMEOUT seconds, default 3 hours) so a hung collective cannot
# hang the job.
set -uo pipefail

table() {  # rows "test<TAB>outcome<TAB>wall<TAB>figure line|figure line..." on stdin
    "$PY" -c '
import sys, textwrap
print("%-70s %-8s %10s" % ("test", "outcome", "wall (m:s)"))
for line in sys.stdin:
    test, outcome, wall, figures = line.rstrip("\n").split("\t")
    print(f"{test:<70} {outcome:<8} {wall:>10}")
    for fig in filter(None, figures.split("|")):
        print(textwrap.fill(fig, 100, initial_indent="    ", subsequent_indent="        "))
'
}

main() {
    cd "$(dirname "$0")/.."
    bash scripts/setup.sh >/dev/null || exit 1
    source scripts/env.sh
    local out=out/verify
    mkdir -p "$out/figures"
    export PARSPH_FIGURES="${PARSPH_FIGURES:-$out/figures}"
    local deadline="${PARSPH_VERIFY_TIMEOUT:-10800}"
    local tests
    mapfile -t tests < <("$PY" -m pytest --collect-only -q --slow -m slow "$@" 2>/dev/null \
                         | grep '::' | sort)
    if [ "${#tests[@]}" = 0 ]; then
        echo "verify: no slow test collected (pytest --collect-only -m slow $*)" >&2
        return 1
    fi
    echo "== ${#tests[@]} slow test(s) on 2 ranks"
    printf '   %s\n' "${tests[@]}"
    local status=0 passed=0 rows=() begin t log start rc wall summary outcome figures
    begin=$(date +%s)
    for t in "${tests[@]}"; do
        log="$out/$(echo "${t##*::}" | tr -c 'A-Za-z0-9_.\n-' '_').log"
        echo "-- $t (log: $log)"
        start=$(date +%s)
        timeout --kill-after=30 "$deadline" mpirun -n 2 bash scripts/rank-output.sh \
            "$PY" -m mpi4py -m pytest -q -s --slow "$t" >"$log" 2>&1
        rc=$?
        wall=$(( $(date +%s) - start ))
        summary=$(grep -E '^(=+ )?[0-9]+ (passed|failed|skipped|error|deselected)' "$log" \
                  | tail -1)
        if [ "$rc" = 0 ] && echo "$summary" | grep -q '1 passed' \
                && ! echo "$summary" | grep -qE 'failed|skipped|error'; then
            outcome=passed
            passed=$((passed + 1))
        elif [ "$rc" = 124 ] || [ "$rc" = 137 ]; then
            outcome="TIMEOUT"
            status=1
        else
            outcome="FAILED"
            status=1
            echo "   exit $rc${summary:+: $summary}; the end of its log:"
            tail -40 "$log"
        fi
        figures=$(grep -E '^figures [A-Za-z0-9_.-]+: ' "$log" | sed 's/^figures //' \
                  | paste -sd '|' -)
        rows+=("${t##*::}	$outcome	$(printf '%d:%02d' $((wall / 60)) $((wall % 60)))	${figures}")
    done
    local total=$(( $(date +%s) - begin ))
    echo
    echo "== slow tests on 2 ranks: $passed of ${#tests[@]} passed in" \
         "$(printf '%d:%02d' $((total / 60)) $((total % 60)))"
    printf '%s\n' "${rows[@]}" | table
    if [ "$#" = 0 ]; then  # the whole set: its wall time is a figure the pages quote
        "$PY" -c "import sys; sys.path.insert(0, '.'); from jobs.figures import record
record('verify', {'wall_min': $total / 60, 'tests': ${#tests[@]}, 'passed': $passed},
       ranks=2, command='bash jobs/verify.sh', source='jobs/verify.sh')" >/dev/null
    fi
    return "$status"
}

main "$@"
exit $?
