"""Test set-up valid at any rank count.

Under ``mpirun -n 2 python -m mpi4py -m pytest`` every rank runs every test; a test
marked ``mpi`` is skipped on one rank. A test marked ``slow`` (minutes: the finest
resolutions of a convergence study) runs only with ``--slow`` or ``PARSPH_SLOW=1``, so
that CI stays within its time. ``mpi_tmp_path`` is one directory shared by all ranks.
Each test ends with a barrier so that ranks stay in step.

``PARSPH_TEST_SHARD=k/n`` keeps only the test modules of shard ``k`` of ``n`` (one-rank
session only): ``scripts/test.sh`` runs the one-rank session as two shards at once, one
per core. Modules are dealt to shards whole (their numba kernels then compile in one
process, not in both) by their measured cost, largest first, each to the shard with the
least so far; a module missing from :data:`MODULE_SECONDS` (under a second) counts as 1 s.
"""
import os
import shutil
import tempfile

import pytest

os.environ.setdefault("H5PY_ALWAYS_USE_MPI", "1")
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one thread per rank
    os.environ.setdefault(_name, "1")
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "parsph", "numba"))


#: Seconds of each test module in a one-rank session with a cold numba cache (as in CI's
#: fresh clone), for dealing modules to shards; only the balance depends on them.
MODULE_SECONDS = {
    "test_coupling": 294, "test_strong_coupling": 170, "test_failures": 169, "test_energy": 90,
    "test_cli": 78, "test_fluid_stability": 36, "test_iisph": 29, "test_probes": 29,
    "test_paraview": 21, "test_solid_stability": 20, "test_output": 16, "test_restart": 14,
    "test_tlsph": 14, "test_constitutive": 11, "test_kernel": 7, "test_decomposition": 5,
    "test_run": 4, "test_tutorial": 4, "test_neighbours": 3, "test_output_schedule": 2,
    "test_study": 2, "test_solvers": 2, "test_series": 2, "test_maps": 30, "test_regularisation": 25, "test_geostatic": 10,
    "test_newmark": 100,
}


def shard_of_modules(modules, n):
    """``{module: shard}``: the modules dealt to ``n`` shards by :data:`MODULE_SECONDS`,
    largest first, each to the least-loaded shard (ties by name, so every process deals
    the same)."""
    load = [0.0] * n
    out = {}
    for name in sorted(modules, key=lambda m: (-MODULE_SECONDS.get(m, 1.0), m)):
        k = min(range(n), key=lambda s: (load[s], s))
        out[name] = k
        load[k] += MODULE_SECONDS.get(name, 1.0)
    return out


def _shard():
    """``(k, n)`` from ``PARSPH_TEST_SHARD=k/n``, or None; a malformed value is an error."""
    value = os.environ.get("PARSPH_TEST_SHARD", "").strip()
    if not value:
        return None
    try:
        k, n = (int(v) for v in value.split("/"))
    except ValueError:
        k = n = -1
    if not 0 <= k < n:
        raise pytest.UsageError(f"PARSPH_TEST_SHARD={value!r}: expected k/n with 0 <= k < n, "
                                "e.g. 0/2")
    return k, n


@pytest.fixture(scope="session")
def comm():
    from decomposition import world

    return world()


def pytest_addoption(parser):
    parser.addoption("--slow", action="store_true", default=False,
                     help="also run the tests marked slow (minutes each)")
    parser.addoption("--keep-output", metavar="DIR", default=None,
                     help="keep each test's output directory under DIR (named after the "
                          "test) instead of removing it: the slow studies' runs, for docs")


def pytest_collection_modifyitems(config, items):
    from decomposition import world

    size = world().size
    skip_mpi = pytest.mark.skip(reason="needs 2 or more ranks (run under mpirun -n 2)")
    skip_serial = pytest.mark.skip(reason="spawns its own processes; runs in the one-rank session")
    skip_one = pytest.mark.skip(reason="one-rank session only (CI time)")
    slow = config.getoption("--slow") or os.environ.get("PARSPH_SLOW") == "1"
    skip_slow = pytest.mark.skip(reason="slow (minutes): run with --slow or PARSPH_SLOW=1")
    shard = _shard()
    if shard is not None and size == 1:
        k, n = shard
        names = [item.module.__name__.rsplit(".", 1)[-1] for item in items]
        deal = shard_of_modules(set(names), n)
        mine = [deal[name] == k for name in names]
        config.hook.pytest_deselected(items=[it for it, m in zip(items, mine) if not m])
        items[:] = [it for it, m in zip(items, mine) if m]
    for item in items:
        if "slow" in item.keywords and not slow:
            item.add_marker(skip_slow)
        if "mpi" in item.keywords and size < 2:
            item.add_marker(skip_mpi)
        if "serial_only" in item.keywords and size > 1:
            item.add_marker(skip_serial)
        if "one_rank" in item.keywords and size > 1:
            item.add_marker(skip_one)


def pytest_configure(config):
    config.addinivalue_line("markers", "serial_only: spawns subprocesses (mpirun); one-rank session only")
    config.addinivalue_line("markers", "one_rank: one-rank session only (CI time: the two-rank "
                            "session is the longer; other tests compare 1 and 2 ranks)")


@pytest.fixture(autouse=True)
def _barrier_after_each_test(comm):
    yield
    comm.Barrier()


@pytest.fixture
def mpi_tmp_path(comm, request):
    """A temporary directory shared by all ranks, removed after the test (kept under
    ``--keep-output DIR`` as DIR/TEST_NAME)."""
    keep = request.config.getoption("--keep-output")
    path = None
    if comm.rank == 0:
        if keep:
            path = os.path.join(os.path.abspath(keep), request.node.name)
            shutil.rmtree(path, ignore_errors=True)
            os.makedirs(path)
        else:
            path = tempfile.mkdtemp(prefix="parsph-test-")
    path = comm.bcast(path, root=0)
    yield path
    comm.Barrier()
    if comm.rank == 0 and not keep:
        shutil.rmtree(path, ignore_errors=True)
