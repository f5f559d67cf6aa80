"""parsph: phase-change TLSPH-IISPH landslide simulation on MPI and PETSc.

The Python API serves scripts and tests the way the CLI does (collective: run it under
``mpirun`` like the CLI)::

    import parsph
    scene = parsph.load_scene("dam_break", overrides=["domain.particle_size=0.01"])
    summary = parsph.run(scene, out="out/db")   # steps, time, wall_s, particles, ...

The folders follow a step's data flow (docs/architecture.md): ``scene/`` (TOML ->
validated scene -> particles), ``core/`` (particle store, kernel, neighbours, density,
contact), ``solid/``, ``fluid/``, ``coupling/``, ``step/`` (driver, stages,
checkpoints), ``io/`` and ``cli/``.
"""
import os as _os

# Compiled numba kernels are cached outside the source tree, so a fresh clone reuses them.
_os.environ.setdefault(
    "NUMBA_CACHE_DIR", _os.path.join(_os.path.expanduser("~"), ".cache", "parsph", "numba")
)

# Debian's h5py picks its parallel (MPI) build only under mpirun or with this set; parsph
# always writes collectively, also on one rank.
_os.environ.setdefault("H5PY_ALWAYS_USE_MPI", "1")

# One thread per MPI rank. PETSc links OpenBLAS and OpenMP (hypre); left alone, each
# starts a worker per core that spins in sched_yield after every call, on the core of the
# other rank: 2-rank IISPH solves ran 15-20 % slower (docs/scaling.md). Only effective
# when parsph is imported before numpy and PETSc; scripts/env.sh sets them for jobs.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    _os.environ.setdefault(_name, "1")

__version__ = "0.1.0"


def __getattr__(name):
    """``parsph.run`` and ``parsph.load_scene``, imported on first use (``import parsph``
    stays cheap for the command line)."""
    if name == "run":
        from parsph.step.run import run
        return run
    if name == "load_scene":
        from parsph.scene.loader import load_scene
        return load_scene
    raise AttributeError(f"module 'parsph' has no attribute {name!r}")
