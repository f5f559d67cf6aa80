"""parsph: phase-change TLSPH-IISPH landslide simulation on MPI and PETSc.

The Python API serves scripts and tests the way the CLI does::

    from parsph.scene import load_scene
    from parsph.run import run
    run(load_scene("dam_break", overrides=["domain.particle_size=0.01"]), out="out/db")
"""
import os as _os

# Compiled numba kernels are cached outside the source tree, so a fresh clone reuses them.
_os.environ.setdefault(
    "NUMBA_CACHE_DIR", _os.path.join(_os.path.expanduser("~"), ".cache", "parsph", "numba")
)

# Debian's h5py picks its parallel (MPI) build only under mpirun or with this set; parsph
# always writes collectively, also on one rank.
_os.environ.setdefault("H5PY_ALWAYS_USE_MPI", "1")

__version__ = "0.1.0"
