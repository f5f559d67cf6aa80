#!/usr/bin/env bash
# Run parsph with mpirun on this machine: jobs/local.sh RANKS SCENE [parsph run options...]
#   jobs/local.sh 2 hydrostatic --set run.mode=geometry --out out/h
set -euo pipefail
cd "$(dirname "$0")/.."
RANKS="${1:?usage: jobs/local.sh RANKS SCENE [options]}"
shift
bash scripts/setup.sh >/dev/null
source scripts/env.sh
exec mpirun -n "$RANKS" "$PY" -m parsph run "$@"
