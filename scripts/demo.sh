#!/usr/bin/env bash
# The main job: set-up if needed, then the built-in default scene on 2 ranks (geometry only until
# its physics lands: particles built, partitioned, density computed), its output in
# out/demo (particles.h5, particles.xdmf, stats.csv) and a picture (out/demo/*.png).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
timeout --kill-after=30 3600 mpirun -n 2 "$PY" -m parsph run --out out/demo --set run.mode=geometry "$@"
"$PY" -m parsph plot out/demo
