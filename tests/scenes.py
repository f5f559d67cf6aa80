"""Small scenes written by tests (TOML text, so tests exercise the real loader)."""

MOVING_2D = """
[scene]
name = "moving"
description = "two blocks passing through each other over a floor, periodic in x"

[domain]
dim = 2
particle_size = 0.05
lo = [0.0, -0.2]
hi = [2.0, 1.2]
periodic = [true, false]

[run]
end_time = 0.4
mode = "kinematic"
cfl = 0.5

[output]
every = 0.2
progress = false

[materials.sand]
model = "kinematic"
density = 1500.0

[[bodies]]
name = "left"
material = "sand"
shape = "box"
lo = [0.1, 0.0]
hi = [0.9, 0.5]
velocity = [2.0, 0.3]

[[bodies]]
name = "right"
material = "sand"
shape = "polygon"
vertices = [[1.0, 0.0], [1.9, 0.0], [1.9, 0.6], [1.2, 0.4]]
velocity = [-1.5, 0.0]

[[walls]]
name = "floor"
shape = "box"
lo = [0.0, -0.15]
hi = [2.0, 0.0]
"""

MOVING_3D = """
[scene]
name = "moving3d"

[domain]
dim = 3
particle_size = 0.1
lo = [0.0, 0.0, -0.4]
hi = [1.5, 1.0, 1.0]
periodic = [true, true, false]

[run]
end_time = 0.2
mode = "kinematic"
cfl = 0.5

[output]
every = 0.1
progress = false

[materials.rock]
model = "kinematic"
density = 2000.0

[[bodies]]
name = "slab"
material = "rock"
shape = "extruded_polygon"
vertices = [[0.0, 0.0], [1.2, 0.0], [0.0, 0.6]]
extent = [0.0, 1.0]
velocity = [1.0, -0.5, 0.0]

[[walls]]
name = "bed"
shape = "tank"
lo = [0.0, 0.0, 0.0]
hi = [1.5, 1.0, 0.9]
sides = ["bottom"]
"""


def write(tmpdir, text, name="scene.toml"):
    import os

    path = os.path.join(tmpdir, name)
    with open(path, "w") as fh:
        fh.write(text)
    return path


def by_id(frame):
    """A frame's fields ordered by global id."""
    import numpy as np

    order = np.argsort(frame["id"])
    return {k: v[order] for k, v in frame.items()}


def last_frame(out):
    """The last frame of a run directory, ordered by global id."""
    import os

    from parsph.io import read_frame

    return by_id(read_frame(os.path.join(out, "particles.h5"), "last"))


def run_on_one_and_two(comm, scene, tmpdir):
    """The keystone comparison: run ``scene`` on rank 0 alone, then on all ranks.

    Returns the two run directories (``tmpdir/one``, ``tmpdir/two``); compare their
    frames by global id on rank 0.
    """
    import os

    from mpi4py import MPI

    from parsph.pipeline import plan, uses_petsc
    from parsph.run import run

    if uses_petsc(plan(scene)):  # PetscInitialize is collective on the world: all ranks now
        import solvers

        solvers.init([])
    one_dir, two_dir = os.path.join(tmpdir, "one"), os.path.join(tmpdir, "two")
    one = comm.Split(0 if comm.rank == 0 else MPI.UNDEFINED, comm.rank)
    if comm.rank == 0:
        run(scene, one_dir, comm=one, progress=False)
        one.Free()
    run(scene, two_dir, comm=comm, progress=False)
    return one_dir, two_dir


def assert_agree_by_id(one, two, x_tol=1e-6, v_tol=1e-4):
    """The last frames of two runs (directories) have the same particles, phases and,
    to the tolerances (m, m/s), positions and velocities by global id; returns them."""
    import numpy as np

    a, b = last_frame(one), last_frame(two)
    assert np.array_equal(a["id"], b["id"])
    assert np.array_equal(a["phase"], b["phase"])
    assert np.abs(a["x"] - b["x"]).max() < x_tol
    assert np.abs(a["v"] - b["v"]).max() < v_tol
    return a, b


LONE_ROW = """
[scene]
name = "lone_row"
description = "a row of five Bingham particles sliding on a floor at 1 m/s, all on the free surface"

[domain]
dim = 2
particle_size = 0.05
lo = [-0.5, -0.3]
hi = [3.0, 1.0]

[run]
end_time = 0.6

[output]
every = 0.05
progress = false

[gravity]
g = [0.0, -9.81]

[materials.debris]            # slope_failure's debris (Table 2)
model = "bingham"
density = 1655.0
viscosity = 1.0e-3
viscosity_max = 1.0e4
cohesion = 10.0
friction_angle = 19.5

[[bodies]]
name = "row"
material = "debris"
shape = "box"
lo = [0.0, 0.0]
hi = [0.25, 0.05]
velocity = [1.0, 0.0]

[[walls]]
name = "floor"
shape = "box"
lo = [-0.5, -0.15]
hi = [3.0, 0.0]
"""


def dense_system(kernel, *args, n_points, dim=1, capacity=None):
    """Run a CSR kernel of ``parsph.fluid.assembly`` (``viscous_csr``, ``ppe_csr``) on
    rows numbered from 0 and return its matrix dense, with the right-hand side; checks
    on the way that every row's columns are sorted and distinct and, given
    ``capacity`` (``assembly.csr_capacity``), that the kernel wrote nothing past it."""
    import numpy as np

    n = n_points * dim
    cap = dim * dim * (n_points * n_points + n_points) if capacity is None else capacity
    guard = 64
    ptr = np.zeros(n + 1, dtype=np.int32)
    cols = np.full(cap + guard, -7, dtype=np.int32)
    vals = np.full(cap + guard, -7.0)
    nnz, rhs = kernel(*args, 0, ptr, cols, vals)
    assert ptr[-1] == nnz <= cap and np.all(np.diff(ptr) >= 0)
    assert np.all(cols[cap:] == -7) and np.all(vals[cap:] == -7.0), "wrote past the capacity"
    A = np.zeros((n, n))
    for r in range(n):
        c = cols[ptr[r]:ptr[r + 1]]
        assert np.all(np.diff(c) > 0), f"row {r}: columns {c} not sorted and distinct"
        A[r, c] = vals[ptr[r]:ptr[r + 1]]
    return A, rhs


def gather_particles(comm, fields):
    """Every rank's (id, x, phase) of ``fields``, sorted by global id (all ranks)."""
    import numpy as np

    allf = comm.allgather({k: fields[k] for k in ("id", "x", "phase")})
    ids = np.concatenate([f["id"] for f in allf])
    order = np.argsort(ids)
    return ids[order], np.concatenate([f["x"] for f in allf])[order], \
        np.concatenate([f["phase"] for f in allf])[order]
