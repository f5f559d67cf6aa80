#!/usr/bin/env bash
# The main job: set-up if needed, then the built-in default scene (the slope failure of the
# paper's Table 2 with phase change: TLSPH soil turning into IISPH Bingham fluid) on 2 ranks;
# output in out/demo (particles.h5, particles.xdmf,
# stats.csv, checkpoint.h5), pictures of the first and last frames and the time series
# (out/demo/plots/frame_*.png, series.png).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
timeout --kill-after=30 3600 mpirun -n 2 "$PY" -m parsph run --out out/demo "$@"
"$PY" -m parsph plot out/demo --frames first,last --series
