#!/usr/bin/env bash
# Idempotent set-up on Debian 12 as root: Open MPI, mpi4py, PETSc/petsc4py with hypre,
# parallel h5py and numba from Debian; ParaView's pvbatch and xvfb (tests/test_paraview.py);
# GDAL's command-line tools (gdalinfo: tests/test_maps.py reads the GeoTIFFs of `parsph maps`);
# a .venv on Debian's Python that sees them; parsph installed editable into it. A second
# run on a set-up machine takes seconds.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"
export DEBIAN_FRONTEND=noninteractive
PKGS="openmpi-bin python3-mpi4py python3-petsc4py python3-h5py-mpi python3-numba
python3-numpy python3-scipy python3-pytest python3-hypothesis python3-matplotlib python3-venv
paraview python3-paraview xvfb xauth gdal-bin"
if ! dpkg -s $PKGS >/dev/null 2>&1; then
    if [ "$(id -u)" != 0 ]; then
        echo "setup: Debian packages missing ($PKGS); run this script as root or install them" >&2
        exit 1
    fi
    apt-get update -q
    apt-get install -y -q --no-install-recommends $PKGS
fi
[ -x "$VENV/bin/python" ] || /usr/bin/python3 -m venv --system-site-packages "$VENV"
SITE=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
PETSC_PY=$(ls -d /usr/lib/petscdir/petsc3.*/x86_64-linux-gnu-real/lib/python3/dist-packages \
           /usr/lib/petscdir/petsc3.*/*-linux-gnu-real/lib/python3/dist-packages 2>/dev/null | sort -uV | tail -1)
if [ -z "$PETSC_PY" ]; then
    echo "setup: petsc4py from Debian not found under /usr/lib/petscdir" >&2
    exit 1
fi
echo "$PETSC_PY" > "$SITE/debian-petsc4py.pth"
# Pin what Debian ships so pip never pulls numpy 2 into the venv (it would break numba, h5py, petsc4py).
CONSTRAINTS="$VENV/constraints.txt"
printf '%s\n' numpy==1.24.2 numba==0.56.4 llvmlite==0.39.1 scipy==1.10.1 mpi4py==3.1.4 \
    h5py==3.7.0 petsc4py==3.18.5 > "$CONSTRAINTS"
# From PyPI (wheels that need only numpy): meshes and their ray tests (trimesh, rtree), GeoTIFF
# height maps (tifffile, imagecodecs for LZW-compressed files). Keep in step with pyproject.toml.
PIP_PKGS="trimesh>=4 rtree>=1 tifffile>=2023.1 imagecodecs>=2023.1"
STAMP="$VENV/.parsph-installed"
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ]; then
    "$VENV/bin/pip" install -q -c "$CONSTRAINTS" $PIP_PKGS
    "$VENV/bin/pip" install -q --no-build-isolation --no-deps -c "$CONSTRAINTS" -e .
    touch "$STAMP"
fi
"$VENV/bin/python" - <<'PY'
import sys
import h5py, mpi4py, numba, numpy, petsc4py
import imagecodecs, rtree, tifffile, trimesh  # geometry from files

print(f"setup: ok (python {sys.version.split()[0]}, numpy {numpy.__version__}, numba {numba.__version__}, "
      f"mpi4py {mpi4py.__version__}, petsc4py {petsc4py.__version__}, h5py {h5py.__version__})")
PY
