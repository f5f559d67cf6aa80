"""Test set-up valid at any rank count.

Under ``mpirun -n 2 python -m mpi4py -m pytest`` every rank runs every test; a test
marked ``mpi`` is skipped on one rank. A test marked ``slow`` (minutes: the finest
resolutions of a convergence study) runs only with ``--slow`` or ``PARSPH_SLOW=1``, so
that CI stays within its time. ``mpi_tmp_path`` is one directory shared by all ranks.
Each test ends with a barrier so that ranks stay in step.
"""
import os
import shutil
import tempfile

import pytest

os.environ.setdefault("H5PY_ALWAYS_USE_MPI", "1")
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one thread per rank
    os.environ.setdefault(_name, "1")
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "parsph", "numba"))


@pytest.fixture(scope="session")
def comm():
    from decomposition import world

    return world()


def pytest_addoption(parser):
    parser.addoption("--slow", action="store_true", default=False,
                     help="also run the tests marked slow (minutes each)")


def pytest_collection_modifyitems(config, items):
    from decomposition import world

    size = world().size
    skip_mpi = pytest.mark.skip(reason="needs 2 or more ranks (run under mpirun -n 2)")
    skip_serial = pytest.mark.skip(reason="spawns its own processes; runs in the one-rank session")
    slow = config.getoption("--slow") or os.environ.get("PARSPH_SLOW") == "1"
    skip_slow = pytest.mark.skip(reason="slow (minutes): run with --slow or PARSPH_SLOW=1")
    for item in items:
        if "slow" in item.keywords and not slow:
            item.add_marker(skip_slow)
        if "mpi" in item.keywords and size < 2:
            item.add_marker(skip_mpi)
        if "serial_only" in item.keywords and size > 1:
            item.add_marker(skip_serial)


def pytest_configure(config):
    config.addinivalue_line("markers", "serial_only: spawns subprocesses (mpirun); one-rank session only")


@pytest.fixture(autouse=True)
def _barrier_after_each_test(comm):
    yield
    comm.Barrier()


@pytest.fixture
def mpi_tmp_path(comm):
    """A temporary directory shared by all ranks, removed after the test."""
    path = tempfile.mkdtemp(prefix="parsph-test-") if comm.rank == 0 else None
    path = comm.bcast(path, root=0)
    yield path
    comm.Barrier()
    if comm.rank == 0:
        shutil.rmtree(path, ignore_errors=True)
